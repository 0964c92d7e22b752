"""Wheel odometry from the true wheel motion: systematic and random wheel errors, dead reckoning
in the odometry's own frame. The model's equations are in :class:`fusion.sim.config.OdometryConfig`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.sim.config import OdometryConfig
from houghloc.geometry import compose

FloatArray = NDArray[np.float64]


def measured_motion(motion: FloatArray, cfg: OdometryConfig, rng: np.random.Generator
                    ) -> FloatArray:
    """(ds, dθ) per step as the wheel encoders report it ((N−1)×2)."""
    ds, dth = motion[:, 0], motion[:, 1]
    half_b = 0.5 * cfg.wheelbase
    left = ds - half_b * dth
    right = ds + half_b * dth
    noise = rng.standard_normal((len(ds), 2)) * cfg.wheel_noise
    left = (1.0 + cfg.left_scale_error) * left + noise[:, 0] * np.sqrt(np.abs(left))
    right = (1.0 + cfg.right_scale_error) * right + noise[:, 1] * np.sqrt(np.abs(right))
    believed_base = cfg.wheelbase * (1.0 + cfg.wheelbase_error)
    turn = (right - left) / believed_base
    if cfg.turn_slip:
        # the tighter the turn, the more the wheels scrub: the encoders count more turn than
        # the robot made (OdometryConfig.turn_slip)
        tightness = np.minimum(1.0, np.abs(dth) / np.maximum(np.abs(ds), 1e-9))
        turn = turn * (1.0 + cfg.turn_slip * tightness)
    return np.column_stack((0.5 * (left + right), turn))


def dead_reckon(motion: FloatArray, frame_offset: tuple[float, float, float]) -> FloatArray:
    """Integrate (ds, dθ) from the identity with the midpoint rule, then express the path in the
    odometry frame: ``frame_offset ⊕ pose`` (N×3, N = steps + 1). Vectorised with cumulative sums.
    """
    ds, dth = motion[:, 0], motion[:, 1]
    theta = np.concatenate(([0.0], np.cumsum(dth)))
    mid = theta[:-1] + 0.5 * dth
    x = np.concatenate(([0.0], np.cumsum(ds * np.cos(mid))))
    y = np.concatenate(([0.0], np.cumsum(ds * np.sin(mid))))
    return compose(frame_offset, np.column_stack((x, y, theta)))


def simulate_odometry(motion: FloatArray, cfg: OdometryConfig, rng: np.random.Generator
                      ) -> FloatArray:
    """Odometry poses (N×3) in the odometry frame for the true wheel motion ((N−1)×2)."""
    return dead_reckon(measured_motion(motion, cfg, rng), cfg.frame_offset)

"""Pose arrays (N×3 rows of x, y, θ): composition, relative motion, interpolation in time.

Composition and relative motion of stacks are ``houghloc.geometry.compose``/``relative``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.geometry import relative, wrap_angle

FloatArray = NDArray[np.float64]


def increments(poses: FloatArray) -> FloatArray:
    """Relative motion between consecutive poses ((N−1)×3), as a localizer computes it."""
    return relative(poses[:-1], poses[1:])


def interpolate_poses(t_query: ArrayLike, t: FloatArray, poses: FloatArray) -> FloatArray:
    """Poses at ``t_query`` by linear interpolation (heading unwrapped first); exact on ``t``."""
    tq = np.asarray(t_query, dtype=float)
    theta = np.unwrap(poses[:, 2])
    return np.column_stack((
        np.interp(tq, t, poses[:, 0]),
        np.interp(tq, t, poses[:, 1]),
        wrap_angle(np.interp(tq, t, theta)),
    ))

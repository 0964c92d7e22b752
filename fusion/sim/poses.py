"""Pose arrays (N×3 rows of x, y, θ): composition, relative motion, interpolation in time.

Array versions of ``houghloc.geometry.compose``/``relative`` (which take single poses).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.geometry import wrap_angle

FloatArray = NDArray[np.float64]


def compose_many(a: ArrayLike, b: FloatArray) -> FloatArray:
    """a ⊕ bᵢ for one pose a and rows bᵢ (N×3)."""
    ax, ay, at = np.asarray(a, dtype=float)
    c, s = np.cos(at), np.sin(at)
    out = np.empty_like(b, dtype=float)
    out[:, 0] = ax + c * b[:, 0] - s * b[:, 1]
    out[:, 1] = ay + s * b[:, 0] + c * b[:, 1]
    out[:, 2] = wrap_angle(at + b[:, 2])
    return out


def relative_many(a: FloatArray, b: FloatArray) -> FloatArray:
    """(⊖aᵢ) ⊕ bᵢ row by row: the motion from aᵢ to bᵢ in aᵢ's frame (N×3)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[:, 2] - a[:, 2])))


def increments(poses: FloatArray) -> FloatArray:
    """Relative motion between consecutive poses ((N−1)×3), as a localizer computes it."""
    return relative_many(poses[:-1], poses[1:])


def interpolate_poses(t_query: ArrayLike, t: FloatArray, poses: FloatArray) -> FloatArray:
    """Poses at ``t_query`` by linear interpolation (heading unwrapped first); exact on ``t``."""
    tq = np.asarray(t_query, dtype=float)
    theta = np.unwrap(poses[:, 2])
    return np.column_stack((
        np.interp(tq, t, poses[:, 0]),
        np.interp(tq, t, poses[:, 1]),
        wrap_angle(np.interp(tq, t, theta)),
    ))


def heading_quaternion(theta: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(q_z, q_w) of a rotation by θ about z (TUM files store x y z qx qy qz qw)."""
    half = 0.5 * np.asarray(theta, dtype=float)
    return np.sin(half), np.cos(half)

"""Planar pose algebra shared by the method and the filter.

A pose is ``(x, y, θ)``: the position of ``base`` in ``map`` and its heading. Angles are radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

TWO_PI = 2.0 * np.pi


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to [-π, π)."""
    return (np.asarray(angle, dtype=float) + np.pi) % TWO_PI - np.pi


def wrap_2pi(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to [0, 2π), the Hough domain's range for θ."""
    return np.asarray(angle, dtype=float) % TWO_PI


def compose(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Pose composition a ⊕ b: the pose b, given in the frame of a, expressed in a's parent frame."""
    ax, ay, at = np.asarray(a, dtype=float)
    bx, by, bt = np.asarray(b, dtype=float)
    c, s = np.cos(at), np.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, float(wrap_angle(at + bt))])


def inverse(a: ArrayLike) -> NDArray[np.float64]:
    """Pose inverse ⊖a, so that a ⊕ (⊖a) is the identity."""
    ax, ay, at = np.asarray(a, dtype=float)
    c, s = np.cos(at), np.sin(at)
    return np.array([-c * ax - s * ay, s * ax - c * ay, float(wrap_angle(-at))])


def relative(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """The motion from a to b in a's frame: (⊖a) ⊕ b. Odometry increments are computed this way."""
    return compose(inverse(a), b)


def transform_points(pose: ArrayLike, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Map robot-frame points (N×2) to the parent frame of ``pose``."""
    x, y, t = np.asarray(pose, dtype=float)
    c, s = np.cos(t), np.sin(t)
    out = points @ np.array([[c, s], [-s, c]])
    out[:, 0] += x
    out[:, 1] += y
    return out


def ranges_to_points(
    ranges: ArrayLike, angles: ArrayLike, max_range: float = np.inf, min_range: float = 0.0
) -> NDArray[np.float64]:
    """Polar beams to sensor-frame points, dropping non-finite, out-of-range and no-return beams."""
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    keep = np.isfinite(r) & np.isfinite(a) & (r > min_range) & (r < max_range)
    r, a = r[keep], a[keep]
    return np.column_stack((r * np.cos(a), r * np.sin(a)))

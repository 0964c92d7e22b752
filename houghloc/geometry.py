"""Planar pose algebra shared by the method and the filter.

A pose is ``(x, y, θ)``: the position of ``base`` in ``map`` and its heading. Angles are radians.
"""

from __future__ import annotations

import math

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
    """Pose composition a ⊕ b: the pose b, given in the frame of a, in a's parent frame.

    Single poses (3,) take a scalar path (this runs for every odometry reading); stacks (N×3)
    are vectorised, and one side may be a single pose.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim == 1 and b.ndim == 1:
        ax, ay, at = a.tolist()
        bx, by, bt = b.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap_scalar(at + bt)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    out[..., 1] = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    out[..., 2] = wrap_angle(a[..., 2] + b[..., 2])
    return out


def inverse(a: ArrayLike) -> NDArray[np.float64]:
    """Pose inverse ⊖a, so that a ⊕ (⊖a) is the identity (single pose or N×3)."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        ax, ay, at = a.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([-c * ax - s * ay, s * ax - c * ay, wrap_scalar(-at)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(a.shape)
    out[..., 0] = -c * a[..., 0] - s * a[..., 1]
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def relative(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """The motion from a to b in a's frame: (⊖a) ⊕ b = (R(−θa)(b − a)_xy, θb − θa). Odometry
    increments are computed this way; single poses take a scalar path (once per reading)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim == 1 and b.ndim == 1:
        (ax, ay, at), (bx, by, bt) = a.tolist(), b.tolist()
        c, s, dx, dy = math.cos(at), math.sin(at), bx - ax, by - ay
        return np.array([c * dx + s * dy, c * dy - s * dx, wrap_scalar(bt - at)])
    return compose(inverse(a), b)


def wrap_scalar(angle: float) -> float:
    """One angle (a Python float) wrapped to [-π, π): ``wrap_angle`` without an array round trip,
    for the code that runs once per reading or per scan."""
    return (float(angle) + math.pi) % TWO_PI - math.pi


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


def inverse_3x3(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of a 3×3 matrix by its adjugate (cofactors over the determinant).

    The per-scan covariances are 3×3; written out, the inverse costs a few float operations where
    ``np.linalg.inv`` costs its general LAPACK call. Raises ``LinAlgError`` when singular, as
    ``np.linalg.inv`` does.
    """
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co_a + b * co_b + c * co_c
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError(f"singular or non-finite 3×3 matrix (determinant {det})")
    return np.array(((co_a, c * h - b * i, b * f - c * e),
                     (co_b, a * i - c * g, c * d - a * f),
                     (co_c, b * g - a * h, a * e - b * d))) / det


def ray_segment_distances(
    origin: ArrayLike, dirs: NDArray[np.float64], starts: NDArray[np.float64],
    ends: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Distance t along each unit ray to each segment (B×S), ``inf`` where it misses.

    Solves ``o + t·d = a + u·(b − a)`` with 2-D cross products (Cramer's rule) and keeps
    ``t > 0``, ``0 ≤ u ≤ 1``. Rays parallel to a segment never hit it (a grazing ray sees
    the segment's end-on neighbour instead, as a real scanner would).
    """
    if len(starts) == 0:
        return np.full((len(dirs), 0), np.inf)
    p0 = starts - np.asarray(origin, dtype=float)[:2]  # S×2
    e = ends - starts
    dx, dy = dirs[:, :1], dirs[:, 1:]
    num_t = p0[:, 0] * e[:, 1] - p0[:, 1] * e[:, 0]  # S
    # In-place arithmetic: the inner loop of the simulator and of the map's visibility (B×S).
    inv = dx * e[:, 1]
    inv -= dy * e[:, 0]
    u = dy * p0[:, 0]
    u -= dx * p0[:, 1]
    # ±inf for parallel rays (and overflow for nearly parallel ones): u becomes ±inf or nan → a
    # miss
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        np.divide(1.0, inv, out=inv)
        t = num_t * inv
        u *= inv
    miss = u < 0.0
    miss |= u > 1.0
    miss |= ~(t > 1e-9)
    t[miss] = np.inf
    return t

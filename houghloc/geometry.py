"""Planar pose algebra shared by the method and the filter.

A pose is ``(x, y, θ)``: the position of ``base`` in ``map`` and its heading. Angles are radians.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.jit import njit

TWO_PI = 2.0 * np.pi

Pose = Sequence[float] | NDArray[np.float64]
"""One pose or increment (x, y, θ) that is read number by number: a tuple, list or array."""


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to [-π, π)."""
    return (np.asarray(angle, dtype=float) + np.pi) % TWO_PI - np.pi


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


@njit
def mod_two_pi(u: float) -> float:
    """``u % TWO_PI`` bit for bit (Python's and Numba's floor modulo: ``fmod``, then + 2π when
    negative), without ``fmod`` where ``u`` lies within a period of [0, 2π): the remainder is
    then ``u`` itself, ``u − 2π`` (exact, by Sterbenz's lemma, as ``fmod``'s) or ``u + 2π``
    (the modulo's own correction, rounded the same). A local search's candidate loop calls it
    on every candidate: on Freiburg 079's, 1.9–2.4 ms a call instead of 4.6–5.6 with ``%``."""
    if 0.0 < u < TWO_PI:
        return u
    if TWO_PI <= u < 2.0 * TWO_PI:
        return u - TWO_PI
    if -TWO_PI < u < 0.0:
        return u + TWO_PI
    return u % TWO_PI  # zero (its sign), far outside, NaN


_SMALLEST_NORMAL = 2.2250738585072014e-308  # np.finfo(float).tiny


@njit
def within_radius(dx: float, dy: float, radius: float) -> bool:
    """``hypot(dx, dy) <= radius``, with the square root taken only where the squared length
    is within a relative 1e-9 of ``radius``²: elsewhere its rounding cannot change the answer.
    Squares below the smallest normal float (lengths under 1e-154) have lost that relative
    precision, so there the square root is always taken."""
    d2, r2 = dx * dx + dy * dy, radius * radius
    if r2 >= _SMALLEST_NORMAL:
        if d2 < r2 * (1.0 - 1e-9):
            return True
        if d2 > r2 * (1.0 + 1e-9):
            return False
    return math.hypot(dx, dy) <= radius


@njit
def bearing_span(p0x: float, p0y: float, p1x: float, p1y: float, step: float, n: int
                 ) -> tuple[int, int]:
    """The bearings that the segment from (p0x, p0y) to (p1x, p1y), relative to the origin,
    spans seen from it (the shorter way round), as ``n`` bins of width ``step`` from angle 0:
    (first, count), the bins (first + q) mod n, one wider on each side for rounding. All n
    when the origin lies on or beside the segment, or a value is not finite."""
    a0 = math.atan2(p0y, p0x)
    gap = math.atan2(p1y, p1x) - a0
    gap = (gap + np.pi) % TWO_PI - np.pi
    if not abs(gap) <= np.pi - 2 * step:
        return 0, n
    low = a0 + min(gap, 0.0)
    first = math.floor(low / step) - 1
    return first, min(math.ceil((low + abs(gap)) / step) + 1 - first + 1, n)


def transform_points(pose: ArrayLike, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Map robot-frame points (N×2) to the parent frame of ``pose``."""
    x, y, t = np.asarray(pose, dtype=float).tolist()
    c, s = math.cos(t), math.sin(t)  # on Python floats: NumPy's on a scalar costs µs each
    out = points @ np.array([[c, s], [-s, c]])
    out[:, 0] += x
    out[:, 1] += y
    return out


def ranges_to_points(
    ranges: ArrayLike, angles: ArrayLike, max_range: float = np.inf, min_range: float = 0.0
) -> NDArray[np.float64]:
    """Polar beams to sensor-frame points, dropping non-finite, out-of-range and no-return beams
    (those with min_range < r < max_range are kept)."""
    r = np.ascontiguousarray(ranges, dtype=float).reshape(-1)
    a = np.ascontiguousarray(angles, dtype=float).reshape(-1)
    if r.shape != a.shape:
        raise ValueError(f"{len(r)} ranges but {len(a)} beam angles")
    return _beams_to_points(r, a, float(max_range), float(min_range))


@njit
def _beams_to_points(r: NDArray[np.float64], a: NDArray[np.float64], max_range: float,
                     min_range: float) -> NDArray[np.float64]:
    out = np.empty((len(r), 2))
    n = 0
    for i in range(len(r)):
        if math.isfinite(r[i]) and math.isfinite(a[i]) and min_range < r[i] < max_range:
            out[n, 0], out[n, 1] = r[i] * math.cos(a[i]), r[i] * math.sin(a[i])
            n += 1
    return out[:n]


def within_range(points: NDArray[np.float64], max_range: float) -> NDArray[np.float64]:
    """The points (N×2, finite) nearer than ``max_range`` to the origin: ``points`` itself when
    all are (the usual case), else a copy of those that are."""
    keep = _nearer_than(np.ascontiguousarray(points, dtype=float), float(max_range))
    return points if keep is None else points[keep]


@njit
def _nearer_than(points: NDArray[np.float64], max_range: float) -> NDArray[np.bool_] | None:
    """None when every point's ``hypot`` is below ``max_range``, else which ones are."""
    keep = np.empty(points.shape[0], np.bool_)
    every = True
    for i in range(points.shape[0]):
        keep[i] = math.hypot(points[i, 0], points[i, 1]) < max_range
        every = every and keep[i]
    return None if every else keep


@njit
def inverse_3x3(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of a 3×3 matrix by its adjugate (cofactors over the determinant).

    The per-scan covariances are 3×3; written out, the inverse costs a few float operations where
    ``np.linalg.inv`` costs its general LAPACK call. Raises ``LinAlgError`` when singular, as
    ``np.linalg.inv`` does.
    """
    a, b, c = m[0, 0], m[0, 1], m[0, 2]
    d, e, f = m[1, 0], m[1, 1], m[1, 2]
    g, h, i = m[2, 0], m[2, 1], m[2, 2]
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co_a + b * co_b + c * co_c
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError("singular or non-finite 3×3 matrix")
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2] = co_a / det, (c * h - b * i) / det, (b * f - c * e) / det
    out[1, 0], out[1, 1], out[1, 2] = co_b / det, (a * i - c * g) / det, (c * d - a * f) / det
    out[2, 0], out[2, 1], out[2, 2] = co_c / det, (b * g - a * h) / det, (a * e - b * d) / det
    return out


@njit
def inverse_small(m: NDArray) -> NDArray:
    """Inverse of a 1×1, 2×2 or 3×3 matrix in closed form (``LinAlgError`` when singular)."""
    k = m.shape[0]
    if k == 3:
        return inverse_3x3(m)
    out = np.empty((k, k))
    if k == 1:
        if m[0, 0] == 0.0 or not math.isfinite(m[0, 0]):
            raise np.linalg.LinAlgError("singular or non-finite 1×1 matrix")
        out[0, 0] = 1.0 / m[0, 0]
        return out
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError("singular or non-finite 2×2 matrix")
    out[0, 0], out[0, 1] = m[1, 1] / det, -m[0, 1] / det
    out[1, 0], out[1, 1] = -m[1, 0] / det, m[0, 0] / det
    return out


def ray_segment_distances(
    origin: ArrayLike, dirs: NDArray[np.float64], starts: NDArray[np.float64],
    ends: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Distance t along each unit ray to each segment (B×S), ``inf`` where it misses.

    Solves ``o + t·d = a + u·(b − a)`` with 2-D cross products (Cramer's rule) and keeps
    ``t > 0``, ``0 ≤ u ≤ 1``. Rays parallel to a segment never hit it (a grazing ray sees
    the segment's end-on neighbour instead, as a real scanner would).
    """
    origin = np.asarray(origin, dtype=float)
    return _ray_segment_kernel(float(origin[0]), float(origin[1]), _rows(dirs), _rows(starts),
                               _rows(ends))


def _rows(values: ArrayLike) -> NDArray[np.float64]:
    """A C-contiguous float64 array (the kernels are compiled for that layout only)."""
    return np.ascontiguousarray(values, dtype=float)


@njit
def _ray_segment_kernel(ox: float, oy: float, dirs: NDArray, starts: NDArray, ends: NDArray
                        ) -> NDArray:
    t = np.empty((len(dirs), len(starts)))
    for j in range(len(starts)):
        p0x, p0y = starts[j, 0] - ox, starts[j, 1] - oy
        ex, ey = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1]
        for i in range(len(dirs)):
            t[i, j] = ray_hit(dirs[i, 0], dirs[i, 1], p0x, p0y, ex, ey)
    return t


@njit
def ray_hit(dx: float, dy: float, p0x: float, p0y: float, ex: float, ey: float) -> float:
    """Distance along the unit ray (dx, dy) from the origin to the segment from (p0x, p0y)
    (relative to the origin) along (ex, ey); ``inf`` where it misses (Cramer's rule)."""
    # ±inf for parallel rays (and overflow for nearly parallel ones): u becomes ±inf or nan →
    # a miss
    inv = 1.0 / (dx * ey - dy * ex)
    t, u = (p0x * ey - p0y * ex) * inv, (dy * p0x - dx * p0y) * inv
    return t if (not (u < 0.0 or u > 1.0) and t > 1e-9) else np.inf


@njit
def positive_definite(m: NDArray[np.float64]) -> bool:
    """Is the symmetric 1×1, 2×2 or 3×3 ``m`` positive definite: are its leading principal
    minors all positive (Sylvester's criterion)? A few products where a Cholesky factorisation
    costs a LAPACK call; NaN fails."""
    k = m.shape[0]
    if not m[0, 0] > 0.0:
        return False
    if k == 1:
        return True
    minor2 = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    if not minor2 > 0.0:
        return False
    if k == 2:
        return True
    det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
           - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
           + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
    return bool(det > 0.0)

"""A scan's points as every stage takes them: the usable ones (finite, within
:data:`MAX_POINT_COORDINATE`), what was dropped, and how far they reach."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.jit import njit

MAX_POINT_COORDINATE = 1e6
"""m; a point with a coordinate beyond this is no range reading (a corrupt value) and is dropped
with the non-finite ones: its square would overflow the distances computed from it."""


def clean_points(points_xy: ArrayLike) -> tuple[NDArray[np.float64], int]:
    """Finite points within ``MAX_POINT_COORDINATE`` as an N×2 float array, and how many were
    dropped."""
    pts = np.asarray(points_xy, dtype=float)
    if pts.size == 0:
        return np.empty((0, 2)), 0
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must be an N×2 array of (x, y), got shape {pts.shape}")
    if _all_usable(pts, MAX_POINT_COORDINATE):  # the usual case: one compiled pass, no mask
        return pts, 0
    usable = (np.abs(pts) <= MAX_POINT_COORDINATE).all(axis=1)  # False for NaN too
    return pts[usable], int((~usable).sum())


def scan_reach(points: NDArray[np.float64]) -> float:
    """How far map lines can be seen in these (non-empty) points: the farthest point plus half a
    metre, rounded up to whole metres so that the map's memoised visibility is reused. Points
    :func:`clean_points` would drop do not count."""
    return float(math.ceil(math.sqrt(_max_norm_sq(np.ascontiguousarray(points, dtype=float),
                                                  MAX_POINT_COORDINATE)) + 0.5))


@njit
def _all_usable(points: NDArray[np.float64], bound: float) -> bool:
    for i in range(points.shape[0]):
        for j in range(points.shape[1]):
            if not abs(points[i, j]) <= bound:  # NaN too
                return False
    return True


@njit
def _max_norm_sq(points: NDArray[np.float64], bound: float) -> float:
    top = 0.0
    for i in range(points.shape[0]):
        x, y = points[i, 0], points[i, 1]
        if abs(x) <= bound and abs(y) <= bound:  # not NaN either
            top = max(top, x * x + y * y)
    return top


def what_was_dropped(points_xy: ArrayLike) -> str:
    """What :func:`clean_points` dropped, for the reason (only asked when it dropped some)."""
    pts = np.asarray(points_xy, dtype=float)
    finite = np.isfinite(pts)
    far = f"beyond {MAX_POINT_COORDINATE:g} m"
    if finite.all():
        return far
    return f"non-finite or {far}" if (np.abs(pts[finite]) > MAX_POINT_COORDINATE).any() else (
        "non-finite")

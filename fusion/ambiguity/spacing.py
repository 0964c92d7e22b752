"""How far apart the parallel lines are that nearest-neighbour matching could confuse: the map's
closest pair, and the closest pair in view from a pose. Tracking is given up when the position's
σ grows past a fraction of it (max_position_sigma_fraction).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from houghloc import SegmentMap
from houghloc.geometry import wrap_angle

SAME_WALL_GAP = 0.05  # m: parallel references closer than this are pieces of one wall


def visible_parallel_spacing(theta: NDArray, rho: NDArray, angle_tol: float = math.radians(2.0),
                             min_gap: float = SAME_WALL_GAP) -> float:
    """The smallest ρ difference between references seen at the same robot-frame θ: the lines
    that nearest-neighbour matching can confuse from here (inf if there are none)."""
    if len(theta) < 2:
        return math.inf
    dth = np.abs(wrap_angle(theta[:, None] - theta[None, :]))
    gap = np.abs(rho[:, None] - rho[None, :])
    # pieces of one wall a few centimetres apart (a map built from scans) are one wall
    close = (dth < angle_tol) & (gap > min_gap)
    return float(gap[close].min()) if close.any() else math.inf


def closest_parallel_spacing(m: SegmentMap, angle_tol: float = math.radians(2.0)) -> float:
    """The smallest distance between two parallel map lines (how far nearest-neighbour matching
    can be trusted); large when no two lines are parallel.

    Lines sorted by direction (mod π) are compared with their k-th neighbour for k = 1, 2, …
    while some pair is still within ``angle_tol``: memory stays linear in the lines, and time
    grows with the size of the largest family of parallel lines, not with its square of all."""
    a, r = m.line_alpha, m.line_r
    n = len(a)
    if n < 2:
        return math.inf
    folded = np.mod(a, np.pi)
    order = np.argsort(folded)
    # the circle of directions, unrolled once so that lines near 0 and near π are neighbours
    ext = np.concatenate((order, order))
    ext_dir = np.concatenate((folded[order], folded[order] + np.pi))
    best = math.inf
    for k in range(1, n):
        i, j = ext[:n], ext[k:k + n]
        close = ext_dir[k:k + n] - ext_dir[:n] < angle_tol
        if not close.any():
            break
        i, j = i[close], j[close]
        same_sense = np.abs(a[i] - a[j]) < np.pi / 2
        gap = np.abs(np.where(same_sense, r[i] - r[j], r[i] + r[j]))
        gap = gap[gap > SAME_WALL_GAP]
        if gap.size:
            best = min(best, float(gap.min()))
    return best

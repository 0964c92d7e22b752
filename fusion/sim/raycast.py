"""Vectorised planar geometry for the simulator: rays against discs, distances (rays against
segments: :func:`houghloc.geometry.ray_segment_distances`).

Segments are arrays of starts and ends (S×2); discs are (D×3) rows ``[x, y, r]``. Every function
works on whole arrays of rays/points at once (no Python loop over beams or points).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def ray_disc_distances(origin: FloatArray, dirs: FloatArray, discs: FloatArray) -> FloatArray:
    """Distance t along each unit ray to the near side of each disc (B×D), ``inf`` on a miss.

    ``|o + t·d − c|² = r²`` gives ``t = b − √(b² − (|c − o|² − r²))`` with ``b = d·(c − o)``.
    A disc that contains the origin is ignored: a sensor inside an obstacle sees past it.
    """
    if len(discs) == 0:
        return np.full((len(dirs), 0), np.inf)
    rel = discs[:, :2] - origin  # D×2
    c2 = np.einsum("ij,ij->i", rel, rel) - discs[:, 2] ** 2  # D
    b = dirs @ rel.T  # B×D
    disc = b * b - c2
    with np.errstate(invalid="ignore"):
        t = b - np.sqrt(disc)
    hit = (disc >= 0.0) & (t > 1e-9) & (c2 > 0.0)
    return np.where(hit, t, np.inf)


def point_segment_distances(points: FloatArray, starts: FloatArray, ends: FloatArray) -> FloatArray:
    """Euclidean distance from each point to each segment (P×S)."""
    if len(starts) == 0:
        return np.full((len(points), 0), np.inf)
    e = ends - starts  # S×2
    ee = np.maximum(np.einsum("ij,ij->i", e, e), 1e-18)
    rel_x = points[:, :1] - starts[:, 0]  # P×S
    rel_y = points[:, 1:] - starts[:, 1]
    u = np.clip((rel_x * e[:, 0] + rel_y * e[:, 1]) / ee, 0.0, 1.0)
    return np.hypot(rel_x - u * e[:, 0], rel_y - u * e[:, 1])


def min_distance(points: FloatArray, starts: FloatArray, ends: FloatArray) -> FloatArray:
    """Distance from each point to the nearest segment (P,), ``inf`` if there are none."""
    d = point_segment_distances(points, starts, ends)
    return d.min(axis=1) if d.shape[1] else np.full(len(points), np.inf)


def segments_cross(
    a0: FloatArray, a1: FloatArray, starts: FloatArray, ends: FloatArray
) -> NDArray[np.bool_]:
    """Whether each moving segment a0→a1 (P×2 each) touches or crosses each segment (P×S).

    Orientation test: the endpoints of each segment lie on opposite sides of (or on) the other's
    line. Used to prove that a path never passes through a wall.
    """

    def orient(p, q, r):  # sign of the cross product (q − p) × (r − p), broadcast P×S
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (
            q[..., 1] - p[..., 1]
        ) * (r[..., 0] - p[..., 0])

    def within_box(p, q, r):  # r inside the bounding box of p, q (for collinear touching)
        return (
            (np.minimum(p[..., 0], q[..., 0]) <= r[..., 0])
            & (r[..., 0] <= np.maximum(p[..., 0], q[..., 0]))
            & (np.minimum(p[..., 1], q[..., 1]) <= r[..., 1])
            & (r[..., 1] <= np.maximum(p[..., 1], q[..., 1]))
        )

    A0, A1 = a0[:, None, :], a1[:, None, :]
    S0, S1 = starts[None, :, :], ends[None, :, :]
    d1, d2 = orient(S0, S1, A0), orient(S0, S1, A1)
    d3, d4 = orient(A0, A1, S0), orient(A0, A1, S1)
    proper = (d1 * d2 < 0.0) & (d3 * d4 < 0.0)
    touch = (
        ((d1 == 0) & within_box(S0, S1, A0))
        | ((d2 == 0) & within_box(S0, S1, A1))
        | ((d3 == 0) & within_box(A0, A1, S0))
        | ((d4 == 0) & within_box(A0, A1, S1))
    )
    return proper | touch


def segment_segment_distance(
    a0: FloatArray, a1: FloatArray, starts: FloatArray, ends: FloatArray
) -> FloatArray:
    """Shortest distance between each segment a0→a1 (P) and each map segment (P×S)."""
    ends_to_walls = np.minimum(
        point_segment_distances(a0, starts, ends), point_segment_distances(a1, starts, ends)
    )
    walls_to_leg = np.minimum(
        point_segment_distances(starts, a0, a1), point_segment_distances(ends, a0, a1)
    ).T
    d = np.minimum(ends_to_walls, walls_to_leg)
    return np.where(segments_cross(a0, a1, starts, ends), 0.0, d)

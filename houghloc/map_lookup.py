"""The map as the global matcher and the polish look it up, built once per map and kept beside
it: the angle index of map-line pairs (hypothesis generation, :mod:`houghloc.pose_hypotheses`),
the distance transform of its walls (every score) and the walls near each cell (the polish,
:mod:`houghloc.polish`). Each is cached on the :class:`SegmentMap` by its
settings and freed with it.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from houghloc.geometry import TWO_PI
from houghloc.jit import njit
from houghloc.polish import WallCells, build_wall_cells
from houghloc.segment_map import MapError, SegmentMap, check_grid_size


@dataclass(frozen=True)
class AngleIndex:
    """Ordered pairs (a, b) of oriented map lines, sorted by δ = β_b − β_a ∈ [0, 2π).

    Entries near 0 and 2π are repeated shifted by ∓2π so a window never needs to wrap. For each
    pair the inverse of N = [[cos β_a, sin β_a], [cos β_b, sin β_b]] is stored: the position of a
    hypothesis is then one 2×2 product, x = N⁻¹ (r − ρ).
    """

    delta: NDArray[np.float64]
    beta_a: NDArray[np.float64]
    beta_b: NDArray[np.float64]
    r_a: NDArray[np.float64]
    r_b: NDArray[np.float64]
    n_inv: NDArray[np.float64]  # E×2×2
    line_a: NDArray[np.intp]
    line_b: NDArray[np.intp]
    cos_a: NDArray[np.float64]  # cos β_a and sin β_a: a heading cut without a modulo
    sin_a: NDArray[np.float64]


@dataclass(frozen=True)
class WallDistance:
    """Distance (m) from each cell centre to the nearest wall; ``origin`` is the lower-left corner
    of cell (0, 0), rows along y. Points outside the grid are infinitely far from walls."""

    distance: NDArray[np.float32]
    origin: NDArray[np.float64]
    cell: float

    def lookup(self, x: NDArray, y: NDArray) -> NDArray[np.float32]:
        """Distances at world points (any shape), O(1) each: the value of the cell holding the
        point (the grid's outermost ring holds +inf, so clipping the indices is the only bounds
        check)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return self.at(_IDENTITY, x, y)[0]

    def lookup_smooth(self, x: NDArray, y: NDArray) -> NDArray[np.float32]:
        """Distances interpolated bilinearly between cell centres: continuous in the position,
        where :meth:`lookup` jumps by a cell (a point exactly on a wall may read one cell off)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return self.at(_IDENTITY, x, y, smooth=True)[0]

    def at(self, poses: NDArray, x: NDArray, y: NDArray, smooth: bool = False
           ) -> NDArray[np.float32]:
        """Distances at robot-frame points (``x``, ``y``, any shape S) placed in the world at each
        of ``poses`` (P×3): P×S, the points' world coordinates never stored.

        World point: (x₀ + x cos θ − y sin θ, y₀ + x sin θ + y cos θ). ``smooth``: the bilinear
        value of :meth:`lookup_smooth`, else the cell's of :meth:`lookup`.
        """
        shape = np.shape(x)
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        out = _distances_at(self.distance, self.origin[0], self.origin[1], 1.0 / self.cell,
                            poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]),
                            _flat(x), _flat(y), smooth)
        return out.reshape((len(poses),) + shape)

    def on_walls(self, poses: NDArray, x: NDArray, y: NDArray, within: float
                 ) -> NDArray[np.float64]:
        """The fraction of robot-frame points (``x``, ``y``) placed at each of ``poses`` (P×3)
        whose cell's distance (:meth:`at`, float32) is at most ``within`` (in float32, as NumPy
        compares them): (P,), in one pass, no P×N array."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        return _on_walls_at(self.distance, self.origin[0], self.origin[1], 1.0 / self.cell,
                            poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]), _flat(x), _flat(y),
                            np.float32(within))

    def rows_on_walls(self, poses: NDArray, x: NDArray, y: NDArray, within: float,
                      coverage: float) -> NDArray[np.bool_]:
        """Whether at least ``coverage`` of each row of robot-frame points (``x``, ``y``: K×S)
        placed at each of ``poses`` (P×3) lie on walls, as :meth:`on_walls` counts them: P×K.
        A row stops being looked up once its answer is decided (most poses are wrong; with
        four samples and a coverage of 0.6, two misses settle a row)."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return _rows_on_walls_at(self.distance, self.origin[0], self.origin[1], 1.0 / self.cell,
                                 poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]),
                                 np.ascontiguousarray(x.reshape(len(x), -1)),
                                 np.ascontiguousarray(y.reshape(len(y), -1)),
                                 np.float32(within), float(coverage))

    def closeness(self, poses: NDArray, x: NDArray, y: NDArray, reach: float,
                  smooth: bool = False) -> NDArray[np.float64]:
        """How close robot-frame points (``x``, ``y``) placed at each of ``poses`` (P×3) lie
        to walls: the mean over the points of max(0, 1 − (d / ``reach``)²), d their distance
        (P,). Not ``smooth``: d is the cell's value less a cell (its quantisation is not
        evidence); ``smooth``: interpolated as :meth:`lookup_smooth`. One pass, no P×N array."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        return _closeness_at(self.distance, self.origin[0], self.origin[1], 1.0 / self.cell,
                             poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]), _flat(x),
                             _flat(y), smooth, 0.0 if smooth else self.cell, 1.0 / reach)


_IDENTITY = np.zeros((1, 3))


def _flat(values: NDArray) -> NDArray[np.float64]:
    """One contiguous float64 row (the kernels are compiled for that layout only)."""
    return np.ascontiguousarray(np.ravel(values), dtype=float)


@njit
def _distance(grid: NDArray, fx: float, fy: float, smooth: bool) -> float:
    """The distance at grid coordinates (``fx``, ``fy``) (cells from the origin): the cell's
    value, or bilinear between cell centres when ``smooth``."""
    h, w = grid.shape
    if not smooth:  # truncation is floor inside the grid; outside, the +inf ring
        return grid[min(max(int(fy), 0), h - 1), min(max(int(fx), 0), w - 1)]
    fx, fy = fx - 0.5, fy - 0.5  # from cell centres
    x0 = min(max(math.floor(fx), 0), w - 2)
    y0 = min(max(math.floor(fy), 0), h - 2)
    ax, ay = min(max(fx - x0, 0.0), 1.0), min(max(fy - y0, 0.0), 1.0)
    top = grid[y0, x0] * (1 - ax) + grid[y0, x0 + 1] * ax
    bottom = grid[y0 + 1, x0] * (1 - ax) + grid[y0 + 1, x0 + 1] * ax
    d = top * (1 - ay) + bottom * ay
    return np.inf if math.isnan(d) else d  # inf · 0 at the rim: far from walls


@njit
def _distances_at(grid: NDArray, ox: float, oy: float, inv_cell: float, poses: NDArray,
                  cos_t: NDArray, sin_t: NDArray, x: NDArray, y: NDArray, smooth: bool
                  ) -> NDArray[np.float32]:
    out = np.empty((len(poses), len(x)), np.float32)
    for p in range(len(poses)):
        c, s, px, py = cos_t[p], sin_t[p], poses[p, 0], poses[p, 1]
        for k in range(len(x)):
            out[p, k] = _distance(grid, (px + c * x[k] - s * y[k] - ox) * inv_cell,
                                  (py + s * x[k] + c * y[k] - oy) * inv_cell, smooth)
    return out


@njit
def _on_walls_at(grid: NDArray, ox: float, oy: float, inv_cell: float, poses: NDArray,
                 cos_t: NDArray, sin_t: NDArray, x: NDArray, y: NDArray, within: np.float32
                 ) -> NDArray[np.float64]:
    out = np.zeros(len(poses))
    for p in range(len(poses)):
        c, s, px, py = cos_t[p], sin_t[p], poses[p, 0], poses[p, 1]
        count = 0
        for k in range(len(x)):
            d = np.float32(_distance(grid, (px + c * x[k] - s * y[k] - ox) * inv_cell,
                                     (py + s * x[k] + c * y[k] - oy) * inv_cell, False))
            if d <= within:
                count += 1
        if len(x):
            out[p] = count / len(x)
    return out


@njit
def _rows_on_walls_at(grid: NDArray, ox: float, oy: float, inv_cell: float, poses: NDArray,
                      cos_t: NDArray, sin_t: NDArray, x: NDArray, y: NDArray,
                      within: np.float32, coverage: float) -> NDArray[np.bool_]:
    n_rows, n_cols = x.shape
    out = np.empty((len(poses), n_rows), np.bool_)
    for p in range(len(poses)):
        c, s, px, py = cos_t[p], sin_t[p], poses[p, 0], poses[p, 1]
        for r in range(n_rows):
            hits = 0
            for k in range(n_cols):
                d = np.float32(_distance(grid, (px + c * x[r, k] - s * y[r, k] - ox) * inv_cell,
                                         (py + s * x[r, k] + c * y[r, k] - oy) * inv_cell,
                                         False))
                if d <= within:
                    hits += 1
                # the fraction is monotone in the hits: decided once reached or out of reach
                if hits / n_cols >= coverage or (hits + n_cols - 1 - k) / n_cols < coverage:
                    break
            out[p, r] = hits / n_cols >= coverage
    return out


@njit
def _closeness_at(grid: NDArray, ox: float, oy: float, inv_cell: float, poses: NDArray,
                  cos_t: NDArray, sin_t: NDArray, x: NDArray, y: NDArray, smooth: bool,
                  less: float, inv_reach: float) -> NDArray[np.float64]:
    out = np.empty(len(poses))
    for p in range(len(poses)):
        c, s, px, py = cos_t[p], sin_t[p], poses[p, 0], poses[p, 1]
        total = 0.0
        for k in range(len(x)):
            d = _distance(grid, (px + c * x[k] - s * y[k] - ox) * inv_cell,
                          (py + s * x[k] + c * y[k] - oy) * inv_cell, smooth)
            e = max(d - less, 0.0) * inv_reach
            if e < 1.0:
                total += 1.0 - e * e
        out[p] = total / max(len(x), 1)
    return out


def _cached(map: SegmentMap, key: tuple, build):
    """Per-map memo (dropped with the map): the index and the grid are built once per map."""
    store = _CACHE.setdefault(map, {})
    if key not in store:
        store[key] = build()
    return store[key]


def map_lines_of_kinds(map: SegmentMap, kinds: tuple[str, ...]) -> NDArray[np.intp]:
    """Canonical lines with at least one segment of the given kinds."""
    segs = map.kind_mask(kinds)
    return np.unique(map.line_of_segment[segs])


def angle_index(map: SegmentMap, kinds: tuple[str, ...], min_angle: float,
                pad: float) -> AngleIndex:
    """The (cached) angle index of a map's oriented line pairs; ``pad`` ≥ the widest window."""
    return _cached(map, ("angle_index", kinds, min_angle, pad),
                   lambda: _build_angle_index(map, kinds, min_angle, pad))


MAX_INDEX_PAIRS = 10_000_000
"""Oriented line pairs in the angle index (about 100 bytes each: 1 GB): a map of up to 1,580
distinct lines; every real building here has under 400."""


def _build_angle_index(map: SegmentMap, kinds: tuple[str, ...], min_angle: float,
                       pad: float) -> AngleIndex:
    lines = map_lines_of_kinds(map, kinds)
    if (2 * len(lines)) ** 2 > MAX_INDEX_PAIRS:
        raise MapError(f"map {map.source}: {len(lines)} distinct lines make "
                       f"{(2 * len(lines)) ** 2:,} oriented pairs for global matching's angle "
                       f"index (~{(2 * len(lines)) ** 2 * 100 / 2**30:.1f} GiB), more than the "
                       f"{MAX_INDEX_PAIRS:,} allowed")
    beta = np.concatenate((map.line_alpha[lines], map.line_alpha[lines] + np.pi))
    r = np.concatenate((map.line_r[lines], -map.line_r[lines]))
    line = np.concatenate((lines, lines))
    grid_a, grid_b = np.meshgrid(np.arange(len(beta)), np.arange(len(beta)), indexing="ij")
    a, b = grid_a.ravel(), grid_b.ravel()
    delta = np.mod(beta[b] - beta[a], TWO_PI)
    keep = (line[a] != line[b]) & (np.abs(np.sin(delta)) >= math.sin(min_angle))
    a, b, delta = a[keep], b[keep], delta[keep]
    # repeat the ends of the circle so that [δ − tol, δ + tol] is one contiguous range
    low, high = delta < pad, delta > TWO_PI - pad
    a = np.concatenate((a, a[low], a[high]))
    b = np.concatenate((b, b[low], b[high]))
    delta = np.concatenate((delta, delta[low] + TWO_PI, delta[high] - TWO_PI))
    order = np.argsort(delta, kind="stable")
    a, b, delta = a[order], b[order], delta[order]
    ca, sa, cb, sb = np.cos(beta[a]), np.sin(beta[a]), np.cos(beta[b]), np.sin(beta[b])
    det = ca * sb - sa * cb  # = sin δ, bounded away from 0 by min_angle
    n_inv = np.stack((np.stack((sb, -sa), -1), np.stack((-cb, ca), -1)), -2) / det[:, None, None]
    return AngleIndex(delta, beta[a], beta[b], r[a], r[b], n_inv, line[a], line[b], ca, sa)


def wall_distance(map: SegmentMap, kinds: tuple[str, ...], cell: float,
                  margin: float = 1.0) -> WallDistance:
    """The (cached) distance-transform grid of the map's segments of ``kinds``."""
    return _cached(map, ("wall_distance", kinds, cell, margin),
                   lambda: _build_wall_distance(map, kinds, cell, margin))


def _build_wall_distance(map: SegmentMap, kinds: tuple[str, ...], cell: float,
                         margin: float) -> WallDistance:
    segs = np.flatnonzero(map.kind_mask(kinds))
    ends = np.concatenate((map.starts[segs], map.ends[segs]))
    origin = ends.min(axis=0) - margin
    w, h = np.ceil((ends.max(axis=0) + margin - origin) / cell).astype(int) + 1
    check_grid_size((h, w), cell, f"map {map.source}")
    # walls are drawn as 0 on a 255 background; the transform gives each cell's distance (in
    # cells, exact Euclidean) to the nearest wall pixel
    image = np.full((h, w), 255, dtype=np.uint8)
    shift = 4  # sub-pixel precision of the drawn segments
    p0 = np.round((map.starts[segs] - origin) / cell * (1 << shift) - 0.5 * (1 << shift))
    p1 = np.round((map.ends[segs] - origin) / cell * (1 << shift) - 0.5 * (1 << shift))
    for a, b in zip(p0.astype(int), p1.astype(int), strict=True):  # once per map
        cv2.line(image, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 0, 1, cv2.LINE_8, shift)
    dist = (cv2.distanceTransform(image, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * cell)
    dist[[0, -1], :] = dist[:, [0, -1]] = np.inf  # off the grid is far from every wall
    return WallDistance(dist.astype(np.float32), origin, cell)


def wall_cells(map: SegmentMap, kinds: tuple[str, ...], gate: float) -> WallCells:
    """The (cached) segments of ``kinds`` near each cell of side ``gate``
    (:func:`houghloc.polish.build_wall_cells`)."""
    return _cached(map, ("wall_cells", kinds, gate), lambda: build_wall_cells(map, kinds, gate))


def inside_map(poses: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                margin: float) -> NDArray[np.bool_]:
    """Which poses lie within ``margin`` of the bounding box of the map's segments of ``kinds``."""
    lo, hi = map_box(map, kinds, margin)
    return _in_box(np.asarray(poses, dtype=float).reshape(-1, 3), lo[0], lo[1], hi[0], hi[1])


def map_box(map: SegmentMap, kinds: tuple[str, ...], margin: float
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The (cached) lower and upper corners of the map's box (:func:`map_bbox`) widened by
    ``margin``: what :func:`inside_map` keeps poses in."""
    def build() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        lo, hi = map_bbox(map, kinds)
        return lo - margin, hi + margin
    return _cached(map, ("box", kinds, margin), build)


@njit
def _in_box(poses: NDArray, x0: float, y0: float, x1: float, y1: float) -> NDArray[np.bool_]:
    out = np.empty(len(poses), np.bool_)
    for p in range(len(poses)):
        out[p] = x0 <= poses[p, 0] <= x1 and y0 <= poses[p, 1] <= y1
    return out


class SegmentSpans:
    """Where the segments of each oriented map line lie along it: the intervals [lo, hi] of
    s along u = (−sin β, cos β), widened by ``margin`` at both ends (a point that close is on
    the wall), one row per oriented line (the canonical lines ``mlines``, then the same lines
    turned by π), padded with empty intervals. Built once per map (:func:`segment_spans`)."""

    def __init__(self, map: SegmentMap, mlines: NDArray[np.intp], kinds: tuple[str, ...],
                 margin: float) -> None:
        segs = np.flatnonzero(map.kind_mask(kinds))
        row = np.searchsorted(mlines, map.line_of_segment[segs])
        s0, s1 = map.seg_s0[segs] - margin, map.seg_s1[segs] + margin
        n = len(mlines)
        # turned by π, u is reversed: the interval [s0, s1] becomes [−s1, −s0]
        row, lo, hi = np.r_[row, row + n], np.r_[s0, -s1], np.r_[s1, -s0]
        order = np.argsort(row, kind="stable")
        row, lo, hi = row[order], lo[order], hi[order]
        counts = np.bincount(row, minlength=2 * n)
        col = np.arange(len(row)) - np.repeat(np.cumsum(counts) - counts, counts)
        self.starts = np.full((2 * n, max(int(counts.max(initial=0)), 1)), np.inf)
        self.ends = np.full_like(self.starts, -np.inf)
        self.starts[row, col], self.ends[row, col] = lo, hi
        self.lo, self.hi = self.starts.min(axis=1), self.ends.max(axis=1)

    def coverage(self, which: NDArray[np.intp], s0: NDArray, s1: NDArray) -> NDArray:
        """The fraction of each interval [s0, s1] along oriented line ``which`` that lies on
        its segments (overlapping segments may count twice: at most 1 is reported)."""
        overlap = (np.minimum(self.ends[which], np.asarray(s1)[:, None])
                   - np.maximum(self.starts[which], np.asarray(s0)[:, None]))
        length = np.maximum(np.asarray(s1) - np.asarray(s0), 1e-9)
        return np.minimum(np.clip(overlap, 0.0, None).sum(axis=1) / length, 1.0)


def segment_spans(map: SegmentMap, kinds: tuple[str, ...], margin: float) -> SegmentSpans:
    """The (cached) :class:`SegmentSpans` of the map's lines of ``kinds``."""
    return _cached(map, ("segment_spans", kinds, margin),
                   lambda: SegmentSpans(map, map_lines_of_kinds(map, kinds), kinds, margin))


def map_bbox(map: SegmentMap, kinds: tuple[str, ...]) -> tuple[NDArray, NDArray]:
    """The lower and upper corners of the box around the map's segments of ``kinds``."""
    segs = map.kind_mask(kinds)
    ends = np.concatenate((map.starts[segs], map.ends[segs]))
    return ends.min(axis=0), ends.max(axis=0)


_CACHE: weakref.WeakKeyDictionary[SegmentMap, dict] = weakref.WeakKeyDictionary()

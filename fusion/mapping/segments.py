"""Segments from an occupancy grid: stages 2–6 of :mod:`fusion.mapping`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fusion.mapping.grid import OccupancyGrid
from houghloc.segment_map import SegmentMap

_CANDIDATE_BLUR_CELLS = 1.5  # Gaussian σ before line detection, in cells
_FREE_SIDE_OFFSETS = (3, 4, 5, 6)  # cells from a wall where its observed side must be free
_MAX_REFIT_TURN_COS = math.cos(math.radians(5.0))  # a refit may turn a detection this much


@dataclass(frozen=True)
class _Lines:
    """Fitted lines: a point on each, its unit direction, and an extent [s0, s1] along it
    (measured from ``point``)."""

    point: NDArray[np.float64]
    direction: NDArray[np.float64]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.column_stack((-self.direction[:, 1], self.direction[:, 0]))

    @property
    def starts(self) -> NDArray[np.float64]:
        return self.point + self.s0[:, None] * self.direction

    @property
    def ends(self) -> NDArray[np.float64]:
        return self.point + self.s1[:, None] * self.direction

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0

    def __len__(self) -> int:
        return len(self.point)


def extract_segments(
    grid: OccupancyGrid,
    min_length: float = 0.5,
    *,
    angle_tol: float = math.radians(3.0),
    offset_tol_cells: float = 1.5,
    bridge_gap: float = 0.25,
    occlusion_gap: float = 1.0,
    door_gap: float = 2.0,
    duplicate_offset: float = 0.15,
    duplicate_angle: float = math.radians(6.0),
    name: str = "map",
) -> SegmentMap:
    """Wall segments of an occupancy grid (see the module docstring for the stages).

    ``angle_tol``/``offset_tol_cells``: how far a detection may deviate from a wall line and still
    belong to it. Gaps along a wall shorter than ``bridge_gap`` are closed; gaps up to
    ``occlusion_gap`` are closed only where the grid has no free cell (an occluded stretch of
    wall, not a doorway); longer gaps, and any gap with free space, split the wall into separate
    segments that still share one line when within ``door_gap``. Segments shorter than
    ``min_length`` are dropped. Near-duplicate lines of one wall face (within
    ``duplicate_angle``, both ends within ``duplicate_offset``, free space on the same side, at
    most ``door_gap`` apart along the wall) are merged onto one line. All segments are walls,
    with ids ``w0, w1, …`` (longest first).
    """
    points, _cells = grid.occupied_points()
    if len(points) < 2:
        raise ValueError("the grid has fewer than two occupied cells: no wall to extract")
    res = grid.resolution
    tree = cKDTree(points)
    candidates = _detect_candidates(grid)
    # LSD's edges of the blurred image lie about one σ outside the wall: gather widely first,
    # then again around the refitted line.
    candidates = _refine(candidates, points, tree, (_CANDIDATE_BLUR_CELLS + 1.5) * res, 2 * res)
    candidates = _refine(candidates, points, tree, offset_tol_cells * res, 2 * res)
    groups = _group_collinear(candidates, angle_tol, offset_tol_cells * res, door_gap)
    segments, facing = _segments_on_lines(
        groups, grid, points, tree, support_tol=offset_tol_cells * res,
        bridge_gap=bridge_gap, occlusion_gap=occlusion_gap, min_length=min_length,
    )
    segments = _merge_duplicates(segments, facing, duplicate_angle, duplicate_offset, door_gap,
                                 bridge_gap)
    if len(segments) == 0:
        raise ValueError(f"no wall segment of at least {min_length} m found in the grid")
    return _walls_longest_first(segments.starts, segments.ends, name)


def _walls_longest_first(starts: NDArray[np.float64], ends: NDArray[np.float64],
                         name: str) -> SegmentMap:
    """The wall map of these segments, longest first, with ids w0, w1, ... in that order."""
    order = np.argsort(-np.linalg.norm(ends - starts, axis=1), kind="stable")
    return SegmentMap(starts[order], ends[order], kinds=["wall"] * len(order),
                      ids=[f"w{i}" for i in range(len(order))], name=name)


def _detect_candidates(grid: OccupancyGrid) -> _Lines:
    """LSD on the occupied-cell image → candidate segments in world coordinates."""
    image = np.where(grid.occupied, 255, 0).astype(np.uint8)
    # Walls in a grid built from scans are jagged chains of cells; LSD needs level lines that
    # agree in orientation, which a blur over a few cells gives (on the raw binary image it
    # finds only short, straight stretches). The blur's edges sit beside the wall: refined later.
    blurred = cv2.GaussianBlur(image, (0, 0), _CANDIDATE_BLUR_CELLS)
    detector = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale=1.0)
    found = detector.detect(blurred)[0]
    if found is None:
        return _lines_from_ends(np.empty((0, 2)), np.empty((0, 2)))
    uv = found.reshape(-1, 4).astype(float)
    ox, oy = grid.origin
    # LSD's pixel centres sit at integer coordinates: cell j spans [j − ½, j + ½].
    a = np.column_stack((ox + (uv[:, 0] + 0.5) * grid.resolution,
                         oy + (uv[:, 1] + 0.5) * grid.resolution))
    b = np.column_stack((ox + (uv[:, 2] + 0.5) * grid.resolution,
                         oy + (uv[:, 3] + 0.5) * grid.resolution))
    long_enough = np.linalg.norm(b - a, axis=1) >= 3 * grid.resolution
    return _lines_from_ends(a[long_enough], b[long_enough])


def _lines_from_ends(a: NDArray[np.float64], b: NDArray[np.float64]) -> _Lines:
    length = np.linalg.norm(b - a, axis=1)
    direction = (b - a) / np.maximum(length, 1e-12)[:, None]
    return _Lines(a, direction, np.zeros(len(a)), length)


def _support(
    lines: _Lines, points: NDArray[np.float64], tree: cKDTree, tol: float, margin: float,
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """All (line, point) pairs with the point within ``tol`` of the line and within its extent
    ± ``margin``; returns line indices, point indices, position along and distance across."""
    if len(lines) == 0:
        empty = np.empty(0, dtype=np.intp)
        return empty, empty, np.empty(0), np.empty(0)
    mid_s = 0.5 * (lines.s0 + lines.s1)
    centre = lines.point + mid_s[:, None] * lines.direction
    radius = np.hypot(0.5 * lines.length + margin, tol)
    near = tree.query_ball_point(centre, radius)
    counts = np.fromiter((len(n) for n in near), dtype=np.intp, count=len(near))
    line = np.repeat(np.arange(len(lines)), counts)
    point = np.concatenate([np.asarray(n, dtype=np.intp) for n in near]) if counts.sum() else line
    rel = points[point] - lines.point[line]
    s = np.einsum("ij,ij->i", rel, lines.direction[line])
    d = np.abs(np.einsum("ij,ij->i", rel, lines.normal[line]))
    keep = (d <= tol) & (s >= lines.s0[line] - margin) & (s <= lines.s1[line] + margin)
    return line[keep], point[keep], s[keep], d[keep]


@dataclass(frozen=True)
class _Moments:
    """Point counts, sums and second moments per line: a total-least-squares fit in closed form
    that can be merged by adding."""

    n: NDArray[np.float64]
    sx: NDArray[np.float64]
    sy: NDArray[np.float64]
    sxx: NDArray[np.float64]
    sxy: NDArray[np.float64]
    syy: NDArray[np.float64]

    @classmethod
    def of(cls, labels: NDArray[np.intp], xy: NDArray[np.float64], count: int) -> _Moments:
        x, y = xy[:, 0], xy[:, 1]

        def total(weights: NDArray[np.float64] | None) -> NDArray[np.float64]:
            return np.bincount(labels, weights=weights, minlength=count).astype(float)

        return cls(total(None), total(x), total(y), total(x * x), total(x * y), total(y * y))

    def fit(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centroid and principal direction per line (where n ≥ 2)."""
        n = np.maximum(self.n, 1.0)
        mx, my = self.sx / n, self.sy / n
        cxx = self.sxx / n - mx * mx
        cxy = self.sxy / n - mx * my
        cyy = self.syy / n - my * my
        phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
        return np.column_stack((mx, my)), np.column_stack((np.cos(phi), np.sin(phi)))


def _refine(candidates: _Lines, points: NDArray[np.float64], tree: cKDTree, tol: float,
            margin: float) -> _Lines:
    """Refit every candidate to the occupied cells around it (TLS); extent from its cells."""
    line, point, _s, _d = _support(candidates, points, tree, tol, margin)
    moments = _Moments.of(line, points[point], len(candidates))
    centroid, direction = moments.fit()
    # Keep the candidate's orientation so its extent stays meaningful.
    flip = np.einsum("ij,ij->i", direction, candidates.direction) < 0
    direction[flip] *= -1
    rel = points[point] - centroid[line]
    s = np.einsum("ij,ij->i", rel, direction[line])
    n = len(candidates)
    s0 = np.full(n, np.inf)
    s1 = np.full(n, -np.inf)
    np.minimum.at(s0, line, s)
    np.maximum.at(s1, line, s)
    ok = (moments.n >= 3) & (np.abs(np.einsum("ij,ij->i", direction, candidates.direction))
                             >= _MAX_REFIT_TURN_COS)
    return _Lines(centroid[ok], direction[ok], s0[ok], s1[ok])


def _group_collinear(lines: _Lines, angle_tol: float, offset_tol: float,
                     door_gap: float) -> _Lines:
    """Greedy grouping, longest detection first: a detection joins the first group whose line it
    matches (direction within ``angle_tol``, both ends within ``offset_tol``) and whose extent it
    overlaps or nearly touches (gap ≤ ``door_gap``); otherwise it starts a group.

    The loop runs over detections (hundreds), each step vectorised over the groups. A group's
    line is refitted from the length-weighted ends of its members as they join, so long walls
    dominate and a chain of slightly rotated pieces cannot drift.
    """
    order = np.argsort(-lines.length, kind="stable")
    starts, ends = lines.starts, lines.ends
    g_point = np.empty((0, 2))
    g_dir = np.empty((0, 2))
    g_s = np.empty((0, 2))
    g_mom = np.empty((0, 6))
    cos_tol = math.cos(angle_tol)
    for i in order:
        a, b = starts[i], ends[i]
        d = lines.direction[i]
        if len(g_point):
            hit = np.flatnonzero(_on_group_line(a, b, d, g_point, g_dir, cos_tol, offset_tol)
                                 & (_gap_to_extent(a, b, g_point, g_dir, g_s) <= door_gap))
        else:
            hit = np.empty(0, dtype=np.intp)
        weight = float(lines.length[i])
        mom = weight * _end_moments(a, b)
        if len(hit):
            g = hit[0]
            old_ends = g_point[g] + g_s[g][:, None] * g_dir[g]  # the group's ends, in the world
            g_mom[g] += mom
            g_point[g], new_dir = _fit_moments(g_mom[g])
            g_dir[g] = new_dir if new_dir @ g_dir[g] >= 0 else -new_dir
            # The refitted line moved: re-express the old extent and add the new member's.
            s_all = (np.vstack((old_ends, a, b)) - g_point[g]) @ g_dir[g]
            g_s[g] = [s_all.min(), s_all.max()]
        else:
            g_point = np.vstack((g_point, 0.5 * (a + b)))
            g_dir = np.vstack((g_dir, d))
            half = 0.5 * float(lines.length[i])
            g_s = np.vstack((g_s, [-half, half]))
            g_mom = np.vstack((g_mom, mom))
    return _Lines(g_point, g_dir, g_s[:, 0], g_s[:, 1])


def _on_group_line(a: NDArray[np.float64], b: NDArray[np.float64], d: NDArray[np.float64],
                   point: NDArray[np.float64], direction: NDArray[np.float64], cos_tol: float,
                   offset_tol: float) -> NDArray[np.bool_]:
    """Per group (a line through ``point`` along ``direction``): does the segment a–b of
    direction d lie on it, its direction within the angle whose cosine is ``cos_tol`` and both
    its ends within ``offset_tol``?"""
    normal = np.column_stack((-direction[:, 1], direction[:, 0]))
    off_a = np.abs(np.einsum("ij,ij->i", a - point, normal))
    off_b = np.abs(np.einsum("ij,ij->i", b - point, normal))
    return (np.abs(direction @ d) >= cos_tol) & (off_a <= offset_tol) & (off_b <= offset_tol)


def _gap_to_extent(a: NDArray[np.float64], b: NDArray[np.float64], point: NDArray[np.float64],
                   direction: NDArray[np.float64], extent: NDArray[np.float64]
                   ) -> NDArray[np.float64]:
    """Per group: the gap along its line between the segment a–b and the group's extent [s0, s1]
    (negative where they overlap)."""
    sa = np.einsum("ij,ij->i", a - point, direction)
    sb = np.einsum("ij,ij->i", b - point, direction)
    return np.maximum(np.minimum(sa, sb) - extent[:, 1], extent[:, 0] - np.maximum(sa, sb))


def _end_moments(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Moments of a segment as a uniform distribution of mass 1 along it (not just its ends):
    the covariance of a uniform segment is ``(b − a)(b − a)ᵀ/12`` about its midpoint."""
    m = 0.5 * (a + b)
    d = b - a
    return np.array([1.0, m[0], m[1], m[0] * m[0] + d[0] * d[0] / 12,
                     m[0] * m[1] + d[0] * d[1] / 12, m[1] * m[1] + d[1] * d[1] / 12])


def _fit_moments(mom: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centroid, direction = _Moments(*(np.atleast_1d(v) for v in mom)).fit()
    return centroid[0], direction[0]


def _segments_on_lines(
    groups: _Lines,
    grid: OccupancyGrid,
    points: NDArray[np.float64],
    tree: cKDTree,
    *,
    support_tol: float,
    bridge_gap: float,
    occlusion_gap: float,
    min_length: float,
    min_fill: float = 0.6,
    min_piece: float = 0.25,
) -> tuple[_Lines, NDArray[np.float64]]:
    """Occupied cells → wall lines (refitted) → runs of cells along each line → segments, and
    each segment's facing: the unit normal pointing to the side it is seen from (free space)."""
    line, point, _s, dist = _support(groups, points, tree, support_tol, margin=occlusion_gap)
    line, point = _keep_best_of_parallel(groups, line, point, dist)
    moments = _Moments.of(line, points[point], len(groups))
    centroid, direction = moments.fit()
    # A refit that turns the line is a blob of clutter, not a wall: drop the line.
    turned = np.abs(np.einsum("ij,ij->i", direction, groups.direction)) < _MAX_REFIT_TURN_COS
    fitted = (moments.n >= 2) & ~turned
    rel = points[point] - centroid[line]
    s = np.einsum("ij,ij->i", rel, direction[line])
    across = np.abs(rel[:, 0] * direction[line, 1] - rel[:, 1] * direction[line, 0])
    keep = fitted[line] & (across <= support_tol)
    line, s = line[keep], s[keep]
    order = np.lexsort((s, line))
    line, s = line[order], s[order]

    pieces = _solid_pieces(line, s, grid.resolution, bridge_gap, min_fill, min_piece)
    pieces = _with_free_side(pieces, grid, centroid, direction)
    runs = _join_occluded_gaps(pieces, grid, centroid, direction, occlusion_gap)
    keep = runs.length >= min_length
    runs = _Runs(runs.line[keep], runs.s0[keep], runs.s1[keep])
    lines = _Lines(centroid[runs.line], direction[runs.line], runs.s0, runs.s1)
    share = _free_side_share(runs, grid, centroid, direction)
    facing = lines.normal * np.where(share[:, 0] >= share[:, 1], 1.0, -1.0)[:, None]
    return lines, facing


@dataclass(frozen=True)
class _Runs:
    """Stretches ``[s0, s1]`` of wall along the fitted lines ``line``, sorted by (line, s0)."""

    line: NDArray[np.intp]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0


def _solid_pieces(line: NDArray[np.intp], s: NDArray[np.float64], resolution: float,
                  bridge_gap: float, min_fill: float, min_piece: float) -> _Runs:
    """Cells sorted by (line, s) → pieces without gaps longer than ``bridge_gap``, kept when at
    least ``min_piece`` long and at least ``min_fill`` of their cell-steps hold a cell. Clutter
    and crossing walls put a few isolated cells on a line; a wall fills it."""
    if len(s) == 0:
        empty = np.empty(0)
        return _Runs(np.empty(0, dtype=np.intp), empty, empty)
    split = (line[1:] != line[:-1]) | (np.diff(s) > bridge_gap)
    piece = np.concatenate(([0], np.cumsum(split)))
    first = np.flatnonzero(np.concatenate(([True], split)))
    last = np.concatenate((first[1:] - 1, [len(s) - 1]))
    half = 0.5 * resolution  # a cell's point lies inside it; the wall spans the whole cell
    s0, s1 = s[first] - half, s[last] + half
    # Distinct cell-steps along the line per piece (a wall two cells thick counts once).
    step = np.floor((s - s[first][piece]) / resolution).astype(np.intp)
    distinct = np.unique(np.column_stack((piece, step)), axis=0)[:, 0]
    filled = np.bincount(distinct, minlength=len(first)) * resolution
    keep = ((s1 - s0) >= min_piece) & (filled >= min_fill * (s1 - s0))
    return _Runs(line[first][keep], s0[keep], s1[keep])


def _with_free_side(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                    direction: NDArray[np.float64], min_share: float = 0.5) -> _Runs:
    """Keep the pieces with free space along one side: a wall face is seen through free space,
    while a line drawn through a blob of clutter or a thick, smeared wall has none."""
    if len(pieces.line) == 0:
        return pieces
    keep = _free_side_share(pieces, grid, point, direction).max(axis=1) >= min_share
    return _Runs(pieces.line[keep], pieces.s0[keep], pieces.s1[keep])


def _free_side_share(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                     direction: NDArray[np.float64]) -> NDArray[np.float64]:
    """Share of free samples on each side of every piece (n × 2: along +normal, along −normal),
    sampled every cell along the piece, 3–6 cells out (free space keeps a clearance from the
    walls)."""
    if len(pieces.line) == 0:
        return np.zeros((0, 2))
    res = grid.resolution
    count = np.maximum(np.ceil(pieces.length / res).astype(np.intp), 1)
    piece = np.repeat(np.arange(len(count)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    along = pieces.s0[piece] + (k + 0.5) * res
    line = pieces.line[piece]
    base = point[line] + along[:, None] * direction[line]
    normal = np.column_stack((-direction[line, 1], direction[line, 0]))
    share = np.zeros((len(count), 2))
    for side, sign in enumerate((1.0, -1.0)):  # two sides, each vectorised over all samples
        seen_free = np.zeros(len(base), dtype=bool)
        for cells_out in _FREE_SIDE_OFFSETS:
            rows, cols = grid.world_to_cell(base + sign * cells_out * res * normal)
            inside = grid.inside(rows, cols)
            seen_free[inside] |= grid.free[rows[inside], cols[inside]]
        share[:, side] = np.bincount(piece, weights=seen_free, minlength=len(count)) / count
    return share


def _merge_duplicates(segments: _Lines, facing: NDArray[np.float64], angle_tol: float,
                      offset_tol: float, max_gap: float, bridge_gap: float) -> _Lines:
    """Merge near-duplicate lines of one wall face onto one line.

    A thick or slightly bent wall often yields two or more lines a few centimetres and a degree
    or two apart, each holding part of the wall's cells. The localizer then sees two map lines
    inside one observed wall's gate: an ambiguous match, or a fix pulled between them. Greedy,
    longest segment first: a segment joins the first cluster whose line it follows (direction
    within ``angle_tol``, both ends within ``offset_tol``), whose face looks the same way (the
    two faces of a thin wall stay apart) and whose extent is at most ``max_gap`` away along
    the line. A cluster's line is the length-weighted fit of its members; the members'
    extents, projected on it, are united where they overlap or are at most ``bridge_gap``
    apart, and stay separate segments of the one line otherwise (a wall with doors).
    """
    if len(segments) < 2:
        return segments
    order = np.argsort(-segments.length, kind="stable")
    starts, ends = segments.starts, segments.ends
    cos_tol = math.cos(angle_tol)
    c_point = np.empty((0, 2))
    c_dir = np.empty((0, 2))
    c_face = np.empty((0, 2))
    c_s = np.empty((0, 2))
    c_mom = np.empty((0, 6))
    members: list[list[int]] = []
    for i in order:
        a, b, d = starts[i], ends[i], segments.direction[i]
        hit = np.empty(0, dtype=np.intp)
        if len(c_point):
            hit = np.flatnonzero(_on_group_line(a, b, d, c_point, c_dir, cos_tol, offset_tol)
                                 & (c_face @ facing[i] > 0)
                                 & (_gap_to_extent(a, b, c_point, c_dir, c_s) <= max_gap))
        mom = float(segments.length[i]) * _end_moments(a, b)
        if len(hit):
            c = hit[0]
            members[c].append(i)
            c_mom[c] += mom
            c_point[c], new_dir = _fit_moments(c_mom[c])
            c_dir[c] = new_dir if new_dir @ c_dir[c] >= 0 else -new_dir
            ends_c = np.concatenate([(starts[k], ends[k]) for k in members[c]])
            s_all = (ends_c - c_point[c]) @ c_dir[c]
            c_s[c] = [s_all.min(), s_all.max()]
        else:
            members.append([i])
            c_point = np.vstack((c_point, 0.5 * (a + b)))
            c_dir = np.vstack((c_dir, d))
            c_face = np.vstack((c_face, facing[i]))
            half = 0.5 * float(segments.length[i])
            c_s = np.vstack((c_s, [-half, half]))
            c_mom = np.vstack((c_mom, mom))
    pieces: list[tuple[int, float, float]] = []  # (cluster, s0, s1) on the cluster's line
    for c, group in enumerate(members):
        s_ends = np.column_stack(((starts[group] - c_point[c]) @ c_dir[c],
                                  (ends[group] - c_point[c]) @ c_dir[c]))
        lo, hi = s_ends.min(axis=1), s_ends.max(axis=1)
        by = np.argsort(lo)
        cur_lo, cur_hi = lo[by[0]], hi[by[0]]
        for k in by[1:]:
            if lo[k] - cur_hi > bridge_gap:
                pieces.append((c, cur_lo, cur_hi))
                cur_lo = lo[k]
            cur_hi = max(cur_hi, hi[k])
        pieces.append((c, cur_lo, cur_hi))
    cluster = np.array([p[0] for p in pieces], dtype=np.intp)
    return _Lines(c_point[cluster], c_dir[cluster], np.array([p[1] for p in pieces]),
                  np.array([p[2] for p in pieces]))


def _join_occluded_gaps(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                        direction: NDArray[np.float64], occlusion_gap: float) -> _Runs:
    """Join consecutive pieces of one line across a gap no longer than ``occlusion_gap`` and
    than either piece, when the gap holds no free space: a stretch of wall hidden behind
    furniture. A gap with free space is a doorway the laser saw through: it stays open."""
    if len(pieces.line) < 2:
        return pieces
    length = pieces.length
    gap = pieces.s0[1:] - pieces.s1[:-1]
    candidate = ((pieces.line[1:] == pieces.line[:-1]) & (gap <= occlusion_gap)
                 & (gap <= np.minimum(length[1:], length[:-1])))
    lines = pieces.line[1:][candidate]
    joined = np.zeros(len(gap), dtype=bool)
    joined[candidate] = ~_gap_has_free_space(grid, point[lines], direction[lines],
                                             pieces.s1[:-1][candidate], pieces.s0[1:][candidate])
    start = np.flatnonzero(np.concatenate(([True], ~joined)))
    end = np.concatenate((start[1:] - 1, [len(gap)]))
    return _Runs(pieces.line[start], pieces.s0[start], pieces.s1[end])


def _keep_best_of_parallel(
    groups: _Lines, line: NDArray[np.intp], point: NDArray[np.intp], dist: NDArray[np.float64],
    parallel_cos: float = math.cos(math.radians(20.0)),
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """A cell supports at most one of several near-parallel lines (the nearest): two detections
    of one wall face must not both become segments. Crossing lines keep a shared cell, so a
    corner cell ends both walls."""
    if len(line) == 0:
        return line, point
    order = np.lexsort((dist, point))
    first = np.ones(len(order), dtype=bool)
    first[1:] = point[order][1:] != point[order][:-1]
    best_line = np.empty(point.max() + 1, dtype=np.intp)
    best_line[point[order][first]] = line[order][first]
    best = best_line[point]
    cos = np.abs(np.einsum("ij,ij->i", groups.direction[line], groups.direction[best]))
    keep = (line == best) | (cos < parallel_cos)
    return line[keep], point[keep]


def _gap_has_free_space(
    grid: OccupancyGrid, point: NDArray[np.float64], direction: NDArray[np.float64],
    s_from: NDArray[np.float64], s_to: NDArray[np.float64], min_free_share: float = 0.25,
) -> NDArray[np.bool_]:
    """For each gap along a line, whether free cells make up ≥ ``min_free_share`` of it (a
    doorway seen through), sampled every half cell strictly inside the gap."""
    if len(point) == 0:
        return np.zeros(0, dtype=bool)
    step = 0.5 * grid.resolution
    inner_from, inner_to = s_from + step, s_to - step
    count = np.maximum(np.ceil((inner_to - inner_from) / step).astype(np.intp), 1)
    gap = np.repeat(np.arange(len(point)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    s = inner_from[gap] + k * step
    xy = point[gap] + s[:, None] * direction[gap]
    rows, cols = grid.world_to_cell(xy)
    inside = grid.inside(rows, cols)
    free = np.zeros(len(xy), dtype=bool)
    free[inside] = grid.free[rows[inside], cols[inside]]
    share = np.bincount(gap, weights=free, minlength=len(point)) / count
    return share >= min_free_share


REFIT_BANDS = (0.20, 0.12, 0.08, 0.05, 0.04, 0.04)  # m, one refit pass per band


def refit_to_endpoints(
    segment_map: SegmentMap,
    endpoints: NDArray[np.float64],
    bands: tuple[float, ...] = REFIT_BANDS,
    *,
    min_points: int = 20,
    max_turn: float = math.radians(5.0),
) -> SegmentMap:
    """Stage 7, for wall maps built from scans: every line refitted to the scan endpoints.

    The grid's cells are 5 cm wide and a wall's cells are smeared by furniture standing against
    it, so a line fitted to cells can sit a few centimetres and degrees off the face the laser
    sees. Each pass assigns every endpoint to its nearest segment when it lies within ``band``
    across it and within its extent, refits each line (all segments on it together, so they stay
    collinear) by total least squares to its endpoints, and projects the segments' ends onto
    the refitted line. The bands shrink pass by pass (``bands``), so a line first gathers its
    whole face and then sheds the clutter beside it. A line keeps its place when fewer than
    ``min_points`` endpoints support it or a pass would turn it by more than ``max_turn`` (the
    endpoints then belong to something else). Ids are renumbered longest first.
    """
    if any(kind != "wall" for kind in segment_map.kinds):
        raise ValueError(f"map {segment_map.name!r}: only a map of walls can be refitted to "
                         "scan endpoints (painted lines return none)")
    starts, ends = segment_map.starts.copy(), segment_map.ends.copy()
    line_of = segment_map.line_of_segment
    n_lines = segment_map.n_lines
    min_cos = math.cos(max_turn)
    for band in bands:
        segment, xy = _endpoints_near_segments(starts, ends, endpoints, band)
        moments = _Moments.of(line_of[segment], xy, n_lines)
        centroid, direction = moments.fit()
        current = np.zeros((n_lines, 2))
        current[line_of] = (ends - starts) / np.linalg.norm(ends - starts, axis=1)[:, None]
        refit = ((moments.n >= min_points)
                 & (np.abs(np.einsum("ij,ij->i", direction, current)) >= min_cos))[line_of]
        c, d = centroid[line_of[refit]], direction[line_of[refit]]
        for ends_ in (starts, ends):  # orthogonal projection onto the refitted line
            along = np.einsum("ij,ij->i", ends_[refit] - c, d)
            ends_[refit] = c + along[:, None] * d
    return _walls_longest_first(starts, ends, segment_map.name)


def nearest_segment(
    starts: NDArray[np.float64], ends: NDArray[np.float64], points: NDArray[np.float64],
    max_distance: float, spacing: float = 0.01,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The points (indices) with a segment within about ``max_distance``, and that nearest
    segment's index for each. The segments are sampled every ``spacing`` into a k-d tree, one
    query for all points: the nearest sample names the segment, whatever the map's size. Every
    point within ``max_distance`` of a segment is found; callers check the exact distance."""
    length = np.linalg.norm(ends - starts, axis=1)
    count = np.ceil(length / spacing).astype(np.intp) + 1
    sample_of = np.repeat(np.arange(len(length)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    samples = starts[sample_of] + (k / (count[sample_of] - 1))[:, None] * (ends - starts)[sample_of]
    near, index = cKDTree(samples).query(points, distance_upper_bound=math.hypot(max_distance,
                                                                                 spacing))
    found = np.flatnonzero(np.isfinite(near))
    return found, sample_of[index[found]]


def _endpoints_near_segments(
    starts: NDArray[np.float64], ends: NDArray[np.float64], endpoints: NDArray[np.float64],
    band: float,
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The endpoints within ``band`` across their nearest segment and within its extent, with
    that segment's index."""
    found, segment = nearest_segment(starts, ends, endpoints, band, spacing=0.02)
    xy = endpoints[found]
    rel, span = xy - starts[segment], ends[segment] - starts[segment]
    length = np.linalg.norm(span, axis=1)
    along = np.einsum("ij,ij->i", rel, span) / length**2
    across = np.abs(rel[:, 0] * span[:, 1] - rel[:, 1] * span[:, 0]) / length
    keep = (along >= 0.0) & (along <= 1.0) & (across <= band)
    return segment[keep], xy[keep]

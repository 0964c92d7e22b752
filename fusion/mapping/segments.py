"""Segments from an occupancy grid: stages 2–6 of :mod:`fusion.mapping`."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fusion.mapping.grid import OccupancyGrid
from fusion.mapping.lines import (
    Moments,
    WallLines,
    end_moments,
    fit_moments,
    gap_to_extent,
    lines_from_ends,
    on_group_line,
    walls_longest_first,
)
from fusion.mapping.pieces import (
    Runs,
    free_side_share,
    join_occluded_gaps,
    merge_duplicates,
    solid_pieces,
    with_free_side,
)
from houghloc.segment_map import SegmentMap

_CANDIDATE_BLUR_CELLS = 1.5  # Gaussian σ before line detection, in cells
_MAX_REFIT_TURN_COS = math.cos(math.radians(5.0))  # a refit may turn a detection this much


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
    segments = merge_duplicates(segments, facing, duplicate_angle, duplicate_offset, door_gap,
                                 bridge_gap)
    if len(segments) == 0:
        raise ValueError(f"no wall segment of at least {min_length} m found in the grid")
    return walls_longest_first(segments.starts, segments.ends, name)


def _detect_candidates(grid: OccupancyGrid) -> WallLines:
    """LSD on the occupied-cell image → candidate segments in world coordinates."""
    image = np.where(grid.occupied, 255, 0).astype(np.uint8)
    # Walls in a grid built from scans are jagged chains of cells; LSD needs level lines that
    # agree in orientation, which a blur over a few cells gives (on the raw binary image it
    # finds only short, straight stretches). The blur's edges sit beside the wall: refined later.
    blurred = cv2.GaussianBlur(image, (0, 0), _CANDIDATE_BLUR_CELLS)
    detector = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale=1.0)
    found = detector.detect(blurred)[0]
    if found is None:
        return lines_from_ends(np.empty((0, 2)), np.empty((0, 2)))
    uv = found.reshape(-1, 4).astype(float)
    ox, oy = grid.origin
    # LSD's pixel centres sit at integer coordinates: cell j spans [j − ½, j + ½].
    a = np.column_stack((ox + (uv[:, 0] + 0.5) * grid.resolution,
                         oy + (uv[:, 1] + 0.5) * grid.resolution))
    b = np.column_stack((ox + (uv[:, 2] + 0.5) * grid.resolution,
                         oy + (uv[:, 3] + 0.5) * grid.resolution))
    long_enough = np.linalg.norm(b - a, axis=1) >= 3 * grid.resolution
    return lines_from_ends(a[long_enough], b[long_enough])


def _support(
    lines: WallLines, points: NDArray[np.float64], tree: cKDTree, tol: float, margin: float,
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


def _refine(candidates: WallLines, points: NDArray[np.float64], tree: cKDTree, tol: float,
            margin: float) -> WallLines:
    """Refit every candidate to the occupied cells around it (TLS); extent from its cells."""
    line, point, _s, _d = _support(candidates, points, tree, tol, margin)
    moments = Moments.of(line, points[point], len(candidates))
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
    return WallLines(centroid[ok], direction[ok], s0[ok], s1[ok])


def _group_collinear(lines: WallLines, angle_tol: float, offset_tol: float,
                     door_gap: float) -> WallLines:
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
            hit = np.flatnonzero(on_group_line(a, b, d, g_point, g_dir, cos_tol, offset_tol)
                                 & (gap_to_extent(a, b, g_point, g_dir, g_s) <= door_gap))
        else:
            hit = np.empty(0, dtype=np.intp)
        weight = float(lines.length[i])
        mom = weight * end_moments(a, b)
        if len(hit):
            g = hit[0]
            old_ends = g_point[g] + g_s[g][:, None] * g_dir[g]  # the group's ends, in the world
            g_mom[g] += mom
            g_point[g], new_dir = fit_moments(g_mom[g])
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
    return WallLines(g_point, g_dir, g_s[:, 0], g_s[:, 1])


def _segments_on_lines(
    groups: WallLines,
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
) -> tuple[WallLines, NDArray[np.float64]]:
    """Occupied cells → wall lines (refitted) → runs of cells along each line → segments, and
    each segment's facing: the unit normal pointing to the side it is seen from (free space)."""
    line, point, _s, dist = _support(groups, points, tree, support_tol, margin=occlusion_gap)
    line, point = _keep_best_of_parallel(groups, line, point, dist)
    moments = Moments.of(line, points[point], len(groups))
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

    pieces = solid_pieces(line, s, grid.resolution, bridge_gap, min_fill, min_piece)
    pieces = with_free_side(pieces, grid, centroid, direction)
    runs = join_occluded_gaps(pieces, grid, centroid, direction, occlusion_gap)
    keep = runs.length >= min_length
    runs = Runs(runs.line[keep], runs.s0[keep], runs.s1[keep])
    lines = WallLines(centroid[runs.line], direction[runs.line], runs.s0, runs.s1)
    share = free_side_share(runs, grid, centroid, direction)
    facing = lines.normal * np.where(share[:, 0] >= share[:, 1], 1.0, -1.0)[:, None]
    return lines, facing


def _keep_best_of_parallel(
    groups: WallLines, line: NDArray[np.intp], point: NDArray[np.intp], dist: NDArray[np.float64],
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



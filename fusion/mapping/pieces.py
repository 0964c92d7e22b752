"""Along each wall line, the runs of occupied cells: the solid pieces (gaps bridged up to a
door's width), kept only when their observed side is free space, joined across gaps that an
occluder explains, and duplicates (two faces of one thin wall) merged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.mapping.grid import OccupancyGrid
from fusion.mapping.lines import (
    WallLines,
    end_moments,
    fit_moments,
    gap_to_extent,
    on_group_line,
)

_FREE_SIDE_OFFSETS = (3, 4, 5, 6)  # cells from a wall where its observed side must be free


@dataclass(frozen=True)
class Runs:
    """Stretches ``[s0, s1]`` of wall along the fitted lines ``line``, sorted by (line, s0)."""

    line: NDArray[np.intp]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0


def solid_pieces(line: NDArray[np.intp], s: NDArray[np.float64], resolution: float,
                  bridge_gap: float, min_fill: float, min_piece: float) -> Runs:
    """Cells sorted by (line, s) → pieces without gaps longer than ``bridge_gap``, kept when at
    least ``min_piece`` long and at least ``min_fill`` of their cell-steps hold a cell. Clutter
    and crossing walls put a few isolated cells on a line; a wall fills it."""
    if len(s) == 0:
        empty = np.empty(0)
        return Runs(np.empty(0, dtype=np.intp), empty, empty)
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
    return Runs(line[first][keep], s0[keep], s1[keep])


def with_free_side(pieces: Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                    direction: NDArray[np.float64], min_share: float = 0.5) -> Runs:
    """Keep the pieces with free space along one side: a wall face is seen through free space,
    while a line drawn through a blob of clutter or a thick, smeared wall has none."""
    if len(pieces.line) == 0:
        return pieces
    keep = free_side_share(pieces, grid, point, direction).max(axis=1) >= min_share
    return Runs(pieces.line[keep], pieces.s0[keep], pieces.s1[keep])


def free_side_share(pieces: Runs, grid: OccupancyGrid, point: NDArray[np.float64],
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


def merge_duplicates(segments: WallLines, facing: NDArray[np.float64], angle_tol: float,
                      offset_tol: float, max_gap: float, bridge_gap: float) -> WallLines:
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
            hit = np.flatnonzero(on_group_line(a, b, d, c_point, c_dir, cos_tol, offset_tol)
                                 & (c_face @ facing[i] > 0)
                                 & (gap_to_extent(a, b, c_point, c_dir, c_s) <= max_gap))
        mom = float(segments.length[i]) * end_moments(a, b)
        if len(hit):
            c = hit[0]
            members[c].append(i)
            c_mom[c] += mom
            c_point[c], new_dir = fit_moments(c_mom[c])
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
    return WallLines(c_point[cluster], c_dir[cluster], np.array([p[1] for p in pieces]),
                  np.array([p[2] for p in pieces]))


def join_occluded_gaps(pieces: Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                        direction: NDArray[np.float64], occlusion_gap: float) -> Runs:
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
    joined[candidate] = ~gap_has_free_space(grid, point[lines], direction[lines],
                                             pieces.s1[:-1][candidate], pieces.s0[1:][candidate])
    start = np.flatnonzero(np.concatenate(([True], ~joined)))
    end = np.concatenate((start[1:] - 1, [len(gap)]))
    return Runs(pieces.line[start], pieces.s0[start], pieces.s1[end])


def gap_has_free_space(
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

"""The scans since the last send, kept raw (a few references and small arrays a scan), and
turned into the recording's columns a whole batch at a time: one NumPy pass or compiled call per
field over the batch, where drawing each scan as it came cost a hundred small operations a scan.

:class:`ScanRows` is what :meth:`fusion.rerun_logger.RerunLogger.log_scan` fills; the functions
below turn it into the arrays of one entity. The arrays a scan keeps are its correction's own
(nothing modifies a correction once made) and a copy of its points.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from fusion.rerun_columns import strips_from_points
from fusion.rerun_view import LineColours, batch_point_rows, hough_marks
from houghloc.jit import njit

_NO_LINES = np.empty(0, np.int64)
_NO_ANGLES = np.empty(0)


class HoughRow(NamedTuple):
    """One scan's marks on the accumulator: its lines' (θ, ρ), the map's references (θ, ρ, map
    line) and its matches (indices into both); ``grid`` (δθ, δρ, ρ_min), None without a vote."""

    row: int
    grid: tuple[float, float, float] | None
    line_theta: NDArray[np.float64]
    line_rho: NDArray[np.float64]
    ref_theta: NDArray[np.float64]
    ref_rho: NDArray[np.float64]
    ref_line: NDArray[np.int64]
    match_line: NDArray[np.int64]
    match_ref: NDArray[np.int64]

    @classmethod
    def of(cls, row: int, correction: Any) -> HoughRow:
        grid = getattr(correction, "grid", None)
        if grid is None:
            return cls(row, None, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, _NO_LINES,
                       _NO_LINES, _NO_LINES)
        lines, refs = correction.lines, correction.references
        matches = correction.matches
        line_theta, line_rho = ((_NO_ANGLES, _NO_ANGLES) if lines is None
                                else (lines.theta, lines.rho))
        ref_theta, ref_rho, ref_line = ((_NO_ANGLES, _NO_ANGLES, _NO_LINES) if refs is None
                                        else (refs.theta, refs.rho, refs.line))
        match_line, match_ref = _NO_LINES, _NO_LINES
        if matches is not None and len(matches) and len(line_theta) and len(ref_theta):
            match_line, match_ref = matches.line, matches.ref
        return cls(row, (grid.theta_step, grid.rho_step, grid.rho_min), line_theta, line_rho,
                   ref_theta, ref_rho, ref_line, match_line, match_ref)


class ScanRows:
    """Per scan since the last send (its row): time, scan index, points and what colours them,
    the estimate; per some rows: odometry, truth, innovation, NIS, corridor placement, the Hough
    marks and the matched map lines (the first sensor's scans only)."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.scan: list[int] = []
        self.points_entity: list[str] = []
        self.points: list[NDArray[np.float64]] = []
        # the scan's lines' members (points × lines) and, per match, its line and map line
        self.members: list[NDArray[np.bool_] | None] = []
        self.match_lines: list[NDArray[np.int64]] = []
        self.map_lines: list[NDArray[np.int64]] = []
        self.pose: list[NDArray[np.float64]] = []
        self.cov: list[NDArray[np.float64]] = []
        self.status: list[str] = []  # a ScanStatus
        self.n_matches: list[int] = []
        self.odometry: list[tuple[int, NDArray[np.float64]]] = []
        self.truth: list[tuple[int, NDArray[np.float64]]] = []
        self.innovation: list[tuple[int, float, float, float]] = []
        self.nis: list[tuple[int, float]] = []
        self.along: list[tuple[int, float]] = []
        self.hough: list[HoughRow] = []
        self.matched: list[tuple[int, NDArray[np.intp]]] = []

    def __len__(self) -> int:
        return len(self.t)

    def add_scan(self, t: float, scan: int, points_entity: str, points: Any, correction: Any,
                 pose: NDArray[np.float64], cov: NDArray[np.float64], status: str) -> int:
        """The fields every scan has; returns its row."""
        row = len(self.t)
        self.t.append(t)
        self.scan.append(scan)
        self.points_entity.append(points_entity)
        self.points.append(np.array(points, dtype=float).reshape(-1, 2))
        lines = getattr(correction, "lines", None)
        matches = getattr(correction, "matches", None)
        self.members.append(None if lines is None or len(lines) == 0 else lines.members)
        map_lines = getattr(correction, "matched_map_lines", _NO_LINES)
        if matches is None or len(matches) == 0 or len(map_lines) != len(matches):
            self.match_lines.append(_NO_LINES)
            self.map_lines.append(_NO_LINES)
        else:
            self.match_lines.append(matches.line)
            self.map_lines.append(map_lines)
        self.pose.append(pose)
        self.cov.append(cov)
        self.status.append(status)
        self.n_matches.append(len(matches) if matches is not None else 0)
        return row


def scan_points(rows: ScanRows, picked: list[int], colours: LineColours
                ) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.int64]]:
    """The picked rows' points in the world (at their estimates), their colours (their matched
    map line's; on an unmatched line light grey; else grey) and how many each row has. Non-finite
    points are left out, as the Hough method left them out (its members index what is left)."""
    points = [rows.points[r] for r in picked]
    lengths = np.fromiter(map(len, points), np.int64, len(points))
    robot = np.concatenate(points) if points else np.empty((0, 2))
    if not np.isfinite(robot.sum()):
        finite = np.isfinite(robot).all(axis=1)
        lengths = np.bincount(np.repeat(np.arange(len(points)), lengths)[finite],
                              minlength=len(points))
        robot = robot[finite]
    world = moved_points(robot, np.array([rows.pose[r] for r in picked]).reshape(-1, 3),
                         lengths)
    members = [rows.members[r] for r in picked]
    usable = [m if m is not None and m.shape[0] == n else None
              for m, n in zip(members, lengths.tolist(), strict=True)]
    n_lines = np.array([0 if m is None else m.shape[1] for m in usable], np.int64)
    flat = [m.reshape(-1) for m in usable if m is not None]
    match_lines = [rows.match_lines[r] if m is not None else _NO_LINES
                   for r, m in zip(picked, usable, strict=True)]
    map_lines = [rows.map_lines[r] if m is not None else _NO_LINES
                 for r, m in zip(picked, usable, strict=True)]
    map_all = _joined(map_lines)
    colours.ensure(map_all)  # may grow the colour table
    table_rows = batch_point_rows(
        np.concatenate(flat) if flat else np.empty(0, np.bool_), lengths, n_lines,
        _joined(match_lines), map_all,
        np.fromiter(map(len, match_lines), np.int64, len(match_lines)))
    return world, colours.table[table_rows], lengths


@njit
def moved_points(points: NDArray[np.float64], poses: NDArray[np.float64],
                 lengths: NDArray[np.int64]) -> NDArray[np.float64]:
    """Robot-frame points (the first ``lengths[0]`` seen from ``poses[0]``, and so on) in the
    map frame: p ↦ R(θ) p + (x, y), as :func:`houghloc.geometry.transform_points` per scan."""
    out = np.empty_like(points)
    at = 0
    for k in range(lengths.shape[0]):
        x, y, theta = poses[k, 0], poses[k, 1], poses[k, 2]
        c, s = np.cos(theta), np.sin(theta)
        for i in range(at, at + lengths[k]):
            out[i, 0] = x + c * points[i, 0] - s * points[i, 1]
            out[i, 1] = y + s * points[i, 0] + c * points[i, 1]
        at += lengths[k]
    return out


def hough_columns(marks: list[HoughRow], colours: LineColours) -> dict[str, Any]:
    """The accumulator marks of many scans: peaks, references (labelled with their map lines)
    and a segment per match, with their colours and per-row counts (``*_lengths``)."""
    line_counts = np.array([len(m.line_theta) for m in marks], np.int64)
    ref_counts = np.array([len(m.ref_theta) for m in marks], np.int64)
    match_counts = np.array([len(m.match_line) for m in marks], np.int64)
    # each scan's match indices shifted to its lines and references in the joined arrays
    line_base = np.repeat(np.cumsum(line_counts) - line_counts, match_counts)
    ref_base = np.repeat(np.cumsum(ref_counts) - ref_counts, match_counts)
    line_theta = _float(_joined([m.line_theta for m in marks], _NO_ANGLES))
    line_rho = _float(_joined([m.line_rho for m in marks], _NO_ANGLES))
    ref_theta = _float(_joined([m.ref_theta for m in marks], _NO_ANGLES))
    ref_rho = _float(_joined([m.ref_rho for m in marks], _NO_ANGLES))
    ref_line = _joined([m.ref_line for m in marks]).astype(np.int64)
    match_line = _joined([m.match_line for m in marks]).astype(np.int64) + line_base
    match_ref = _joined([m.match_ref for m in marks]).astype(np.int64) + ref_base
    peaks, ref_pixels, ends = np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2, 2))
    grids = {m.grid for m in marks if m.grid is not None}
    if len(grids) == 1:  # one sensor's grid: the usual case, all in one call
        peaks, ref_pixels, ends = hough_marks(*grids.pop(), line_theta, line_rho, ref_theta,
                                              ref_rho, match_line, match_ref)
    elif grids:  # rows of several grids: each row on its own
        parts = [hough_marks(*m.grid, _float(m.line_theta), _float(m.line_rho),
                             _float(m.ref_theta), _float(m.ref_rho),
                             m.match_line.astype(np.int64), m.match_ref.astype(np.int64))
                 for m in marks if m.grid is not None]
        peaks, ref_pixels, ends = (np.concatenate([p[k] for p in parts]) for k in range(3))
    colours.ensure(ref_line)
    peak_rows = np.full(len(peaks), -2, np.intp)
    peak_rows[match_line] = ref_line[match_ref]
    table = colours.table
    return {"peaks": peaks, "peak_colours": table[peak_rows], "peak_lengths": line_counts,
            "references": ref_pixels, "reference_colours": table[ref_line],
            "reference_labels": colours.label(ref_line), "reference_lengths": ref_counts,
            "matches": strips_from_points(ends.reshape(-1, 2), np.full(len(ends), 2)),
            "match_colours": table[peak_rows[match_line]], "match_lengths": match_counts}


def _joined(arrays: list[NDArray], empty: NDArray = _NO_LINES) -> NDArray:
    return np.concatenate(arrays) if arrays else empty


def _float(values: NDArray) -> NDArray[np.float64]:
    return np.ascontiguousarray(values, dtype=float)


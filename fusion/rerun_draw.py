"""The batches of scans drawn as Rerun columns: the estimates, their ellipses and the paths,
the walls each scan matched, the marks on the Hough image and the time series
(:class:`ScanDrawing`, the part of :class:`fusion.rerun_logger.RerunLogger` that turns
:class:`fusion.rerun_scans.ScanRows` into entities). The look of each entity:
:mod:`fusion.rerun_view`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from fusion.rerun_columns import PathPieces, strips_from_points
from fusion.rerun_scans import ScanRows, hough_columns
from fusion.rerun_stream import ColumnStream
from fusion.rerun_view import (
    PATH_COLOURS,
    STATUS_COLOURS,
    UNMATCHED,
    LineColours,
    covariance_ellipse,
    heading_vector,
)
from houghloc.geometry import compose, relative

WALL_TABLE_CELLS = 1 << 22  # scans × walls looked at in one pass for the matched walls (bytes)

METRICS = ("innovation/x", "innovation/y", "innovation/theta", "nis", "sigma/x", "sigma/y",
           "sigma/theta", "matches", "error/position", "error/heading", "along_corridor")
DEGREES = np.array([1.0, 1.0, 180.0 / math.pi])
"""(x, y, θ) to the time series' units: metres and degrees"""
_METRIC_ENTITY = {name: f"metrics/{name}" for name in METRICS}
_STATUS_RGBA: dict[str, NDArray[np.uint8]] = {
    status: np.array([rgba], dtype=np.uint8) for status, rgba in STATUS_COLOURS.items()}
_UNMATCHED_RGBA = np.array([UNMATCHED], dtype=np.uint8)
NO_LINES = np.empty(0, np.int64)


def _path_style(name: str, recent: bool) -> Any:
    """A path's look; the newest piece, near the robot, carries the path's name: the legend."""
    return rr.LineStrips2D.from_fields(colors=PATH_COLOURS[name], radii=0.02, draw_order=2.0,
                                       labels=name if recent else None, show_labels=recent)


class ScanDrawing(ColumnStream):
    """Draws a batch of scans on its stream; keeps what the drawing carries from batch to
    batch: the map's walls and line colours, the paths' pieces, the odometry path's anchor."""

    def __init__(self, stream: rr.RecordingStream) -> None:
        super().__init__(stream)
        self._colours = LineColours()
        self._walls: tuple[NDArray[np.float64], NDArray[np.intp]] = (
            np.empty((0, 2, 2)), np.empty(0, np.intp))
        self._n_lines = 0  # the map's lines
        self._paths = {name: PathPieces(f"world/path/{name}") for name in PATH_COLOURS}
        self._odometry_anchor: tuple[NDArray, NDArray] | None = None  # (est₀, odom₀)

    # ---------------------------------------------------------------- world
    def _send_robot(self, rows: ScanRows) -> None:
        """The estimates (arrows coloured by status, 95 % ellipses), the truth and the paths."""
        poses, covs = np.array(rows.pose), np.array(rows.cov)
        colours = np.concatenate([_STATUS_RGBA.get(s, _UNMATCHED_RGBA) for s in rows.status])
        self._send("world/robot/estimate", rr.Arrows2D, rows, None, None,
                   origins=poses[:, :2], vectors=heading_vector(poses), colors=colours,
                   labels=[str(s) for s in rows.status])
        ellipses = covariance_ellipse(poses[:, :2], covs[:, :2, :2])
        self._send("world/robot/covariance", rr.LineStrips2D, rows, None, None,
                   strips=strips_from_points(ellipses.reshape(-1, 2),
                                             np.full(len(poses), ellipses.shape[1])),
                   colors=colours)
        self._send_path(rows, "estimate", list(range(len(rows))), poses)
        if rows.odometry:
            picked = [row for row, _ in rows.odometry]
            odometry = np.array([pose for _, pose in rows.odometry])
            if self._odometry_anchor is None:
                self._odometry_anchor = (poses[picked[0]], odometry[0])
            first_estimate, first_odometry = self._odometry_anchor
            self._send_path(rows, "odometry", picked,
                            compose(first_estimate, relative(first_odometry, odometry)))
        if rows.truth:
            picked = [row for row, _ in rows.truth]
            truth = np.array([pose for _, pose in rows.truth])
            self._send("world/robot/truth", rr.Arrows2D, rows, picked, None,
                       origins=truth[:, :2], vectors=heading_vector(truth))
            self._send_path(rows, "truth", picked, truth)

    def _send_path(self, rows: ScanRows, name: str, picked: list[int],
                   poses: NDArray[np.float64]) -> None:
        """A path's newest piece at each picked row and its older pieces' changes
        (:class:`PathPieces`)."""
        recent, updates = self._paths[name].extend(poses[:, :2])
        entity = f"world/path/{name}/recent"
        if entity not in self._styled:  # the style is built once: it costs more than a send
            self._style_once(entity, _path_style(name, recent=True))
        self._send(entity, rr.LineStrips2D, rows, picked, None, strips=recent)
        for k, piece, line in updates:
            batch = self._batches.get(piece)
            if batch is None:  # the style is built once: it costs more than a row
                batch = self._batch(piece, rr.LineStrips2D, _path_style(name, recent=False))
            n = 1 if len(line) else 0
            batch.add(rows.t[picked[k]], rows.scan[picked[k]], n, strips=[line][:n])

    def _send_matched_walls(self, rows: ScanRows) -> None:
        """The walls of the map lines each scan's lines matched, in the map's order, each in its
        line's colour (the colour of the points that lie on it)."""
        walls, line_of = self._walls
        picked = [row for row, _ in rows.matched]
        matched = [np.asarray(lines, np.intp) for _, lines in rows.matched]
        counts = np.fromiter(map(len, matched), np.intp, len(matched))
        n_lines = self._n_lines
        rows_at_once = max(WALL_TABLE_CELLS // max(len(line_of), 1), 1)
        scan_of, wall = [], []
        for first in range(0, len(matched), rows_at_once):
            part = matched[first:first + rows_at_once]
            # scans × map lines: which lines each scan matched (ids beyond the map: no wall)
            table = np.zeros((len(part), n_lines + 1), bool)
            table[np.repeat(np.arange(len(part)), counts[first:first + rows_at_once]),
                  np.minimum(np.concatenate(part), n_lines)] = True
            # a scan's walls are those of its lines, in the map's order (np.isin(line_of, …))
            scans, walls_seen = np.nonzero(table[:, line_of])
            scan_of.append(scans + first)
            wall.append(walls_seen)
        scan_of_all = np.concatenate(scan_of) if scan_of else np.empty(0, np.intp)
        wall_all = np.concatenate(wall) if wall else np.empty(0, np.intp)
        self._colours.ensure(line_of)
        self._send("world/map/matched", rr.LineStrips2D, rows, picked,
                   np.bincount(scan_of_all, minlength=len(matched)),
                   strips=strips_from_points(walls[wall_all].reshape(-1, 2),
                                             np.full(len(wall_all), 2)),
                   colors=self._colours.table[line_of[wall_all]])

    # ---------------------------------------------------------------- Hough
    def _send_hough(self, rows: ScanRows) -> None:
        """Each scan's peaks, references and matches on the accumulator image."""
        marks = hough_columns(rows.hough, self._colours)
        picked = [mark.row for mark in rows.hough]
        self._send("hough/peaks", rr.Points2D, rows, picked, marks["peak_lengths"],
                   positions=marks["peaks"], colors=marks["peak_colours"])
        self._send("hough/references", rr.Points2D, rows, picked, marks["reference_lengths"],
                   positions=marks["references"], colors=marks["reference_colours"],
                   labels=marks["reference_labels"])
        self._send("hough/matches", rr.LineStrips2D, rows, picked, marks["match_lengths"],
                   strips=marks["matches"], colors=marks["match_colours"])

    def _send_metrics(self, rows: ScanRows) -> None:
        """The time series: σ of x, y, θ and the lines matched at every scan; the innovation,
        the NIS and the corridor placement where there is one."""
        covs = np.array(rows.cov)
        sigma = np.sqrt(np.maximum(np.diagonal(covs, axis1=1, axis2=2), 0.0)) * DEGREES
        for k, name in enumerate(METRICS[4:7]):
            self._send(_METRIC_ENTITY[name], rr.Scalars, rows, None, None, scalars=sigma[:, k])
        self._send(_METRIC_ENTITY["matches"], rr.Scalars, rows, None, None,
                   scalars=np.array(rows.n_matches, dtype=float))
        if rows.innovation:
            values = np.array(rows.innovation)
            picked = values[:, 0].astype(np.intp)
            for k, name in enumerate(METRICS[:3]):
                self._send(_METRIC_ENTITY[name], rr.Scalars, rows, picked, None,
                           scalars=values[:, k + 1])
        for name, series in (("nis", rows.nis), ("along_corridor", rows.along)):
            if series:
                values = np.array(series)
                self._send(_METRIC_ENTITY[name], rr.Scalars, rows, values[:, 0].astype(np.intp),
                           None, scalars=values[:, 1])

"""Every stage of the pipeline recorded to Rerun: the logger the pipeline is given
when somebody wants to look. Its public methods are exactly those of
:class:`fusion.visualize.Logger`. How it looks: :mod:`fusion.rerun_view`; how the rows are
batched: :mod:`fusion.rerun_columns`; the served web viewer: :mod:`fusion.rerun_serve`.

Entity paths (2D geometry already in map coordinates: rerun 0.41 has no 2D transform)::

    world/map/walls, world/map/lines          LineStrips2D, static: walls grey, painted lines
                                              white and thinner
    world/map/matched                         the walls of the map lines the scan matched, each in
                                              its line's colour (that of the points on it)
    world/scan/points                         the scan at the estimated pose, each point in the
                                              colour of the map line its observed line matched;
                                              on an unmatched observed line light grey, else grey
    world/scan/<sensor>/points                the same for every sensor after the first one seen
    world/robot/estimate                      Arrows2D, coloured by the measurement's status
    world/robot/covariance                    95 % ellipse of the x-y covariance (LineStrips2D)
    world/robot/truth                         Arrows2D, when ground truth is logged
    world/path/{estimate,odometry,truth}/<k>  the paths, in pieces (see below); odometry is
                                              est₀ ⊕ (odom₀⁻¹ ⊕ odomₖ), anchored at the first scan;
                                              the newest piece labelled with the path's name
    hough/accumulator                         DepthImage of the votes, viridis colour map (8 bits
                                              when the first scan has ≤ 255 points, else 16)
    hough/peaks, hough/references             Points2D in accumulator pixels (references labelled
                                              with their segment ids)
    hough/matches                             LineStrips2D, observed line → its reference point
    metrics/innovation/{x,y,theta}, metrics/nis, metrics/sigma/{x,y,theta}, metrics/matches,
    metrics/error/{position,heading}          Scalars (errors: truth interpolated at the scan)
    metrics/along_corridor                    Scalars (m a corridor fix was moved along it)
    log/state                                 TextLog: the ambiguity manager's state and reason
    log/scan                                  TextLog: why a scan was not used (not "accepted")
    global/hypotheses                         Arrows2D with the scores as labels

Timelines: ``time`` (sensor seconds: a duration for simulated clocks, a timestamp once the clock
looks like Unix time) and ``scan`` (sequence; events between scans carry only ``time``).
Angles in the time series are in degrees, lengths in metres.

The Hough image is the accumulator as it is stored (no copy): one row per θ cell, one column per
ρ cell, so ρ runs left to right from ``rho_min`` and θ top to bottom from 0. Cell (i_θ, i_ρ) is
the pixel square [i_ρ, i_ρ+1) × [i_θ, i_θ+1), and a continuous (θ, ρ) is drawn at
u = (ρ − ρ_min)/δρ, v = θ/δθ + ½ (θ cell i is centred on iδθ; ρ cell j spans an interval).

Speed: one ``log`` call costs ~100 µs whatever its size, so per-scan data is buffered and sent
with one ``send_columns`` call per entity every ``BATCH_SCANS`` scans, every ``BATCH_SECONDS``
of wall time when serving (a live viewer lags at most that), and at :meth:`RerunLogger.flush`.
Only the Hough image (where the cost is per pixel), the state log and the hypotheses are logged
at once; when not serving, the SDK gathers them into chunks of ``FILE_CHUNK_BYTES``.

Paths are logged in blocks because the viewer shows the latest value of an entity: a path sent
whole at every scan grows quadratically with the run. The newest ``PATH_PIECE`` poses are
re-sent at every scan; older ones sit in blocks merged like a binary counter (:class:`PathPieces`).
The number of entities stays logarithmic in the run: a file sink keeps an index of every chunk
(with a column per entity and component) until it writes the footer, and an entity per piece
made that index grow with the run's length times the number of its pieces.

Rerun's 2D views draw +y downwards (rerun issue #1387: no view coordinates for 2D views yet), so
the world view is the map mirrored top to bottom; hovering shows true map coordinates.
"""

from __future__ import annotations

import logging
import math
import subprocess
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike, NDArray

from fusion.rerun_columns import BATCH_SCANS, ColumnBatch, ErrorSeries, PathPieces
from fusion.rerun_serve import GRPC_PORT, SERVE_HOST, WEB_PORT, die_with_parent, web_viewer_command
from fusion.rerun_view import (
    ARROW_LENGTH,
    PAINTED,
    PATH_COLOURS,
    SERIES_COLOUR,
    SERIES_COLOURS,
    SERIES_NAMES,
    STATE_LEVELS,
    STATUS_COLOURS,
    UNMATCHED,
    WALL_COLOUR,
    LineColours,
    covariance_ellipse,
    default_blueprint,
    entity_styles,
    heading_vector,
    hough_marks,
    point_rows,
)
from fusion.status import ScanStatus
from houghloc.geometry import compose, relative, transform_points

if TYPE_CHECKING:
    from fusion.localizer import Estimate
    from houghloc import ScanCorrection, SegmentMap

_log = logging.getLogger(__name__)

BATCH_SECONDS = 0.5  # wall-clock seconds a live (served) view lags at most
IMAGE_BATCH = 25  # Hough images buffered at most: 1.2 MB on Intel's grid, within the cache
# (25 replayed the Intel log 2–3 % faster than 100 or 10, measured alternately)
FILE_CHUNK_BYTES = 8 << 20  # bytes of immediate logs (Hough images) per chunk, when not serving
FILE_FLUSH_SECONDS = 2.0  # ... or this long, whichever first
UNIX_TIME_THRESHOLD = 1e8  # s; a clock past 1973 is a wall clock, not a simulation's

METRICS = ("innovation/x", "innovation/y", "innovation/theta", "nis", "sigma/x", "sigma/y",
           "sigma/theta", "matches", "error/position", "error/heading", "along_corridor")
_DEGREES = np.array([1.0, 1.0, 180.0 / math.pi])
_SCALE = _DEGREES.tolist()
_METRIC_ENTITY = {name: f"metrics/{name}" for name in METRICS}
_STATUS_RGBA = {status: np.array([rgba], dtype=np.uint8) for status, rgba in STATUS_COLOURS.items()}
_UNMATCHED_RGBA = np.array([UNMATCHED], dtype=np.uint8)
_NO_LINES = np.empty(0, np.int64)
_NO_ANGLES = np.empty(0)


def _floats(values: Any) -> NDArray[np.float64]:
    return np.ascontiguousarray(values, dtype=float)


# ------------------------------------------------------------------------------- the logger
class RerunLogger:
    """Records every stage to its own :class:`rerun.RecordingStream` (never the global one).

    ``path``: write an ``.rrd`` file there. ``serve``: host a gRPC server on ``SERVE_HOST`` only
    (port ``grpc_port``; :attr:`grpc_url`) and, unless ``web_port`` is None, a web viewer at
    :attr:`web_url` (a child process, stopped by :meth:`close`). With neither,
    the data goes to memory (:attr:`memory`, for notebooks). ``accumulator_every``: log the Hough
    image every N scans (0: never) — it is the costly part. The default blueprint travels with
    the recording.

    Per-scan data is buffered and sent in columns every ``BATCH_SCANS`` scans (or, when
    serving, ``BATCH_SECONDS`` of wall time), and by :meth:`flush` / :meth:`close` (the Hough
    images also every ``IMAGE_BATCH``); the state log and the hypotheses are logged at once.

    About 400 lines, on purpose: every stage's writer shares the one stream, its batches, its
    time columns and the map's colours; the parts that stand alone are apart (the look:
    :mod:`fusion.rerun_view`; the columns, paths and error series: :mod:`fusion.rerun_columns`;
    the served viewer: :mod:`fusion.rerun_serve`).
    """

    def __init__(self, path: str | Path | None = None, *, serve: bool = False,
                 app_id: str = "houghloc", recording_name: str | None = None,
                 accumulator_every: int = 1, grpc_port: int = GRPC_PORT,
                 web_port: int | None = WEB_PORT) -> None:
        # Unless a viewer watches live, images are gathered into larger chunks (see BATCH_SCANS)
        batcher = None if serve else rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_SECONDS,
                                                           flush_num_bytes=FILE_CHUNK_BYTES)
        self.stream = rr.RecordingStream(app_id, recording_id=uuid.uuid4(),
                                         batcher_config=batcher)
        self.accumulator_every = int(accumulator_every)
        self.memory: Any = None
        self.grpc_url: str | None = None  # for the native viewer: ``rerun <grpc_url>``
        self.web_url: str | None = None  # the web viewer, connected to ``grpc_url``
        self._web_viewer: subprocess.Popen | None = None
        sinks: list[Any] = []
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(path)))
        if serve:
            server = rr.GrpcServerSink(bind_ip=SERVE_HOST, port=grpc_port)
            sinks.append(server)
            self.grpc_url = server.uri
        if sinks:
            self.stream.set_sinks(*sinks, default_blueprint=default_blueprint())
        else:
            self.memory = self.stream.memory_recording()
            self.stream.send_blueprint(default_blueprint())
        if recording_name:
            self.stream.send_recording_name(recording_name)
        if serve and web_port is not None:
            self._start_web_viewer(web_port)
        self._closed = False
        self._time_kind: str | None = None
        self._styles = entity_styles()
        self._batches: dict[str, ColumnBatch] = {}
        self._styled: set[str] = set()
        self._batched_scans = 0
        self._accumulator_entities: dict[tuple[int, int], str] = {}
        # each Hough image's pixel type and its largest value
        self._image_type: dict[str, tuple[type[np.unsignedinteger], int]] = {}
        self._batch_seconds = BATCH_SECONDS if serve else math.inf  # nobody watches a file live
        self._last_send = time.monotonic()
        self._scans_logged = 0
        self._colours = LineColours()
        # compiled (or loaded from the cache) now, not on a scan of the stream
        point_rows(np.zeros((1, 1), bool), _NO_LINES, _NO_LINES)
        hough_marks(1.0, 1.0, 0.0, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, _NO_LINES,
                    _NO_LINES)
        self._walls: tuple[NDArray[np.float64], NDArray[np.intp]] = (
            np.empty((0, 2, 2)), np.empty(0, np.intp))
        self._walls_of_line: list[NDArray[np.intp]] = []
        # the last scan's matched map lines, their walls and the walls' colours
        self._last_matched: tuple[frozenset[int], list, NDArray[np.uint8]] | None = None
        self._primary_sensor: str | None = None
        self._paths = {name: PathPieces(f"world/path/{name}") for name in PATH_COLOURS}
        self._odometry: NDArray[np.float64] | None = None
        self._odometry_anchor: tuple[NDArray, NDArray] | None = None  # (est₀, odom₀)
        self._error_series = ErrorSeries()
        self._truth_unlogged = False
        for name in METRICS:
            self.stream.log(f"metrics/{name}", rr.SeriesLines(
                names=SERIES_NAMES.get(name, name.split("/")[-1]),
                colors=SERIES_COLOURS.get(name.split("/")[-1], SERIES_COLOUR)), static=True)

    # ---------------------------------------------------------------- the Logger protocol
    def log_map(self, segment_map: SegmentMap) -> None:
        """The map, once, as static data; fixes the colour of every map line."""
        line_of = np.asarray(segment_map.line_of_segment)
        is_wall = np.asarray(segment_map.kinds) == "wall"
        n_lines = int(line_of.max()) + 1 if len(line_of) else 0
        painted = np.ones(n_lines, dtype=bool)
        painted[line_of[is_wall]] = False  # a line with any wall on it is a wall
        names: list[list[str]] = [[] for _ in range(n_lines)]
        for sid, line in zip(segment_map.ids, line_of.tolist(), strict=True):
            names[line].append(str(sid))
        self._colours.set_map(painted, ["+".join(n) for n in names])
        strips = np.stack((segment_map.starts, segment_map.ends), axis=1)
        ids = np.asarray(segment_map.ids, dtype=object)
        # the walls in one colour; each scan highlights those it matched (world/map/matched)
        self._walls = (strips[is_wall], line_of[is_wall])
        # each map line's walls (indices into self._walls), for the walls a scan matched
        wall_lines = line_of[is_wall]
        order = np.argsort(wall_lines, kind="stable")
        bounds = np.searchsorted(wall_lines[order], np.arange(n_lines + 1))
        self._walls_of_line = [order[bounds[j]:bounds[j + 1]] for j in range(n_lines)]
        self._last_matched = None
        for entity, keep, radius, colour in (("world/map/walls", is_wall, 0.03, WALL_COLOUR),
                                             ("world/map/lines", ~is_wall, 0.02, PAINTED)):
            self.stream.log(entity, rr.LineStrips2D(
                strips[keep], radii=radius, colors=colour, labels=list(ids[keep]),
                show_labels=False, draw_order=1.0), static=True)

    def log_odometry(self, t: float, odom_pose: ArrayLike) -> None:
        """Remember the latest odometry pose; the odometry path is drawn at each scan."""
        self._odometry = np.asarray(odom_pose, dtype=float).reshape(3)

    def log_scan(self, t: float, index: int, sensor: str, points: NDArray[np.float64],
                 correction: ScanCorrection | None, estimate: Estimate) -> None:
        """One scan: its points in the world, the robot, the paths, the Hough stage, metrics."""
        t, index = float(t), int(index)
        pose = np.asarray(estimate.pose, dtype=float)
        cov = np.asarray(estimate.cov, dtype=float)
        primary = self._is_primary(sensor)
        self._scan_points(t, index, "world/scan/points" if primary
                          else f"world/scan/{sensor}/points", points, correction, pose)
        self._robot(t, index, pose, cov, estimate.status)
        if primary:
            self._matched_walls(t, index, correction)
            self._hough(t, index, correction)
        if estimate.status != ScanStatus.ACCEPTED:
            reason = getattr(correction, "reason", "")
            self._batch("log/scan", rr.TextLog).add(
                t, index, 1, text=[f"scan {index} ({sensor}): {estimate.status}"
                                   + (f": {reason}" if reason else "")],
                level=["DEBUG" if estimate.status == ScanStatus.NO_FIX else "WARN"])
        self._metrics(t, index, pose, cov, correction, getattr(estimate, "outcome", None))
        along = getattr(estimate, "along", None)
        if along is not None:
            self._scalar("along_corridor", t, index, along.offset)
        self._scans_logged += 1
        self._batched_scans += 1
        if (self._batched_scans >= BATCH_SCANS
                or time.monotonic() - self._last_send >= self._batch_seconds):
            self._send_batches()

    def log_truth(self, t: float, pose: ArrayLike) -> None:
        """Ground truth: kept for the error series; drawn (robot and path) at the next scan."""
        if self._error_series.add_truth(t, pose):
            self._truth_unlogged = True

    def log_state(self, t: float, state: str, reason: str) -> None:
        """A transition of the ambiguity manager, as a text log whose level follows the state."""
        self._set_time(t)
        self.stream.log("log/state", rr.TextLog(f"{state}: {reason}" if reason else state,
                                                level=STATE_LEVELS.get(state, "INFO")))

    def log_hypotheses(self, t: float, poses: ArrayLike, scores: ArrayLike) -> None:
        """Global localization's candidate poses (N×3) with their scores as labels."""
        self._set_time(t)
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        scores = np.asarray(scores, dtype=float).reshape(-1)
        if len(poses) == 0:
            self.stream.log("global/hypotheses", rr.Clear(recursive=False))
            return
        # brighter for better scores: the best is full yellow, none darker than a fifth
        best = scores.max() if len(scores) == len(poses) and scores.max() > 0 else 0.0
        brightness = np.clip(scores / best, 0.2, 1.0) if best > 0 else np.ones(len(poses))
        labels = [f"{s:.3g}" for s in scores.tolist()] if len(scores) == len(poses) else None
        self.stream.log("global/hypotheses", rr.Arrows2D(
            origins=poses[:, :2], vectors=ARROW_LENGTH * np.column_stack(
                (np.cos(poses[:, 2]), np.sin(poses[:, 2]))), labels=labels, radii=0.03,
            colors=np.round(np.outer(brightness, (255, 200, 0))).astype(np.uint8)))

    def flush(self) -> None:
        """Send everything buffered and wait until the sinks have it."""
        self._send_batches()
        self.stream.flush()

    def close(self) -> None:
        """Flush, settle the error series with the last truth, finish the file, stop serving."""
        if self._closed:
            return
        self._closed = True
        self._send_batches(final=True)
        self.stream.flush()
        if self.memory is None:  # disconnecting a memory sink would drop what it holds
            self.stream.disconnect()  # writes the .rrd footer, shuts the gRPC server down
        if self._web_viewer is not None:
            self._web_viewer.terminate()
            try:
                self._web_viewer.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._web_viewer.kill()
            self._web_viewer = None

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- time and batches
    def _set_time(self, t: float, scan: int | None = None) -> None:
        """Time of an immediate log call; events between scans belong to no scan."""
        self.stream.reset_time()
        if scan is not None:
            self.stream.set_time("scan", sequence=int(scan))
        self.stream.set_time("time", **{self._clock(t): float(t)})

    def _clock(self, t: float) -> str:
        """``duration`` for a simulated clock, ``timestamp`` for Unix time; fixed at first use."""
        if self._time_kind is None:
            self._time_kind = "timestamp" if t > UNIX_TIME_THRESHOLD else "duration"
        return self._time_kind

    def _time_column(self, t: NDArray[np.float64]) -> rr.TimeColumn:
        return rr.TimeColumn("time", **{self._clock(float(t[0])): t})

    def _batch(self, entity: str, archetype: Any, style: Any = None) -> ColumnBatch:
        batch = self._batches.get(entity)
        if batch is None:
            batch = self._batches[entity] = ColumnBatch(entity, archetype)
            self._style_once(entity, style if style is not None else self._styles.get(entity))
        return batch

    def _style_once(self, entity: str, style: Any) -> None:
        if style is not None and entity not in self._styled:
            self._styled.add(entity)
            self.stream.log(entity, style, static=True)

    def _send_batches(self, final: bool = False) -> None:
        self._errors(final)
        for batch in self._batches.values():
            batch.send(self.stream, self._time_column)
        self._batched_scans = 0
        self._last_send = time.monotonic()

    # ---------------------------------------------------------------- world
    def _is_primary(self, sensor: str) -> bool:
        if self._primary_sensor is None:
            self._primary_sensor = sensor
        return sensor == self._primary_sensor

    def _scan_points(self, t: float, index: int, entity: str, points: Any, correction: Any,
                     pose: NDArray[np.float64]) -> None:
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if not math.isfinite(pts.sum()):  # one pass in the usual case, where all are finite
            # the Hough method dropped them too: members index what is left
            pts = pts[np.isfinite(pts).all(axis=1)]
        rows = self._point_rows(len(pts), correction)  # may grow the colour table
        colours = self._colours.table[rows]
        self._batch(entity, rr.Points2D, self._styles["points"]).add(
            t, index, len(pts), positions=transform_points(pose, pts), colors=colours)

    def _point_rows(self, n: int, correction: Any) -> NDArray[np.int64]:
        """Colour-table row of each point: its matched map line, else −2 on a line, else −1."""
        lines = getattr(correction, "lines", None)
        if lines is None or len(lines) == 0 or lines.members.shape[0] != n:
            return np.full(n, -1, dtype=np.int64)
        members = np.ascontiguousarray(lines.members)
        matches = correction.matches
        map_lines = np.asarray(correction.matched_map_lines, dtype=np.int64)
        if matches is None or len(matches) == 0 or len(map_lines) != len(matches):
            return point_rows(members, _NO_LINES, _NO_LINES)
        self._colours.ensure(map_lines)
        return point_rows(members, np.asarray(matches.line, dtype=np.int64), map_lines)

    def _matched_walls(self, t: float, index: int, correction: ScanCorrection | None) -> None:
        """The walls of the map lines this scan's lines matched, each in its line's colour (the
        colour of the points that lie on it)."""
        strips, line_of = self._walls
        matched = getattr(correction, "matched_map_lines", None)
        if matched is None or len(matched) == 0 or len(line_of) == 0:
            self._batch("world/map/matched", rr.LineStrips2D).add(
                t, index, 0, strips=[], colors=np.empty((0, 4), np.uint8))
            return
        lines = frozenset(np.asarray(matched).tolist())
        if self._last_matched is None or self._last_matched[0] != lines:
            # consecutive scans mostly match the same lines: their walls are picked once
            of_line, known = self._walls_of_line, len(self._walls_of_line)
            # the walls in the map's order, as np.isin(line_of, matched) would pick them
            keep = np.sort(np.concatenate([of_line[j] for j in lines if j < known]
                                          or [np.empty(0, np.intp)]))
            self._colours.ensure(line_of[keep])
            self._last_matched = (lines, list(strips[keep]), self._colours.table[line_of[keep]])
        _, walls, colours = self._last_matched
        self._batch("world/map/matched", rr.LineStrips2D).add(
            t, index, len(walls), strips=walls, colors=colours)

    def _robot(self, t: float, index: int, pose: NDArray[np.float64], cov: NDArray[np.float64],
               status: ScanStatus) -> None:
        colour = _STATUS_RGBA.get(status, _UNMATCHED_RGBA)
        self._batch("world/robot/estimate", rr.Arrows2D).add(
            t, index, 1, origins=pose[None, :2], vectors=heading_vector(pose), colors=colour,
            labels=[status])
        self._batch("world/robot/covariance", rr.LineStrips2D).add(
            t, index, 1, strips=[covariance_ellipse(pose, cov[:2, :2])], colors=colour)
        self._extend_path(t, index, "estimate", pose)
        if self._odometry is not None:
            if self._odometry_anchor is None:
                self._odometry_anchor = (pose.copy(), self._odometry.copy())
            first_estimate, first_odometry = self._odometry_anchor
            self._extend_path(t, index, "odometry",
                              compose(first_estimate, relative(first_odometry, self._odometry)))
        if self._truth_unlogged:
            self._truth_unlogged = False
            truth = self._error_series.latest_truth()
            self._batch("world/robot/truth", rr.Arrows2D).add(
                t, index, 1, origins=truth[None, :2], vectors=heading_vector(truth))
            self._extend_path(t, index, "truth", truth)

    def _extend_path(self, t: float, index: int, name: str, pose: NDArray[np.float64]) -> None:
        for entity, strip in self._paths[name].append(pose):
            batch = self._batches.get(entity)
            if batch is None:
                # the newest piece, near the robot, carries the path's name: the legend
                recent = entity.endswith("/recent")
                batch = self._batch(entity, rr.LineStrips2D, rr.LineStrips2D.from_fields(
                    colors=PATH_COLOURS[name], radii=0.02, draw_order=2.0,
                    labels=name if recent else None, show_labels=recent))
            n = 1 if len(strip) else 0
            batch.add(t, index, n, strips=[strip][:n])

    # ---------------------------------------------------------------- Hough
    def _hough(self, t: float, index: int, correction: Any) -> None:
        grid = getattr(correction, "grid", None)
        every = self.accumulator_every
        if grid is not None and every > 0 and self._scans_logged % every == 0:
            self._accumulator(t, index, correction.accumulator, correction.n_points)
        lines = getattr(correction, "lines", None)
        refs = getattr(correction, "references", None)
        matches = getattr(correction, "matches", None)
        ref_ids = _NO_LINES if refs is None or grid is None else np.asarray(refs.line, np.int64)
        self._colours.ensure(ref_ids)
        if grid is None:
            peaks, ref_pixels, ends = np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2, 2))
            match_line, match_ref = _NO_LINES, _NO_LINES
        else:
            line_theta, line_rho = ((_NO_ANGLES, _NO_ANGLES) if lines is None
                                    else (_floats(lines.theta), _floats(lines.rho)))
            ref_theta, ref_rho = ((_NO_ANGLES, _NO_ANGLES) if refs is None
                                  else (_floats(refs.theta), _floats(refs.rho)))
            match_line, match_ref = _NO_LINES, _NO_LINES
            if matches is not None and len(matches) and len(line_theta) and len(ref_theta):
                match_line = np.asarray(matches.line, np.int64)
                match_ref = np.asarray(matches.ref, np.int64)
            peaks, ref_pixels, ends = hough_marks(grid.theta_step, grid.rho_step, grid.rho_min,
                                                  line_theta, line_rho, ref_theta, ref_rho,
                                                  match_line, match_ref)
        peak_rows = np.full(len(peaks), -2, dtype=np.intp)
        if len(ends):
            peak_rows[match_line] = ref_ids[match_ref]
        table = self._colours.table
        self._batch("hough/peaks", rr.Points2D).add(
            t, index, len(peaks), positions=peaks, colors=table[peak_rows])
        self._batch("hough/references", rr.Points2D).add(
            t, index, len(ref_ids), positions=ref_pixels, colors=table[ref_ids],
            labels=self._colours.label(ref_ids))
        match_colours = (table[peak_rows[match_line]] if len(ends)
                         else np.empty((0, 4), np.uint8))
        self._batch("hough/matches", rr.LineStrips2D).add(
            t, index, len(ends), strips=list(ends), colors=match_colours)

    def _accumulator(self, t: float, index: int, votes: NDArray | None, n_points: int) -> None:
        """The vote image, batched like the time series but sent every ``IMAGE_BATCH`` images
        (one ``log`` of an image costs ~0.4 ms, a row of a batch ~40 µs). Its format is static
        per entity: a grid of another shape (another sensor's settings) gets its own entity."""
        if votes is None:
            return
        h, w = votes.shape
        entity = self._accumulator_entities.get((h, w))
        if entity is None:
            entity = self._accumulator_entities[(h, w)] = (
                "hough/accumulator" if not self._accumulator_entities
                else f"hough/accumulator/{h}x{w}")
        batch = self._batches.get(entity)
        if batch is None:  # the format and style once: building them costs more than the row
            # A cell gets at most one vote per point: 8 bits hold every vote of a sensor whose
            # first scan has at most 255 points (a 180-beam laser: half the bytes of 16 bits);
            # a later scan of more points is drawn saturated there. 16 bits otherwise.
            dtype = np.uint8 if n_points <= 255 else np.uint16
            self._image_type[entity] = (dtype, int(np.iinfo(dtype).max))
            batch = self._batch(entity, rr.DepthImage, rr.DepthImage.from_fields(
                format=rr.components.ImageFormat(
                    width=w, height=h,
                    channel_datatype="U8" if dtype is np.uint8 else "U16"),
                meter=1.0, colormap="viridis", draw_order=0.0))
        dtype, top = self._image_type[entity]
        image = (votes if n_points <= top else np.minimum(votes, top)).astype(dtype)
        batch.add(t, index, 1, buffer=image.reshape(1, -1).view(np.uint8))
        if len(batch.t) >= IMAGE_BATCH:
            batch.send(self.stream, self._time_column)

    # ---------------------------------------------------------------- time series
    def _metrics(self, t: float, index: int, pose: NDArray, cov: NDArray, correction: Any,
                 outcome: Any) -> None:
        if outcome is not None and outcome.dof > 0 and len(outcome.innovation):
            innovation = np.asarray(outcome.innovation, dtype=float)
            basis = getattr(correction, "observable", None)
            if outcome.dof < 3 and basis is not None and basis.shape[1] == outcome.dof:
                innovation = basis @ innovation  # observed directions back to (x, y, θ)
            if innovation.shape == (3,):
                for name, value in zip(METRICS[:3], (innovation * _DEGREES).tolist(),
                                       strict=True):
                    self._scalar(name, t, index, value)
            self._scalar("nis", t, index, outcome.nis)
        for k, name in enumerate(METRICS[4:7]):  # σ of x, y, θ
            self._scalar(name, t, index, math.sqrt(max(float(cov[k, k]), 0.0)) * _SCALE[k])
        matches = getattr(correction, "matches", None)
        self._scalar("matches", t, index, len(matches) if matches is not None else 0)
        self._error_series.add_estimate(t, index, pose)

    def _scalar(self, name: str, t: float, index: int, value: float) -> None:
        self._batch(_METRIC_ENTITY[name], rr.Scalars).add(t, index, 1, scalars=float(value))

    def _errors(self, final: bool) -> None:
        """The error series of the estimates whose truth has arrived (:class:`ErrorSeries`)."""
        for name, t, scan, value in self._error_series.ready(final):
            self._batch(f"metrics/{name}", rr.Scalars).add(t, scan, 1, scalars=float(value))

    # ---------------------------------------------------------------- serving
    def _start_web_viewer(self, web_port: int) -> None:
        grpc_url = self.grpc_url or ""
        try:
            self._web_viewer = subprocess.Popen(web_viewer_command(grpc_url, web_port),
                                                stdout=subprocess.DEVNULL,
                                                stderr=subprocess.DEVNULL,
                                                preexec_fn=die_with_parent)
        except OSError as exc:
            _log.warning("cannot start the Rerun web viewer (%s); open %s with `rerun`",
                         exc, grpc_url)
            return
        self.web_url = f"http://{SERVE_HOST}:{web_port}/?url={quote(grpc_url, safe='')}"
        _log.info("Rerun web viewer: %s", self.web_url)



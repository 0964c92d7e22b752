"""Every stage of the pipeline recorded to Rerun: the logger the pipeline is given
when somebody wants to look. Its public methods are exactly those of
:class:`fusion.visualize.Logger`. How it looks: :mod:`fusion.rerun_view`; how the rows are
batched: :mod:`fusion.rerun_columns`; how a batch of scans is drawn: :mod:`fusion.rerun_draw`;
the served web viewer: :mod:`fusion.rerun_serve`.

The entities drawn and their paths: :mod:`fusion.rerun_view`.

Timelines: ``time`` (sensor seconds: a duration for simulated clocks, a timestamp once the clock
looks like Unix time) and ``scan`` (sequence; events between scans carry only ``time``).
Angles in the time series are in degrees, lengths in metres.

The Hough image is the accumulator cell for cell: one row per θ cell, one column per
ρ cell, so ρ runs left to right from ``rho_min`` and θ top to bottom from 0. Cell (i_θ, i_ρ) is
the pixel square [i_ρ, i_ρ+1) × [i_θ, i_θ+1), and a continuous (θ, ρ) is drawn at
u = (ρ − ρ_min)/δρ, v = θ/δθ + ½ (θ cell i is centred on iδθ; ρ cell j spans an interval).

Speed: one ``log`` call costs ~100 µs whatever its size, so a scan is kept raw
(:class:`fusion.rerun_scans.ScanRows`: references to its correction's arrays, a copy of its
points and pose) and drawn with the others of its batch, one NumPy pass or compiled call per
field and one ``send_columns`` call per entity, every ``BATCH_SCANS`` scans, every
``BATCH_SECONDS`` of wall time when serving (a live viewer lags at most that), and at
:meth:`RerunLogger.flush`. The Hough image is copied into a block at once (the accumulator is
the biggest array a scan makes); the state log and the hypotheses are logged at once, and when
not serving the SDK gathers them into chunks of ``FILE_CHUNK_BYTES``.

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

from fusion.rerun_columns import (
    BATCH_SCANS,
    ErrorSeries,
)
from fusion.rerun_draw import DEGREES, METRICS, NO_LINES, ScanDrawing
from fusion.rerun_scans import HoughRow, ScanRows, moved_points, scan_points
from fusion.rerun_serve import GRPC_PORT, SERVE_HOST, WEB_PORT, die_with_parent, web_viewer_command
from fusion.rerun_view import (
    ARROW_LENGTH,
    PAINTED,
    SERIES_COLOUR,
    SERIES_COLOURS,
    SERIES_NAMES,
    STATE_LEVELS,
    WALL_COLOUR,
    batch_point_rows,
    default_blueprint,
    hough_marks,
)
from fusion.status import ScanStatus

if TYPE_CHECKING:
    from fusion.estimate import Estimate
    from houghloc import ScanCorrection, SegmentMap

_log = logging.getLogger(__name__)

BATCH_SECONDS = 0.5  # wall-clock seconds a live (served) view lags at most
FILE_CHUNK_BYTES = 8 << 20  # bytes of immediate logs (Hough images) per chunk, when not serving
FILE_FLUSH_SECONDS = 2.0  # ... or this long, whichever first

_NO_ANGLES = np.empty(0)


# ------------------------------------------------------------------------------- the logger
class RerunLogger(ScanDrawing):
    """Records every stage to its own :class:`rerun.RecordingStream` (never the global one).

    ``path``: write an ``.rrd`` file there. ``serve``: host a gRPC server on ``SERVE_HOST`` only
    (port ``grpc_port``; :attr:`grpc_url`) and, unless ``web_port`` is None, a web viewer at
    :attr:`web_url` (a child process, stopped by :meth:`close`). With neither,
    the data goes to memory (:attr:`memory`, for notebooks). ``accumulator_every``: log the Hough
    image every N scans (0: never) — it is the costly part. The default blueprint travels with
    the recording.

    Per-scan data is buffered and sent in columns every ``BATCH_SCANS`` scans (or, when
    serving, ``BATCH_SECONDS`` of wall time), and by :meth:`flush` / :meth:`close` (the Hough
    images also every ``IMAGE_BLOCK_BYTES``); the state log and the hypotheses are logged at once.

    Every stage's writer shares the one stream, its batches, its time columns and the map's
    colours (the stream and its columns: :class:`fusion.rerun_stream.ColumnStream`; a batch of
    scans drawn on it: :class:`fusion.rerun_draw.ScanDrawing`); the parts
    that stand alone are apart (the look: :mod:`fusion.rerun_view`; the scans' raw rows and the
    arrays drawn from them: :mod:`fusion.rerun_scans`; the columns, paths and error series:
    :mod:`fusion.rerun_columns`; the served viewer: :mod:`fusion.rerun_serve`).
    """

    def __init__(self, path: str | Path | None = None, *, serve: bool = False,
                 app_id: str = "houghloc", recording_name: str | None = None,
                 accumulator_every: int = 1, grpc_port: int = GRPC_PORT,
                 web_port: int | None = WEB_PORT) -> None:
        # Unless a viewer watches live, images are gathered into larger chunks (see BATCH_SCANS)
        batcher = None if serve else rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_SECONDS,
                                                           flush_num_bytes=FILE_CHUNK_BYTES)
        super().__init__(rr.RecordingStream(app_id, recording_id=uuid.uuid4(),
                                            batcher_config=batcher))
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
        self._batch_seconds = BATCH_SECONDS if serve else math.inf  # nobody watches a file live
        self._last_send = time.monotonic()
        self._scans_logged = 0
        # compiled (or loaded from the cache) now, not on a scan of the stream
        batch_point_rows(np.zeros(1, bool), np.ones(1, np.int64), np.ones(1, np.int64),
                         NO_LINES, NO_LINES, np.zeros(1, np.int64))
        moved_points(np.zeros((1, 2)), np.zeros((1, 3)), np.ones(1, np.int64))
        hough_marks(1.0, 1.0, 0.0, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, _NO_ANGLES, NO_LINES,
                    NO_LINES)
        self._primary_sensor: str | None = None
        self._odometry: NDArray[np.float64] | None = None
        self._error_series = ErrorSeries()
        self._rows = ScanRows()  # the scans since the last send
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
        self._n_lines = n_lines
        for entity, keep, radius, colour in (("world/map/walls", is_wall, 0.03, WALL_COLOUR),
                                             ("world/map/lines", ~is_wall, 0.02, PAINTED)):
            self.stream.log(entity, rr.LineStrips2D(
                strips[keep], radii=radius, colors=colour, labels=list(ids[keep]),
                show_labels=False, draw_order=1.0), static=True)

    def log_odometry(self, t: float, odom_pose: ArrayLike) -> None:
        """Remember the latest odometry pose; the odometry path is drawn at each scan."""
        self._odometry = np.array(odom_pose, dtype=float).reshape(3)  # kept until sent

    def log_scan(self, t: float, index: int, sensor: str, points: NDArray[np.float64],
                 correction: ScanCorrection | None, estimate: Estimate) -> None:
        """One scan: its points in the world, the robot, the paths, the Hough stage, metrics
        (kept raw in :class:`ScanRows`, drawn a batch at a time; the Hough image at once)."""
        t, index = float(t), int(index)
        pose = np.array(estimate.pose, dtype=float)  # copies: kept until the batch is sent
        cov = np.array(estimate.cov, dtype=float)
        primary = self._is_primary(sensor)
        rows = self._rows
        row = rows.add_scan(t, index, "world/scan/points" if primary
                            else f"world/scan/{sensor}/points", points, correction, pose, cov,
                            estimate.status)
        if self._odometry is not None:
            rows.odometry.append((row, self._odometry))
        if self._truth_unlogged:
            self._truth_unlogged = False
            rows.truth.append((row, self._error_series.latest_truth()))
        if primary:
            rows.matched.append((row, getattr(correction, "matched_map_lines", NO_LINES)))
            rows.hough.append(HoughRow.of(row, correction))
            every = self.accumulator_every
            if (correction is not None and correction.grid is not None and every > 0
                    and self._scans_logged % every == 0):
                self._accumulator(t, index, correction.accumulator, correction.n_points)
        if estimate.status != ScanStatus.ACCEPTED:
            reason = getattr(correction, "reason", "")
            self._batch("log/scan", rr.TextLog).add(
                t, index, 1, text=[f"scan {index} ({sensor}): {estimate.status}"
                                   + (f": {reason}" if reason else "")],
                level=["DEBUG" if estimate.status == ScanStatus.NO_FIX else "WARN"])
        self._batch("metrics/localized", rr.Scalars).add(
            t, index, 1, scalars=float(estimate.localized_probability))
        self._innovation(row, correction, getattr(estimate, "outcome", None))
        self._error_series.add_estimate(t, index, pose)
        along = getattr(estimate, "along", None)
        if along is not None:
            rows.along.append((row, float(along.offset)))
        self._scans_logged += 1
        if (len(rows) >= BATCH_SCANS
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

    def _send_batches(self, final: bool = False) -> None:
        self._send_scans()
        self._errors(final)
        for batch in self._batches.values():
            batch.send(self.stream, self._time_column)
        for images in self._images.values():
            images.send(self.stream, self._time_column)
        self._last_send = time.monotonic()

    def _send_scans(self) -> None:
        """Every scan since the last send, drawn as columns (:mod:`fusion.rerun_scans`)."""
        rows, self._rows = self._rows, ScanRows()
        if len(rows) == 0:
            return
        by_entity: dict[str, list[int]] = {}
        for row, entity in enumerate(rows.points_entity):
            by_entity.setdefault(entity, []).append(row)
        for entity, picked in by_entity.items():
            world, colours, lengths = scan_points(rows, picked, self._colours)
            self._style_once(entity, self._styles["points"])
            self._send(entity, rr.Points2D, rows, picked, lengths, positions=world,
                       colors=colours)
        self._send_robot(rows)
        self._send_metrics(rows)
        if rows.hough:
            self._send_hough(rows)
        self._send_matched_walls(rows)

    # ---------------------------------------------------------------- world
    def _is_primary(self, sensor: str) -> bool:
        if self._primary_sensor is None:
            self._primary_sensor = sensor
        return sensor == self._primary_sensor

    # ---------------------------------------------------------------- time series
    def _innovation(self, row: int, correction: Any, outcome: Any) -> None:
        """The update's innovation in (x, y, θ) and its NIS, when the scan updated the filter."""
        if outcome is None or outcome.dof <= 0 or not len(outcome.innovation):
            return
        innovation = np.asarray(outcome.innovation, dtype=float)
        basis = getattr(correction, "observable", None)
        if outcome.dof < 3 and basis is not None and basis.shape[1] == outcome.dof:
            innovation = basis @ innovation  # observed directions back to (x, y, θ)
        if innovation.shape == (3,):
            x, y, theta = (innovation * DEGREES).tolist()
            self._rows.innovation.append((row, x, y, theta))
        self._rows.nis.append((row, float(outcome.nis)))

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



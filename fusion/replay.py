"""Replay a stream of events through a :class:`~fusion.Localizer`: the offline runner behind
``houghloc run`` and ``houghloc demo``.

Outputs are written so that an interrupted run leaves valid files: the trajectory is streamed one
complete TUM line per scan; ``metrics.json`` is written whole, atomically, at the end (also after
Ctrl-C, marked ``interrupted``).
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from fusion.config import METRICS_VERSION_KEY
from fusion.evaluation import ATE, ATEResult, LostFraction, NEESResult, Trajectory, chi2_band, nees
from fusion.events import Event, Landmark, Odometry, PointSet, ReadStats, Scan, Truth
from fusion.integrity import integrity_scores, is_localized, localized_probability
from fusion.io.files import atomic_write_json
from fusion.io.localized import LocalizedWriter
from fusion.io.tum import TumWriter
from fusion.localizer import Localizer
from fusion.time_order import Held, TimeOrder, settled
from houghloc import __version__


@dataclass
class ReplayResult:
    """The estimated trajectory (one pose per processed scan), ground truth if any, timings."""

    t: NDArray[np.float64]
    poses: NDArray[np.float64]
    cov_upper: NDArray[np.float64]  # N×6: each covariance's upper triangle, row by row
    statuses: list[str]
    truth: Trajectory | None
    localized_probability: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    """Each pose's probability of being within 0.3 m and 5° of the truth (fusion.integrity)"""
    seconds: dict[str, float] = field(default_factory=dict)
    events: int = 0
    interrupted: bool = False
    scans: int = 0
    span: tuple[float | None, float | None] = (None, None)  # first and last scan time
    scan_cpu: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    """Each recorded scan's CPU time (s), in the order of ``t``, when ``replay`` was asked to
    time them: the cost of its fusion."""
    localized_scans: int = 0
    """poses reported localized (counted whether or not the poses are kept)"""
    probability_sum: float = 0.0

    def integrity(self) -> dict[str, float]:
        """The share of poses reported localized and their mean probability."""
        n = max(self.scans, 1)
        return {"localized_fraction": self.localized_scans / n,
                "mean_probability": self.probability_sum / n}

    @property
    def trajectory(self) -> Trajectory:
        return Trajectory(self.t, self.poses)

    @property
    def covs(self) -> NDArray[np.float64]:
        """The pose covariances, N×3×3 (built on each call: a long run keeps only the upper
        triangles)."""
        return self.covs_at(slice(None))

    def covs_at(self, index: slice | NDArray[np.intp]) -> NDArray[np.float64]:
        """The covariances of the scans ``index`` selects, K×3×3."""
        upper = self.cov_upper[index]
        return upper[:, _FULL_FROM_UPPER].reshape(-1, 3, 3)

    @property
    def scans_per_second(self) -> float:
        total = self.seconds.get("total", 0.0)
        return self.scans / total if total > 0 else float("nan")


_UPPER = np.triu_indices(3)
_FULL_FROM_UPPER = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])  # upper triangle → row-major 3×3


class _Rows:
    """Fixed-width float rows appended one at a time into one array: 8 bytes a value, where a
    list of small arrays costs some 100 bytes a row. The array grows in place
    (``ndarray.resize``: a large block is remapped, not copied, and the spare capacity is not
    resident until written), so a ten-hour log's results cost their own size and no copy."""

    def __init__(self, width: int) -> None:
        self._data = np.empty((1024, width))
        self._n = 0

    def append(self, *values: ArrayLike) -> None:
        if self._n == len(self._data):
            self._data.resize((2 * len(self._data), self._data.shape[1]), refcheck=False)
        self._data[self._n] = np.concatenate([np.ravel(v) for v in values])
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def array(self) -> NDArray[np.float64]:
        """The rows, taken out of the collector (shrunk in place, not copied)."""
        data, self._data = self._data, np.empty((0, self._data.shape[1]))
        data.resize((self._n, data.shape[1]), refcheck=False)
        return data


@contextmanager
def _signals_between_events() -> Iterator[Callable[[], None]]:
    """While a run replays, SIGINT and SIGTERM take effect between two events, not inside one:
    raised from a handler while compiled code is running (between a kernel's return and its
    result's conversion), the exception is lost and a ``SystemError`` takes its place. The
    signals whose handler is a Python function (Ctrl-C's, the CLI's SIGTERM) are recorded, and
    the yielded check calls that handler at the next event."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None  # only the main thread receives signals
        return
    received: list[tuple[int, Any]] = []
    handlers: dict[int, Callable[[int, Any], Any]] = {}
    for stop in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(stop)
        if callable(handler):
            handlers[int(stop)] = handler

    def record(signum: int, frame: Any) -> None:
        received.append((signum, frame))

    def stop_if_signalled() -> None:
        if received:
            signum, frame = received.pop(0)
            handlers[signum](signum, frame)

    for sig in handlers:
        signal.signal(sig, record)
    try:
        yield stop_if_signalled
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        for signum, _ in received:  # came while the outputs were closed: delivered now
            signal.raise_signal(signum)


def replay(events: Iterable[Event], localizer: Localizer, *,
           trajectory_path: str | Path | None = None, progress: bool | None = None,
           description: str = "replay", keep: bool = True,
           time_scans: bool = False, localized_path: str | Path | None = None) -> ReplayResult:
    """Feed every event to the localizer in arrival order; collect the estimate at each scan.

    ``progress``: a tqdm bar in scans (None: only when writing to a terminal). ``keep=False``
    keeps no per-scan results in memory (they are in the trajectory file): memory then does not
    grow with the log, and only counts and timings are returned. ``time_scans``: keep each
    scan's CPU time too (``ReplayResult.scan_cpu``, for a benchmark's worst window).
    ``localized_path``: where each pose's integrity is written as it is recorded
    (:mod:`fusion.io.localized`).

    A scan taken after the newest odometry reading is used at once, but its pose is recorded
    when the odometry covering its time has arrived, or the next scan at the latest
    (:class:`fusion.time_order.TimeOrder`, as the ROS 2 node does). Outputs stay in scan order.
    """
    rows = _Rows(1 + 3 + 6 + 1)  # t, pose, covariance's upper triangle, localized probability
    statuses: list[str] = []  # the same few strings, shared: one reference a scan
    scan_cpu: list[float] = []
    truth = _Rows(4)  # t, x, y, θ
    seconds = {"odometry": 0.0, "scans": 0.0}
    writer = TumWriter(trajectory_path).open() if trajectory_path is not None else None
    side = LocalizedWriter(localized_path).open() if localized_path is not None else None
    reported = [0, 0.0]  # poses reported localized, sum of the probabilities
    bar = tqdm(desc=description, unit="scan", disable=(None if progress is None else not progress),
               mininterval=0.5, dynamic_ncols=True)
    n_events = 0
    n_scans = 0
    first_t = last_t = None
    interrupted = False
    tracker = localizer.tracker
    order = TimeOrder()

    def record(due: list[Held]) -> None:
        for held in due:
            est = settled(held, tracker)
            probability = localized_probability(np.asarray(est.cov), est.mode)
            reported[0] += is_localized(probability)
            reported[1] += probability
            if keep:
                rows.append(held.t_out, est.pose, np.asarray(est.cov)[_UPPER], probability)
                statuses.append(est.status)
            if writer is not None:
                writer.write(held.t_out, *est.pose)
            if side is not None:
                side.write(held.t_out, probability, est.status)

    started = time.perf_counter()
    with _signals_between_events() as stop_if_signalled:
        try:
            for event in events:
                stop_if_signalled()
                n_events += 1
                t0 = time.perf_counter()
                if isinstance(event, Odometry):
                    localizer.on_odometry(event.t, event.x, event.y, event.theta,
                                          event.unmeasured)
                    seconds["odometry"] += time.perf_counter() - t0
                    record(order.odometry(tracker.odometry_time))
                    continue
                if isinstance(event, Landmark):
                    localizer.on_landmark(event.t, event.label, event.bearing)
                    continue
                if isinstance(event, Truth):
                    truth.append((event.t, event.x, event.y, event.theta))
                    localizer.logger.log_truth(event.t, (event.x, event.y, event.theta))
                    continue
                record(order.scan_arriving())
                cpu = time.process_time() if time_scans else 0.0
                if isinstance(event, Scan):
                    est = localizer.on_scan(event.t, event.ranges, event.angles, event.sensor,
                                            event.max_range)
                elif isinstance(event, PointSet):
                    est = localizer.on_points(event.t, event.points, event.sensor)
                else:
                    continue
                seconds["scans"] += time.perf_counter() - t0
                if time_scans:
                    scan_cpu.append(time.process_time() - cpu)
                stamp = getattr(event, "stamp", None)  # a record's own (out-of-order) timestamp
                t_est = est.t if stamp is None else stamp
                n_scans += 1
                first_t = t_est if first_t is None else first_t
                last_t = t_est
                record(order.localized(est, t_est, tracker.odometry_time))
                bar.update()
            stop_if_signalled()  # a signal that came in the last event
        except KeyboardInterrupt:
            interrupted = True
        finally:
            record(order.drain())
            bar.close()
            if writer is not None:
                writer.close()
            if side is not None:
                side.close()
            localizer.logger.flush()
    seconds["total"] = time.perf_counter() - started
    seconds.update(localizer.stats.seconds)
    table, truth_table = rows.array(), truth.array()
    return ReplayResult(
        table[:, 0], table[:, 1:4], table[:, 4:10], statuses,
        Trajectory(truth_table[:, 0], truth_table[:, 1:]) if len(truth_table) else None,
        table[:, 10], seconds, n_events, interrupted, n_scans, (first_t, last_t),
        np.array(scan_cpu), int(reported[0]), float(reported[1]))


def accuracy(result: ReplayResult | Trajectory, reference: Trajectory | None) -> dict[str, Any]:
    """ATE, lost fraction (and NEES, given covariances) against ground truth or reference poses."""
    est = result if isinstance(result, Trajectory) else result.trajectory
    if reference is None or len(reference) == 0 or len(est) == 0:
        return {}
    ate = ATE().compute(est, reference)
    lost = LostFraction().from_ate(ate)  # the same association, not a second one
    out: dict[str, Any] = {"ate": ate.as_dict(), "lost": lost.as_dict()}
    idx = ate.association.est_index
    if len(idx) and isinstance(result, ReplayResult):
        out["nees"] = _nees(result, reference, ate).as_dict()
        if len(result.localized_probability) == len(est):
            out["integrity"] = integrity_scores(result.localized_probability[idx],
                                                ~np.asarray(lost.lost, dtype=bool))
    return out


def _nees(result: ReplayResult, reference: Trajectory, ate: ATEResult,
          chunk: int = 65536) -> NEESResult:
    """NEES of every associated estimate, a chunk at a time: a ten-hour run's covariances are
    not copied whole (fancy indexing copies)."""
    est_index, ref_index = ate.association.est_index, ate.association.ref_index
    values = np.empty(len(est_index))
    for lo in range(0, len(est_index), chunk):
        i, j = est_index[lo:lo + chunk], ref_index[lo:lo + chunk]
        err = np.column_stack((result.poses[i, :2] - reference.poses[j, :2],
                               ate.heading_errors[lo:lo + chunk]))
        values[lo:lo + chunk] = nees(err, result.covs_at(i)).values
    return NEESResult(values, 3, chi2_band(len(values), 3))


def metrics_document(result: ReplayResult, localizer: Localizer, read_stats: ReadStats | None,
                     reference: Trajectory | None, extra: dict[str, Any] | None = None
                     ) -> dict[str, Any]:
    """Everything ``metrics.json`` reports: counts, time per stage, accuracy when known."""
    own = localizer.summary()
    n = result.scans
    doc: dict[str, Any] = {METRICS_VERSION_KEY: __version__, "initial_pose": own["initial_pose"],
                           "scans": n, "events": result.events,
                           "interrupted": result.interrupted}
    doc.update((k, v) for k, v in own.items() if k not in ("initial_pose", "config"))
    doc["integrity"] = result.integrity()
    doc["seconds"] = {k: round(v, 6) for k, v in result.seconds.items()}
    doc["time_per_scan_ms"] = {
        k: round(1e3 * v / n, 4) for k, v in result.seconds.items() if n and k != "total"}
    doc["scans_per_second"] = _finite(result.scans_per_second)
    if read_stats is not None:  # the reader's stray stamps beside the localizer's
        doc["stray_timestamps"] += read_stats.stray_timestamps
        doc["log"] = {"records": read_stats.records, "skipped": read_stats.skipped,
                      "backwards_timestamps": read_stats.backwards_timestamps,
                      "stray_timestamps": read_stats.stray_timestamps,
                      "warnings_by_kind": read_stats.by_kind(),
                      "warnings": read_stats.warnings[:20]}
    doc.update(accuracy(result, reference))
    if extra:
        doc.update(extra)
    doc["config"] = own["config"]  # last: the long part, what `--config metrics.json` reads back
    return doc


def write_metrics(path: str | Path, doc: dict[str, Any]) -> None:
    atomic_write_json(path, _json_safe(doc))


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def _json_safe(value: Any) -> Any:
    """NaN and infinities become null (JSON has no NaN; a reader must not choke on the file)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value

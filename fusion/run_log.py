"""One run of houghloc over a log: the function behind ``houghloc run``, ``houghloc demo``, the
benchmark's sweep and the notebooks.

    log (CARMEN, .mat, simulator directory, ROS bag) or events
      ─▶ Localizer(map, config, initial pose, logger) ─▶ replay ─▶ trajectory.tum, metrics.json

The caller only parses and prints: :func:`run_log` returns what there is to say.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.config import LocalizerConfig
from fusion.evaluation import Trajectory
from fusion.events import Event, ReadStats, Truth
from fusion.io import from_first_scan, is_rosbag, merge_by_time, open_log, read_rosbag
from fusion.localizer import Localizer
from fusion.replay import ReplayResult, metrics_document, replay, write_metrics
from fusion.visualize import Logger, NullLogger
from houghloc import SegmentMap


class RunError(ValueError):
    """A run that cannot start: options that do not fit the log."""


@dataclass(frozen=True, slots=True)
class LogSource:
    """A log opened for a run: its events, what its reader counted, the ground truth beside it
    (a simulator directory's ``gt.tum``), the configuration with what the log says of the sensor
    (a ROS bag's ``/tf_static`` mount), and a line saying where the data came from (bags)."""

    events: Iterable[Event]
    read_stats: ReadStats | None
    ground_truth: Path | None
    config: LocalizerConfig
    origin: str | None = None


@dataclass(frozen=True, slots=True)
class LogRun:
    """What a run produced: the replay's result, the localizer (its stats, the manager's log),
    the ``metrics.json`` document, and the reader's counts."""

    result: ReplayResult
    localizer: Localizer
    metrics: dict[str, Any]
    read_stats: ReadStats | None


def open_source(path: str | Path, config: LocalizerConfig, scan_topic: str | None = None,
                odom_topic: str | None = None) -> LogSource:
    """Open any supported log for a run with ``config``; a ROS bag's scans feed the configured
    laser, mounted as its ``/tf_static`` says when it says."""
    path = Path(path)
    if not is_rosbag(path):
        if scan_topic or odom_topic:
            raise RunError(f"--scan-topic and --odom-topic are for ROS bags; {path} is not one")
        gt = path / "gt.tum" if path.is_dir() and (path / "gt.tum").exists() else None
        events, stats = open_log(path)
        return LogSource(events, stats, gt, config)
    if config.laser is None:
        raise RunError("a ROS bag's LaserScan needs a laser sensor in the config")
    bag = read_rosbag(path, scan_topic=scan_topic, odometry_topic=odom_topic, sensor=config.laser)
    scans, odometry = bag.topics()
    mount = bag.sensor_mount()
    origin = (f"{path}: scans from {scans}, odometry from {odometry or 'nowhere'}; "
              + ("laser mount from /tf_static: x {:.3f} m, y {:.3f} m, θ {:.4f} rad".format(*mount)
                 if mount is not None else "no /tf_static mount: the config's"))
    if mount is not None:
        config = config.with_mount(config.laser, mount)
    events, stats = open_log(path, scan_topic=scan_topic, odometry_topic=odom_topic,
                             sensor=config.laser)
    return LogSource(events, stats, None, config, origin)


def run_log(source: LogSource | Iterable[Event], segment_map: SegmentMap,
            config: LocalizerConfig | None = None, *, initial_pose: ArrayLike | None = None,
            reference: Trajectory | None = None, out: Path | None = None,
            logger: Logger | None = None, progress: bool | None = None,
            description: str = "localizing", time_scans: bool = False,
            metrics_extra: dict[str, Any] | None = None) -> LogRun:
    """Localize a log (a :class:`LogSource`, or events as they are) in ``segment_map``.

    ``initial_pose``: where the robot starts (None: global localization; with a log, its
    odometry before the first scan is skipped). ``reference``: poses to score against (with a
    log, also shown in the recording beside the estimate). ``out``: a directory for
    ``trajectory.tum``, ``localized.csv`` (:mod:`fusion.io.localized`) and ``metrics.json``
    (None: nothing written, every pose kept in memory).
    ``time_scans``: each scan's CPU time in the result (a benchmark's worst window)."""
    logger = logger or NullLogger()
    if isinstance(source, LogSource):
        events, read_stats = source.events, source.read_stats
        config = source.config if config is None else config
        if initial_pose is not None:
            events = from_first_scan(events)
        if reference is not None and not isinstance(logger, NullLogger):
            # the recording shows the ground truth beside the estimate, in time (without a
            # recording the reference is only scored, and is not carried through the replay)
            truth = (Truth(float(t), *map(float, pose))
                     for t, pose in zip(reference.t, reference.poses, strict=True))
            events = merge_by_time([events, truth])
    else:  # events as they come (a simulation's carry its own truth)
        events, read_stats = source, None
    pose: NDArray[np.float64] | None = (None if initial_pose is None
                                        else np.asarray(initial_pose, dtype=float))
    localizer = Localizer(segment_map, config, pose, logger)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    result = replay(events, localizer,
                    trajectory_path=None if out is None else out / "trajectory.tum",
                    localized_path=None if out is None else out / "localized.csv",
                    progress=progress, description=description,
                    keep=out is None or reference is not None, time_scans=time_scans)
    metrics = metrics_document(result, localizer, read_stats, reference, metrics_extra)
    if out is not None:
        write_metrics(out / "metrics.json", metrics)
    return LogRun(result, localizer, metrics, read_stats)

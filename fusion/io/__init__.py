"""Readers and writers: logs in, events out; trajectories and metrics out.

``open_log(path)`` picks the reader from the file:

* ``*.mat`` → the Intel lab ``.mat`` (``read_intel_mat``);
* a directory with ``log.carmen`` → the simulator's output directory: its CARMEN log, merged in time
  with its ``camera.points`` if there is one (and any ``extra_sources``);
* a directory with ``metadata.yaml``, a ``*.bag``, ``*.mcap`` or ``*.db3`` → a ROS bag;
* anything else → a CARMEN text log, plain or gzip (``read_carmen``).

All readers stream: they return an iterable of events plus a ``ReadStats`` that fills as the
events are consumed. Every reader raises ``LogError`` for a file it cannot use.

``read_reference(path)`` reads a reference trajectory to score a run against: a TUM file, or the
corrected poses a CARMEN log's laser records carry.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.events import Event, ReadStats, Scan
from fusion.io.camera_points import read_camera_points
from fusion.io.carmen import CarmenLog, read_carmen
from fusion.io.carmen_conventions import FlaserSpacing, flaser_angles
from fusion.io.errors import LogError
from fusion.io.files import atomic_write_json, atomic_write_text
from fusion.io.intel_mat import IntelMatLog, read_intel_mat
from fusion.io.relations import INTEL_TIME_OFFSET, Relations, read_relations
from fusion.io.rosbag import RosbagLog, read_rosbag
from fusion.io.textfile import open_text_log
from fusion.io.timing import MAX_TIME_STEP, StrayStampFilter, from_first_scan
from fusion.io.tum import TrajectoryValueError, TumWriter, read_tum, write_tum

__all__ = [
    "INTEL_TIME_OFFSET",
    "MAX_TIME_STEP",
    "SIM_CAMERA_NAME",
    "SIM_LOG_NAME",
    "CarmenLog",
    "EventSource",
    "FlaserSpacing",
    "IntelMatLog",
    "LogError",
    "Relations",
    "RosbagLog",
    "StrayStampFilter",
    "TrajectoryValueError",
    "TumWriter",
    "atomic_write_json",
    "atomic_write_text",
    "corrected_scans",
    "flaser_angles",
    "from_first_scan",
    "is_rosbag",
    "merge_by_time",
    "open_log",
    "read_camera_points",
    "read_carmen",
    "read_intel_mat",
    "read_reference",
    "read_relations",
    "read_rosbag",
    "read_tum",
    "write_tum",
]

SIM_LOG_NAME = "log.carmen"
"""The CARMEN log inside a simulator output directory."""
SIM_CAMERA_NAME = "camera.points"
"""Its camera frames, if it has any (:mod:`fusion.io.camera_points`)."""

ROSBAG_SUFFIXES = (".bag", ".mcap", ".db3")

EventSource = Callable[[Path], Iterable[Event]]
"""An extra reader for a simulator directory: given the directory, it returns events in time order
(e.g. the camera's ``PointSet``s from ``camera.points``). It may return nothing."""


def open_log(
    path: str | Path,
    *,
    extra_sources: Iterable[EventSource] = (),
    **reader_options: Any,
) -> tuple[Iterator[Event], ReadStats]:
    """Open any supported log; return (events iterator, stats filled while iterating).

    ``reader_options`` go to the chosen reader (e.g. ``raw_odometry=`` or ``spacing=`` for CARMEN,
    ``scan_topic=`` for bags). A simulator directory's ``camera.points`` and ``extra_sources``
    are merged with its CARMEN log by time (stable: on equal times the log's events come first);
    the camera file's bad records are counted and warned about in the same stats.
    Raises ``LogError`` for a missing path or a directory that is neither kind.
    """
    events, stats = _open_reader(Path(path), extra_sources, reader_options)
    return iter(StrayStampFilter(events, stats, name=str(path))), stats


def read_reference(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A reference trajectory, times (N,) and poses N×3, sorted by time: a TUM file
    (:func:`read_tum`), or a corrected CARMEN log (plain or gzip), whose laser records carry
    the corrected poses (:func:`corrected_scans`). Raises ``LogError`` naming the problem."""
    path = Path(path)
    if not _starts_with_a_record(path):
        return read_tum(path)
    scans = corrected_scans(path)
    if not scans:
        raise LogError(path, "a CARMEN log whose laser records carry no corrected pose (its "
                             "odometry is raw): give a corrected log or a TUM trajectory")
    times = np.array([s.t for s in scans], dtype=float)
    order = np.argsort(times, kind="stable")
    poses = np.array([s.reference for s in scans], dtype=float).reshape(-1, 3)
    return times[order], poses[order]


def corrected_scans(path: str | Path) -> list[Scan]:
    """The scans of a CARMEN log that carry a corrected pose (none for a raw log)."""
    events, _ = open_log(path)
    return [e for e in events if isinstance(e, Scan) and e.reference is not None]


def _starts_with_a_record(path: Path) -> bool:
    """Does the first line that is neither blank nor a comment start with a word (a CARMEN
    record's name) rather than a number (a TUM line)?"""
    if not path.is_file():
        return False  # read_tum says what is wrong
    with open_text_log(path) as f:
        for line in f:
            tokens = line.split(maxsplit=1)
            if tokens and not tokens[0].startswith("#"):
                return tokens[0][:1].isalpha()
    return False


def is_rosbag(path: str | Path) -> bool:
    """A ROS 1 ``.bag``, a ROS 2 bag directory, or a ROS 2 bag's storage file."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file() and not (path / SIM_LOG_NAME).is_file()
    return path.suffix.lower() in ROSBAG_SUFFIXES


def _open_reader(path: Path, extra_sources: Iterable[EventSource],
                 reader_options: dict[str, Any]) -> tuple[Iterable[Event], ReadStats]:
    if not path.exists():
        raise LogError(path, "file not found")
    if path.is_dir():
        if (path / SIM_LOG_NAME).is_file():
            carmen = read_carmen(path / SIM_LOG_NAME, **reader_options)
            streams = [iter(carmen), *(iter(source(path)) for source in extra_sources)]
            if (path / SIM_CAMERA_NAME).is_file():
                streams.append(read_camera_points(path / SIM_CAMERA_NAME, carmen.stats))
            events = merge_by_time(streams) if len(streams) > 1 else streams[0]
            return events, carmen.stats
        if (path / "metadata.yaml").is_file():
            bag = read_rosbag(path, **reader_options)
            return iter(bag), bag.stats
        raise LogError(path, f"directory without {SIM_LOG_NAME} or a ROS 2 bag's metadata.yaml")
    suffix = path.suffix.lower()
    if suffix == ".mat":
        mat = read_intel_mat(path, **reader_options)
        return iter(mat), mat.stats
    if suffix in ROSBAG_SUFFIXES:
        bag = read_rosbag(path, **reader_options)
        return iter(bag), bag.stats
    carmen = read_carmen(path, **reader_options)
    return iter(carmen), carmen.stats


def merge_by_time(streams: Iterable[Iterable[Event]]) -> Iterator[Event]:
    """Merge event streams that are each in arrival order into one (lazy; ties keep stream order).

    A point set arrives at ``arrival`` (its data was taken earlier, at ``t``); everything else
    arrives when it was taken.
    """
    return heapq.merge(*streams, key=arrival_time)


def arrival_time(event: Event) -> float:
    arrival = getattr(event, "arrival", None)
    return event.t if arrival is None else arrival

"""ROS 1 and ROS 2 bags (``rosbags``, no ROS install needed): ``sensor_msgs/msg/LaserScan`` and
``nav_msgs/msg/Odometry`` become ``Scan`` and ``Odometry`` events.

* Time: the message's ``header.stamp`` (the measurement time); the bag's record time only when
  the stamp is zero (unset).
* Odometry: ``pose.pose.position`` x, y and the yaw of ``pose.pose.orientation``.
* LaserScan: beam i at ``angle_min + i·angle_increment``; ``Scan.max_range = range_max`` (returns at
  or beyond it mean no return). NaN (invalid, REP 117) and ranges below ``range_min`` are replaced
  by +inf, i.e. "no return", so they can never become points.
* Events come in the bag's record order; header stamps that go backwards are passed on and
  counted in ``ReadStats.backwards_timestamps``.

A message that cannot be decoded is skipped with a warning (``ReadStats`` and the ``logging``
logger ``fusion.io.rosbag``); a bag that cannot be opened, or has neither topic type, raises
``LogError``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.events import Event, Odometry, ReadStats, Scan
from fusion.io.errors import LogError

log = logging.getLogger(__name__)

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
LOGGED_WARNINGS = 20
ROSBAG2_FILE_SUFFIXES = (".mcap", ".db3")


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Heading (rotation about z) of a quaternion; exact for planar rotations."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def bag_paths(path: str | Path) -> list[Path]:
    """What ``AnyReader`` must be given: a ROS 1 ``.bag`` file, or a ROS 2 bag *directory* (a
    ``.mcap``/``.db3`` file inside a directory with ``metadata.yaml`` means that directory)."""
    path = Path(path)
    if path.is_file() and path.suffix in ROSBAG2_FILE_SUFFIXES:
        if not (path.parent / "metadata.yaml").is_file():
            raise LogError(
                path, "a ROS 2 storage file needs the metadata.yaml of its bag directory"
            )
        return [path.parent]
    return [path]


@dataclass
class RosbagLog:
    """A ROS bag opened for streaming; iterate for events, ``stats`` fills as it goes."""

    path: Path
    scan_topics: Sequence[str] | None = None
    odometry_topics: Sequence[str] | None = None
    stats: ReadStats = field(default_factory=ReadStats)

    def __iter__(self) -> Iterator[Event]:
        from rosbags.highlevel import AnyReader  # imported on use: it is slow to import

        stats = self.stats
        stats.records = stats.skipped = stats.backwards_timestamps = 0
        stats.warnings.clear()
        try:
            reader = AnyReader(bag_paths(self.path))
            reader.open()
        except LogError:
            raise
        except Exception as err:  # AnyReaderError, FileNotFoundError, storage errors…
            raise LogError(self.path, f"cannot open as a ROS bag ({err})") from None
        try:
            connections = self._connections(reader.connections)
            last_t: float | None = None
            angles_cache: dict[tuple[int, float, float], NDArray[np.float64]] = {}
            for index, (connection, bag_time, raw) in enumerate(reader.messages(connections)):
                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                    event = _to_event(
                        msg, connection.msgtype, connection.topic, bag_time, angles_cache
                    )
                except Exception as err:  # a corrupt message must not end the replay
                    stats.warn(f"message {index} on {connection.topic}: skipped ({err})")
                    if stats.skipped <= LOGGED_WARNINGS:
                        log.warning("%s: %s", self.path, stats.warnings[-1])
                    continue
                stats.records += 1
                if last_t is not None and event.t < last_t:
                    stats.backwards_timestamps += 1
                last_t = event.t
                yield event
        finally:
            reader.close()
        if stats.records == 0:
            raise LogError(self.path, "no usable LaserScan or Odometry message")

    def _connections(self, connections: Sequence[Any]) -> list[Any]:
        wanted = [
            c
            for c in connections
            if (c.msgtype == LASER_SCAN and _selected(c.topic, self.scan_topics))
            or (c.msgtype == ODOMETRY and _selected(c.topic, self.odometry_topics))
        ]
        if not wanted:
            found = sorted({f"{c.topic} ({c.msgtype})" for c in connections}) or ["nothing"]
            raise LogError(
                self.path, f"no {LASER_SCAN} or {ODOMETRY} topic; found {', '.join(found)}"
            )
        return wanted


def read_rosbag(
    path: str | Path,
    *,
    scan_topics: Sequence[str] | None = None,
    odometry_topics: Sequence[str] | None = None,
) -> RosbagLog:
    """Open a ROS 1 ``.bag`` or a ROS 2 bag (directory, or its ``.mcap``/``.db3``) for streaming.

    ``scan_topics``/``odometry_topics``: restrict to these topics (default: every topic of the
    type). A scan's ``sensor`` is its topic name. Raises ``LogError`` for a missing path at once;
    other problems with the bag are raised as ``LogError`` when iteration starts.
    """
    path = Path(path)
    if not path.exists():
        raise LogError(path, "file not found")
    return RosbagLog(path, scan_topics, odometry_topics)


def _selected(topic: str, topics: Sequence[str] | None) -> bool:
    return topics is None or topic in topics


def _stamp(msg: Any, bag_time_ns: int) -> float:
    stamp = msg.header.stamp
    t = stamp.sec + stamp.nanosec * 1e-9
    return t if t > 0 else bag_time_ns * 1e-9


def _to_event(
    msg: Any,
    msgtype: str,
    topic: str,
    bag_time_ns: int,
    angles_cache: dict[tuple[int, float, float], NDArray[np.float64]],
) -> Event:
    t = _stamp(msg, bag_time_ns)
    if msgtype == ODOMETRY:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        theta = yaw_from_quaternion(q.x, q.y, q.z, q.w)
        if not all(math.isfinite(v) for v in (p.x, p.y, theta)):
            raise ValueError("non-finite odometry pose")
        return Odometry(t, float(p.x), float(p.y), theta)
    ranges = np.asarray(msg.ranges, dtype=float).copy()
    invalid = np.isnan(ranges) | (ranges < msg.range_min)
    ranges[invalid] = np.inf
    key = (len(ranges), float(msg.angle_min), float(msg.angle_increment))
    angles = angles_cache.get(key)
    if angles is None:
        angles = msg.angle_min + msg.angle_increment * np.arange(len(ranges), dtype=float)
        angles.flags.writeable = False
        angles_cache[key] = angles
    return Scan(t, ranges, angles, max_range=float(msg.range_max), sensor=topic)

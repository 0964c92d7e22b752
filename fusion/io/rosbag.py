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

* Topics: the scans of one ``LaserScan`` topic and the odometry of one ``Odometry`` topic. Unless
  named, ``/scan`` and ``/odom`` when the bag has them, else the bag's only topic of the type.
  Scans carry the name of the configured sensor they feed (``sensor``, default ``laser``), not
  their topic, so a stock bag needs no configuration.
* The laser's mount: :meth:`RosbagLog.sensor_mount` reads it off ``/tf_static`` (the transform
  from the odometry's ``child_frame_id``, the robot's base, to the scans' ``frame_id``), as a
  robot's URDF publishes it.

A message that cannot be decoded is skipped with a warning (``ReadStats`` and the ``logging``
logger ``fusion.io.rosbag``); a bag that cannot be opened, or has no usable scan topic, raises
``LogError`` with a one-line message that lists the bag's topics.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from fusion.events import Event, Odometry, ReadStats, Scan
from fusion.io.errors import LogError

log = logging.getLogger(__name__)

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
DEFAULT_SCAN_TOPIC = "/scan"
DEFAULT_ODOMETRY_TOPIC = "/odom"
STATIC_TF_TOPIC = "/tf_static"
BASE_FRAMES = ("base_link", "base_footprint")
"""The robot's frame when no odometry message names it (REP 105)."""
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
    scan_topic: str | None = None
    odometry_topic: str | None = None
    sensor: str = "laser"
    stats: ReadStats = field(default_factory=ReadStats)

    def __iter__(self) -> Iterator[Event]:
        stats = self.stats
        stats.records = stats.skipped = stats.backwards_timestamps = 0
        stats.warnings.clear()
        with self._opened() as reader:
            connections = self._connections(reader.connections)
            last_t: float | None = None
            angles_cache: dict[tuple[int, float, float], NDArray[np.float64]] = {}
            for index, (connection, bag_time, raw) in enumerate(reader.messages(connections)):
                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                    event = message_to_event(msg, connection.msgtype, self.sensor, bag_time,
                                      angles_cache)
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
        if stats.records == 0:
            raise LogError(self.path, "no usable LaserScan or Odometry message")

    def topics(self) -> tuple[str, str | None]:
        """The scan topic and the odometry topic (None: the bag has none) that are replayed."""
        with self._opened() as reader:
            return self._topics(reader.connections)

    def sensor_mount(self) -> tuple[float, float, float] | None:
        """The laser's pose on the robot (x, y, θ), read off ``/tf_static``: the transform from
        the robot's base (the odometry's ``child_frame_id``, else ``base_link`` or
        ``base_footprint``) to the scans' ``frame_id``, projected on the floor. None when the bag
        has no static transforms joining the two frames."""
        with self._opened() as reader:
            scan_topic, odometry_topic = self._topics(reader.connections)
            laser = _first(reader, scan_topic, lambda m: m.header.frame_id)
            base = (None if odometry_topic is None
                    else _first(reader, odometry_topic, lambda m: m.child_frame_id))
            static = [c for c in reader.connections
                      if c.topic == STATIC_TF_TOPIC and c.msgtype == TF_MESSAGE]
            tree = StaticTree()
            # (no connections would mean every message to rosbags)
            for connection, _, raw in reader.messages(static) if static else ():
                try:
                    transforms = reader.deserialize(raw, connection.msgtype).transforms
                except Exception as err:  # a corrupt message: the others may still do
                    log.warning("%s: a /tf_static message is unreadable (%s)", self.path, err)
                    continue
                for tf in transforms:
                    if not tree.add(tf):
                        log.warning("%s: /tf_static %s -> %s is no rigid motion: ignored",
                                    self.path, tf.header.frame_id, tf.child_frame_id)
        if not laser:
            return None
        for frame in ([base] if base else list(BASE_FRAMES)):
            mount = tree.planar(frame.lstrip("/"), laser.lstrip("/"))
            if mount is not None:
                return mount
        return None

    @contextmanager
    def _opened(self) -> Iterator[Any]:
        from rosbags.highlevel import AnyReader  # imported on use: it is slow to import

        try:
            reader = AnyReader(bag_paths(self.path))
            reader.open()
        except LogError:
            raise
        except Exception as err:  # AnyReaderError, FileNotFoundError, storage errors…
            raise LogError(self.path, f"cannot open as a ROS bag ({err})") from None
        try:
            yield reader
        finally:
            reader.close()

    def _topics(self, connections: Sequence[Any]) -> tuple[str, str | None]:
        scan = _choose(self.path, connections, LASER_SCAN, self.scan_topic, DEFAULT_SCAN_TOPIC,
                       "--scan-topic")
        assert scan is not None  # required: a LogError otherwise
        odometry = _choose(self.path, connections, ODOMETRY, self.odometry_topic,
                           DEFAULT_ODOMETRY_TOPIC, "--odom-topic", required=False)
        return scan, odometry

    def _connections(self, connections: Sequence[Any]) -> list[Any]:
        scan, odometry = self._topics(connections)
        return [c for c in connections
                if (c.topic, c.msgtype) in ((scan, LASER_SCAN), (odometry, ODOMETRY))]


class StaticTree:
    """Static transforms (``geometry_msgs/TransformStamped``), child → parent, composed on
    demand: the pose of one frame in another, when they share a root."""

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, NDArray[np.float64]]] = {}

    def add(self, tf: Any) -> bool:
        """Take one transform; False (and nothing kept) when it is no rigid motion: a
        non-finite number, or a quaternion of zero length."""
        t, q = tf.transform.translation, tf.transform.rotation
        quaternion = np.array([q.x, q.y, q.z, q.w], dtype=float)
        translation = np.array([t.x, t.y, t.z], dtype=float)
        if not (np.isfinite(quaternion).all() and np.isfinite(translation).all()
                and np.linalg.norm(quaternion) > 1e-9):
            return False
        matrix = np.eye(4)
        matrix[:3, :3] = Rotation.from_quat(quaternion).as_matrix()
        matrix[:3, 3] = translation
        self._parent[tf.child_frame_id.lstrip("/")] = (tf.header.frame_id.lstrip("/"), matrix)
        return True

    def _to_root(self, frame: str) -> tuple[str, NDArray[np.float64]]:
        """The frame's root and the frame's pose in it."""
        pose, seen = np.eye(4), {frame}
        while frame in self._parent:
            frame, matrix = self._parent[frame]
            if frame in seen:  # a cycle: no tree
                break
            seen.add(frame)
            pose = matrix @ pose
        return frame, pose

    def planar(self, base: str, child: str) -> tuple[float, float, float] | None:
        """``child``'s pose in ``base`` as x, y and the heading of its x axis on the floor."""
        base_root, base_pose = self._to_root(base)
        child_root, child_pose = self._to_root(child)
        if base_root != child_root:
            return None
        relative = np.linalg.solve(base_pose, child_pose)
        return (float(relative[0, 3]), float(relative[1, 3]),
                math.atan2(relative[1, 0], relative[0, 0]))


def read_rosbag(
    path: str | Path,
    *,
    scan_topic: str | None = None,
    odometry_topic: str | None = None,
    sensor: str = "laser",
) -> RosbagLog:
    """Open a ROS 1 ``.bag`` or a ROS 2 bag (directory, or its ``.mcap``/``.db3``) for streaming.

    ``scan_topic``/``odometry_topic``: the topics to replay (default ``/scan`` and ``/odom``, or
    the bag's only topic of each type). ``sensor``: the configured sensor the scans feed. Raises
    ``LogError`` for a missing path at once; other problems with the bag are raised as
    ``LogError`` when iteration starts.
    """
    path = Path(path)
    if not path.exists():
        raise LogError(path, "file not found")
    return RosbagLog(path, scan_topic, odometry_topic, sensor)


def _choose(path: Path, connections: Sequence[Any], msgtype: str, wanted: str | None,
            default: str, option: str, required: bool = True) -> str | None:
    """The topic of ``msgtype`` to replay; a LogError that lists the bag's topics when none
    (or more than one, unnamed) fits."""
    candidates = sorted({c.topic for c in connections if c.msgtype == msgtype})
    if wanted is not None:
        if wanted in candidates:
            return wanted
    elif default in candidates:
        return default
    elif len(candidates) == 1:
        return candidates[0]
    elif not candidates and not required:
        return None
    found = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "nothing"
    short = msgtype.replace("/msg/", "/")
    if wanted is not None:
        problem = f"no {short} topic {wanted}"
    elif candidates:
        problem = f"several {short} topics, none is {default}: choose one with {option}"
    else:
        problem = f"no {short} topic"
    raise LogError(path, f"{problem}; the bag has {found}")


def _first(reader: Any, topic: str, read: Any) -> str | None:
    """``read`` of the first decodable message on ``topic``."""
    wanted = [c for c in reader.connections if c.topic == topic]
    for connection, _, raw in reader.messages(wanted) if wanted else ():
        try:
            return str(read(reader.deserialize(raw, connection.msgtype)))
        except Exception:
            continue
    return None


def _stamp(msg: Any, bag_time_ns: int) -> float:
    stamp = msg.header.stamp
    t = stamp.sec + stamp.nanosec * 1e-9
    return t if t > 0 else bag_time_ns * 1e-9


def message_to_event(
    msg: Any,
    msgtype: str,
    sensor: str,
    bag_time_ns: int,
    angles_cache: dict[tuple[int, float, float], NDArray[np.float64]],
) -> Event:
    """A decoded ``LaserScan`` (fed to configured ``sensor``) or ``Odometry`` message as an
    event, stamped with its header (``bag_time_ns`` when that is unset). The same for a bag's
    messages and a live node's (the attributes are ROS's, whoever decoded them)."""
    if msgtype == ODOMETRY:
        return odometry_event(msg, bag_time_ns)
    return scan_event(msg, sensor, bag_time_ns, angles_cache)


def odometry_event(msg: Any, bag_time_ns: int = 0) -> Odometry:
    """``nav_msgs/Odometry`` → :class:`Odometry` (x, y and the yaw of the pose)."""
    t = _stamp(msg, bag_time_ns)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    theta = yaw_from_quaternion(q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in (p.x, p.y, theta)):
        raise ValueError("non-finite odometry pose")
    return Odometry(t, float(p.x), float(p.y), theta)


def scan_event(msg: Any, sensor: str, bag_time_ns: int = 0,
               angles_cache: dict[tuple[int, float, float], NDArray[np.float64]] | None = None
               ) -> Scan:
    """``sensor_msgs/LaserScan`` → :class:`Scan` (NaN and below ``range_min``: no return)."""
    t = _stamp(msg, bag_time_ns)
    angles_cache = {} if angles_cache is None else angles_cache
    ranges = np.asarray(msg.ranges, dtype=float).copy()
    invalid = np.isnan(ranges) | (ranges < msg.range_min)
    ranges[invalid] = np.inf
    key = (len(ranges), float(msg.angle_min), float(msg.angle_increment))
    angles = angles_cache.get(key)
    if angles is None:
        angles = msg.angle_min + msg.angle_increment * np.arange(len(ranges), dtype=float)
        angles.flags.writeable = False
        angles_cache[key] = angles
    return Scan(t, ranges, angles, max_range=float(msg.range_max), sensor=sensor)

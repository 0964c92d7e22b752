"""The ROS 2 node: the same :class:`~fusion.Localizer` as ``houghloc run``, fed from topics.

    /scan (sensor_msgs/LaserScan) ──▶ held until odometry reaches its stamp ──▶ Localizer.on_scan
    /odom (nav_msgs/Odometry) ──────▶ Localizer.on_odometry
    /initialpose (PoseWithCovarianceStamped, as RViz sends it) ──▶ a new Localizer at that pose
    /tf_static ──▶ the laser's mount on the robot (base_frame → the scans' frame_id)

    houghloc/pose (PoseWithCovarianceStamped, as amcl_pose), /tf map → odom (as AMCL),
    houghloc/state (std_msgs/String: the ambiguity manager's state, localized or not, and why)
    houghloc/localized (std_msgs/Float32: the probability that the pose is within 0.3 m and 5°
    of the truth, with every pose; fusion.integrity)

A scan waits for the odometry at its time (as AMCL waits for the odom → base transform) at most
``odom_wait`` seconds, so that the filter predicts to the scan before the scan corrects it; a
robot without odometry therefore costs that much latency. The ``map → odom`` transform is dated
``transform_tolerance`` ahead of the scan, as AMCL does, so that tf users can look it up until
the next scan.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry as OdometryMsg
from numpy.typing import NDArray
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Float32, String

from fusion.config import LocalizerConfig
from fusion.events import Scan
from fusion.integrity import is_localized
from fusion.io.rosbag import StaticTree, odometry_event, scan_event
from fusion.localizer import Estimate, Localizer
from fusion.ros2.messages import (
    map_to_odom,
    planar_covariance,
    planar_pose,
    ros_covariance,
    set_planar_pose,
    set_planar_transform,
    set_stamp,
)
from fusion.ros2.tf2_msgs import available as tf2_msgs_available
from fusion.visualize import Logger, NullLogger
from houghloc import SegmentMap
from houghloc.geometry import wrap_angle

MAX_INITIAL_SIGMA_XY = 1.0e3
"""m: an initial pose's σ beyond this (a click that means "somewhere") is taken as this."""
PENDING_SCANS = 10
"""Scans held for odometry at most; beyond, the oldest is dropped (the node is behind)."""
ODOMETRY_KEPT = 1000
"""Odometry readings kept to place map → odom at a scan's time: 10 s at 100 Hz."""
STOP_CHECK_SECONDS = 0.1
"""s: how long a signal to stop may wait for the spin to notice it."""

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""/tf_static and the state: a late subscriber still gets the last message."""


@dataclass
class _Pending:
    scan: Scan
    arrived: float  # monotonic s


class LocalizerNode(Node):
    """A thin adapter: ROS messages in, the Localizer's estimates out; no localization here."""

    def __init__(self, segment_map: SegmentMap, config: LocalizerConfig,
                 initial_pose: NDArray[np.float64] | None = None,
                 logger: Logger | None = None, name: str = "houghloc",
                 **node_options: Any) -> None:
        super().__init__(name, **node_options)
        self.map, self.config, self.rerun = segment_map, config, logger or NullLogger()
        if config.laser is None:
            raise ValueError("the node needs a laser sensor in the config")
        self.sensor = config.laser
        p = self._declare_settings()
        self.map_frame, self.odom_frame, self.base_frame = p["map_frame"], p["odom_frame"], \
            p["base_frame"]
        self.transform_tolerance, self.odom_wait = p["transform_tolerance"], p["odom_wait"]
        self.localizer: Localizer | None = None
        self._start_pose = None if initial_pose is None else np.asarray(initial_pose, float)
        self._start_cov: NDArray[np.float64] | None = None
        self._pending: deque[_Pending] = deque()
        self._odometry: deque[tuple[float, float, float, float]] = deque(maxlen=ODOMETRY_KEPT)
        self._angles: dict[tuple[int, float, float], NDArray[np.float64]] = {}
        self._static = StaticTree()
        self._frame = ""  # the scans' frame_id, where the laser is
        self._state_text = ""
        self.dropped_scans = 0
        self.scans = 0

        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "houghloc/pose", 10)
        self.state_pub = self.create_publisher(String, "houghloc/state", LATCHED)
        self.localized_pub = self.create_publisher(Float32, "houghloc/localized", 10)
        self.tf_pub = None
        if tf2_msgs_available():
            from tf2_msgs.msg import TFMessage

            self._tf_message = TFMessage
            # the mount is read whether or not this node publishes map -> odom
            self.create_subscription(TFMessage, "/tf_static", self._on_tf_static, LATCHED)
            if p["publish_tf"]:
                self.tf_pub = self.create_publisher(TFMessage, "/tf", 100)
        else:
            self.get_logger().warning(
                "tf2_msgs is not installed: map -> odom is not published on /tf and the laser "
                "mount comes from the config (python -m fusion.ros2.tf2_msgs builds it)")
        self.create_subscription(LaserScan, p["scan_topic"], self._on_scan,
                                 qos_profile_sensor_data)
        self.create_subscription(OdometryMsg, p["odom_topic"], self._on_odometry, 50)
        self.create_subscription(PoseWithCovarianceStamped, "initialpose", self._on_initial_pose,
                                 10)
        self.create_timer(0.05, self._release_waiting)
        self._publish_state("lost (waiting for the first scan)" if initial_pose is None
                            else "tracking (initial pose given)")

    def _declare_settings(self) -> dict[str, Any]:
        """ROS parameters with AMCL's names where AMCL has one."""
        defaults = {"map_frame": "map", "odom_frame": "odom", "base_frame": "base_footprint",
                    "scan_topic": "scan", "odom_topic": "odom", "publish_tf": True,
                    "transform_tolerance": 0.1, "odom_wait": 0.25}
        return {k: self.declare_parameter(k, v).value for k, v in defaults.items()}

    # ------------------------------------------------------------------------------ inputs
    def _on_odometry(self, msg: OdometryMsg) -> None:
        try:
            event = odometry_event(msg)
        except ValueError as err:
            self.get_logger().warning(f"odometry dropped: {err}")
            return
        self._odometry.append((event.t, event.x, event.y, event.theta))
        if self.localizer is not None:
            self.localizer.on_odometry(event.t, event.x, event.y, event.theta)
        self._release(event.t)

    def _on_scan(self, msg: LaserScan) -> None:
        scan = scan_event(msg, self.sensor, 0, self._angles)
        self._frame = msg.header.frame_id
        if len(self._pending) == PENDING_SCANS:
            self._pending.popleft()
            self.dropped_scans += 1
        self._pending.append(_Pending(scan, time.monotonic()))
        self._release(self._odometry[-1][0] if self._odometry else -math.inf)

    def _on_tf_static(self, msg: Any) -> None:
        for tf in msg.transforms:
            if not self._static.add(tf):
                self.get_logger().warning(f"/tf_static {tf.header.frame_id} -> "
                                          f"{tf.child_frame_id} is no rigid motion: ignored")

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Start again from the pose RViz's "2D Pose Estimate" gives, with its covariance."""
        pose = np.array(planar_pose(msg.pose.pose))
        cov = planar_covariance(msg.pose.covariance)
        if not (np.isfinite(pose).all() and np.isfinite(cov).all()):
            self.get_logger().warning("initial pose dropped: not finite")
            return
        self._start_pose, self._start_cov = pose, cov
        self.localizer = None  # the next scan starts a new one there
        self._publish_state("tracking (initial pose received)")
        self.get_logger().info(f"initial pose x {pose[0]:.2f} y {pose[1]:.2f} "
                               f"θ {pose[2]:.3f}")

    # --------------------------------------------------------------------------- localizing
    def _release_waiting(self) -> None:
        """Scans that waited ``odom_wait`` for odometry go on without it."""
        now = time.monotonic()
        while self._pending and now - self._pending[0].arrived >= self.odom_wait:
            self._localize(self._pending.popleft().scan)

    def _release(self, odometry_time: float) -> None:
        """Scans the odometry has reached go through the localizer, oldest first."""
        while self._pending and self._pending[0].scan.t <= odometry_time:
            self._localize(self._pending.popleft().scan)

    def _localize(self, scan: Scan) -> None:
        if self.localizer is None:
            self.localizer = self._start(scan.t)
        try:
            estimate = self.localizer.on_scan(scan.t, scan.ranges, scan.angles, self.sensor,
                                              scan.max_range)
        except ValueError as err:  # e.g. a scan no sensor could take
            self.get_logger().warning(f"scan at {scan.t:.3f} dropped: {err}")
            return
        self.scans += 1
        self._publish(estimate)

    def _start(self, t: float) -> Localizer:
        """A Localizer for the robot as it is now: the laser's mount from /tf_static when it
        is there, the pose given (or global localization), the odometry up to ``t``."""
        config = self.config
        mount = self._static.planar(self.base_frame, self._frame.lstrip("/"))
        if mount is not None:
            config = config.with_mount(self.sensor, mount)
            self.get_logger().info("laser mount from /tf_static: x {:.3f} y {:.3f} θ {:.4f}"
                                   .format(*mount))
        if self._start_cov is not None:
            sigma_xy = math.sqrt(max(self._start_cov[0, 0], self._start_cov[1, 1], 1e-8))
            sigma_theta = math.degrees(math.sqrt(max(self._start_cov[2, 2], 1e-10)))
            raw = config.as_dict()
            raw["filter"].update(initial_sigma_xy=min(sigma_xy, MAX_INITIAL_SIGMA_XY),
                                 initial_sigma_theta_deg=min(sigma_theta, 180.0))
            config = LocalizerConfig.from_dict(raw, "initialpose")
        try:
            localizer = Localizer(self.map, config, self._start_pose, self.rerun)
        except ValueError as err:  # a pose outside the map: not where the robot can be
            self.get_logger().warning(f"initial pose refused ({err}): global localization")
            self._start_pose = self._start_cov = None
            localizer = Localizer(self.map, config.model_copy(update={"initial_pose": None}),
                                  None, self.rerun)
        before = [o for o in self._odometry if o[0] <= t]
        if before:  # the reading the pose is given at: the increments start there
            localizer.on_odometry(*before[-1])
        return localizer

    # ------------------------------------------------------------------------------ outputs
    def _publish(self, estimate: Estimate) -> None:
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = self.map_frame
        set_stamp(msg.header.stamp, estimate.t)
        set_planar_pose(msg.pose.pose, estimate.pose)
        msg.pose.covariance = ros_covariance(estimate.cov)
        self.pose_pub.publish(msg)
        odom = self._odometry_at(estimate.t)
        if self.tf_pub is not None and odom is not None:
            tf = TransformStamped()
            tf.header.frame_id, tf.child_frame_id = self.map_frame, self.odom_frame
            set_stamp(tf.header.stamp, estimate.t + self.transform_tolerance)
            set_planar_transform(tf.transform, map_to_odom(estimate.pose, odom))
            self.tf_pub.publish(self._tf_message(transforms=[tf]))
        assert self.localizer is not None
        manager = self.localizer.manager
        reason = manager.transitions[-1].reason if manager.transitions else ""
        # the integrity output (fusion.integrity): what a navigation stack should trust
        probability = estimate.localized_probability
        self.localized_pub.publish(Float32(data=float(probability)))
        localized = "localized" if is_localized(probability) else "not localized"
        self._publish_state(f"{manager.state.value}, {localized} ({reason})" if reason
                            else f"{manager.state.value}, {localized}")

    def _publish_state(self, text: str) -> None:
        if text != self._state_text:
            self._state_text = text
            self.state_pub.publish(String(data=text))

    def _odometry_at(self, t: float) -> NDArray[np.float64] | None:
        """The odometry pose at ``t``, interpolated between the readings around it (the last
        one when ``t`` is past it)."""
        if not self._odometry:
            return None
        # the first reading at or after t (the readings are in time order); scans come
        # shortly before the newest reading, so the search starts from the end
        readings = self._odometry
        k = len(readings)
        while k > 0 and readings[k - 1][0] >= t:
            k -= 1
        if k == 0 or k == len(readings):
            return np.array(readings[min(k, len(readings) - 1)][1:])
        a, b = np.array(readings[k - 1]), np.array(readings[k])
        w = (t - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 1.0
        pose = a[1:] + w * (b[1:] - a[1:])
        pose[2] = a[3] + w * float(wrap_angle(b[3] - a[3]))
        return pose


def run_node(segment_map: SegmentMap, config: LocalizerConfig,
             initial_pose: NDArray[np.float64] | None, logger: Logger,
             ros_args: list[str]) -> int:
    """``houghloc ros2``: spin the node until Ctrl-C, SIGTERM (as ``ros2 launch`` and systemd
    stop a node) or a shutdown; 0 when it ends cleanly."""
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    # A signal only asks the loop below to stop. Raised as an exception (Ctrl-C's
    # KeyboardInterrupt) it could land inside rclpy's own code, an executor half built, and
    # leave a traceback; rclpy's own handlers would shut the context down under the node
    # still being built. So rclpy installs none, and the context ends in the `finally`. A
    # signal the parent set to be ignored stays ignored (a shell without job control starts
    # its background jobs with SIGINT ignored, so that Ctrl-C at the prompt spares them).
    stop = threading.Event()
    previous = {signum: signal.signal(signum, lambda *_: stop.set())
                for signum in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(signum) is not signal.SIG_IGN}
    node: LocalizerNode | None = None
    executor: SingleThreadedExecutor | None = None
    try:
        rclpy.init(args=["houghloc", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
        node = LocalizerNode(segment_map, config, initial_pose, logger)
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        while not stop.is_set():
            executor.spin_once(timeout_sec=STOP_CHECK_SECONDS)
    except ExternalShutdownException:
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        # printed, not logged: the ROS context (and /rosout) is shut down by now
        scans, dropped = (node.scans, node.dropped_scans) if node is not None else (0, 0)
        print(f"houghloc: {scans} scans localized, {dropped} dropped", file=sys.stderr)
    return 0

"""The ROS 2 node: the same :class:`~fusion.Localizer` as ``houghloc run``, fed from topics, as a
managed (lifecycle) node that nav2's lifecycle manager starts in place of AMCL.

    scan (LaserScan; several: houghloc.scan_topics) ─▶ Localizer.on_scan ─▶ TimeOrder: its
                                                       pose held until the odometry covers it
    odom (nav_msgs/Odometry) ─────────▶ Localizer.on_odometry
    initialpose (PoseWithCovarianceStamped, RViz's 2D Pose Estimate) ─▶ a new Localizer there
    map (OccupancyGrid, transient local, as map_server) ─▶ the segment map, unless --map
    /tf_static ─▶ each laser's mount on the robot (base_frame_id → the scan's frame_id)

    amcl_pose (PoseWithCovarianceStamped; houghloc.pose_topic), /tf map → odom (as AMCL),
    particle_cloud (PoseArray: the hypotheses followed, or the one pose),
    houghloc/localized (Float32: the probability that the pose is within 0.3 m and 5° of the
    truth, fusion.integrity), houghloc/state (String), /diagnostics (DiagnosticArray, 1 Hz)

    services: reinitialize_global_localization, request_nomotion_update (std_srvs/Empty),
    set_initial_pose (nav2_msgs/SetInitialPose, where nav2_msgs is installed or built)

Lifecycle, as nav2's AMCL: *configure* reads the parameters (:mod:`fusion.ros2.settings`), loads
the map and config and creates the publishers, subscriptions and services; *activate* chooses
where to start (``set_initial_pose``, else a recent saved pose, else global localization) and
lets scans through; *deactivate* stops taking scans; *cleanup* drops all of it. ``houghloc ros2``
configures and activates the node itself unless ``--managed``.

A scan is localized when it arrives; its pose is published once the odometry covers its stamp,
so that the pose at its time holds the odometry on both sides, or when the next scan arrives,
or after ``houghloc.odom_wait`` seconds: the rules of ``houghloc run``, in the same
:class:`~fusion.time_order.TimeOrder`.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid as OccupancyGridMsg
from nav_msgs.msg import Odometry as OdometryMsg
from numpy.typing import NDArray
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from std_srvs.srv import Empty

from fusion.config import LocalizerConfig
from fusion.estimate import Estimate
from fusion.events import Scan
from fusion.io.rosbag import StaticTree, odometry_event, scan_event
from fusion.localizer import Localizer
from fusion.resources import find_config, find_map
from fusion.ros2.messages import planar_covariance, planar_pose
from fusion.ros2.odometry import OdometryBuffer
from fusion.ros2.outputs import LATCHED, Outputs
from fusion.ros2.saved_pose import save_pose
from fusion.ros2.settings import NodeSettings, declare, read
from fusion.ros2.start import GLOBAL, Start, choose_start
from fusion.ros2.tf2_msgs import available as tf2_msgs_available
from fusion.time_order import Held, TimeOrder, settled
from fusion.visualize import Logger, NullLogger
from houghloc import SegmentMap

MAX_INITIAL_SIGMA_XY = 1.0e3
"""m: an initial pose's σ beyond this (a click that means "somewhere") is taken as this."""
ODOMETRY_KEPT = 1000
"""Odometry readings kept to place map → odom at a scan's time: 10 s at 100 Hz."""


class LocalizerNode(LifecycleNode):
    """A thin adapter: ROS messages in, the Localizer's estimates out; no localization here.

    ``segment_map``/``config``/``initial_pose`` given here (``houghloc ros2 --map …``) take the
    place of ``houghloc.map``, ``houghloc.config`` and the saved pose."""

    def __init__(self, segment_map: SegmentMap | None = None,
                 config: LocalizerConfig | None = None,
                 initial_pose: NDArray[np.float64] | None = None,
                 logger: Logger | None = None, name: str = "houghloc", autostart: bool = True,
                 **node_options: Any) -> None:
        super().__init__(name, **node_options)
        declare(self)
        self._given_map, self._given_config = segment_map, config
        self._given_pose = None if initial_pose is None else np.asarray(initial_pose, float)
        self.rerun = logger or NullLogger()
        self.settings = NodeSettings()
        self.map: SegmentMap | None = None
        self.map_source = ""
        self.config = config or LocalizerConfig()
        self.localizer: Localizer | None = None
        self.outputs: Outputs | None = None
        self._active = False
        self._entities: list[Any] = []  # what configure made and cleanup destroys
        self._order = TimeOrder()
        self._reset_inputs()
        self.scans = 0
        self.dropped_scans = 0
        """scans that could not be localized: no map yet, or no sensor could take them"""
        if autostart:
            self.trigger_configure()
            self.trigger_activate()

    @property
    def transform_tolerance(self) -> float:
        return self.settings.transform_tolerance

    def _reset_inputs(self) -> None:
        self._begin: Start = GLOBAL  # where the next Localizer starts, and why
        self._order.clear()
        self._odometry = OdometryBuffer(ODOMETRY_KEPT)
        self._angles: dict[tuple[int, float, float], NDArray[np.float64]] = {}
        self._static = StaticTree()
        self._frames: dict[str, str] = {}  # sensor name → the frame its scans come in
        self._warned: set[str] = set()
        self._last: Estimate | None = None  # of the running Localizer

    # ------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        s = self.settings = read(self)
        self._order = TimeOrder(s.houghloc__odom_wait)
        try:
            self.config = self._given_config or LocalizerConfig.from_yaml(
                find_config(s.houghloc__config) if s.houghloc__config else None)
            if self.config.laser is None:
                raise ValueError("the node needs a laser sensor in the config")
            if self._given_map is not None:
                self.map, self.map_source = self._given_map, "--map"
            elif s.houghloc__map:
                self.map = SegmentMap.from_yaml(find_map(s.houghloc__map))
                self.map_source = s.houghloc__map
        except (OSError, ValueError) as err:
            self.get_logger().error(f"configure failed: {err}")
            return TransitionCallbackReturn.FAILURE
        self.outputs = Outputs(self, s, tf2_msgs_available())
        self._entities = self._subscribe(s)
        return TransitionCallbackReturn.SUCCESS

    def _subscribe(self, s: NodeSettings) -> list[Any]:
        made: list[Any] = []
        if tf2_msgs_available():
            from tf2_msgs.msg import TFMessage

            made.append(self.create_subscription(TFMessage, "/tf_static", self._on_tf_static,
                                                 LATCHED))
        else:
            self.get_logger().warning(
                "tf2_msgs is not installed: map -> odom is not published on /tf and the laser "
                "mount comes from the config (python -m fusion.ros2.tf2_msgs builds it)")
        laser = self.config.laser
        assert laser is not None
        for i, topic in enumerate(s.houghloc__scan_topics or (s.scan_topic,)):
            sensor = laser if i == 0 else f"{laser}_{i}"
            made.append(self.create_subscription(
                LaserScan, topic, lambda msg, name=sensor: self._on_scan(msg, name),
                qos_profile_sensor_data))
        made.append(self.create_subscription(OdometryMsg, s.houghloc__odom_topic,
                                             self._on_odometry, 50))
        made.append(self.create_subscription(PoseWithCovarianceStamped, "initialpose",
                                             self._on_initial_pose, 10))
        if self.map is None:
            made.append(self.create_subscription(OccupancyGridMsg, s.map_topic, self._on_map,
                                                 LATCHED))
        made.append(self.create_service(Empty, "reinitialize_global_localization",
                                        self._on_reinitialize))
        made.append(self.create_service(Empty, "request_nomotion_update", self._on_nomotion))
        if tf2_msgs_available("nav2_msgs.srv"):
            from nav2_msgs.srv import SetInitialPose

            made.append(self.create_service(SetInitialPose, "set_initial_pose",
                                            self._on_set_initial_pose))
        made.append(self.create_timer(0.05, self._release_waiting))
        if s.saved_pose_filepath:
            made.append(self.create_timer(s.houghloc__save_pose_period, self._save_pose))
        return made

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.localizer is None or self.settings.always_reset_initial_pose:
            self._choose_start()
        self._active = True
        assert self.outputs is not None
        if self.localizer is not None:
            self.outputs.state("tracking (resumed)")
        else:
            lost = self._begin.pose is None
            self.outputs.state(f"{'lost' if lost else 'tracking'} ({self._begin.reason})")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        if self.outputs is not None:
            self.outputs.state("inactive")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy()
        return TransitionCallbackReturn.SUCCESS

    def _destroy(self) -> None:
        self._active = False
        destroyers: dict[str, Any] = {"Subscription": self.destroy_subscription,
                                      "Service": self.destroy_service,
                                      "Timer": self.destroy_timer}
        for entity in self._entities:
            destroyers[type(entity).__name__](entity)
        self._entities = []
        if self.outputs is not None:
            self.outputs.destroy()
            self.outputs = None
        self.localizer, self.map = None, None
        self._reset_inputs()

    def _choose_start(self) -> None:
        """Where the next Localizer starts (:func:`fusion.ros2.start.choose_start`)."""
        self.localizer, self._last = None, None
        self._begin = choose_start(self.settings, self._given_pose, self.config.filter.initial_cov,
                                   self.get_logger().info)

    # ------------------------------------------------------------------------------ inputs
    def _on_odometry(self, msg: OdometryMsg) -> None:
        try:
            event = odometry_event(msg)
        except ValueError as err:
            self.get_logger().warning(f"odometry dropped: {err}")
            return
        self._odometry.append(event.t, event.x, event.y, event.theta)
        if self.localizer is not None and self._active:
            self.localizer.on_odometry(event.t, event.x, event.y, event.theta)
        if self.localizer is not None:
            self._report(self._order.odometry(self.localizer.tracker.odometry_time))

    def _on_scan(self, msg: LaserScan, sensor: str | None = None) -> None:
        """A scan of ``sensor`` (the config's laser, or the i-th of ``houghloc.scan_topics``)."""
        if not self._active:
            return
        sensor = sensor or self.config.laser or "laser"
        scan = scan_event(msg, sensor, 0, self._angles)
        self._frames.setdefault(sensor, msg.header.frame_id.lstrip("/"))
        self._report(self._order.scan_arriving())
        self._localize(scan)

    def _on_tf_static(self, msg: Any) -> None:
        for tf in msg.transforms:
            if not self._static.add(tf):
                self.get_logger().warning(f"/tf_static {tf.header.frame_id} -> "
                                          f"{tf.child_frame_id} is no rigid motion: ignored")

    def _on_set_initial_pose(self, request: Any, response: Any) -> Any:
        """nav2's ``set_initial_pose`` service: as a message on ``initialpose``."""
        self._on_initial_pose(request.pose)
        return response

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Start again from the pose RViz's "2D Pose Estimate" gives, with its covariance."""
        pose = np.array(planar_pose(msg.pose.pose))
        cov = planar_covariance(msg.pose.covariance)
        if not (np.isfinite(pose).all() and np.isfinite(cov).all()):
            self.get_logger().warning("initial pose dropped: not finite")
            return
        self._restart(pose, cov, "initial pose received")
        self.get_logger().info(f"initial pose x {pose[0]:.2f} y {pose[1]:.2f} "
                               f"θ {pose[2]:.3f}")

    def _on_map(self, msg: OccupancyGridMsg) -> None:
        """A map from ``map_server``: its walls become the segment map (as ``map build
        --grid``); the robot goes on from its estimate in the new map."""
        from fusion.mapping.segments import extract_segments
        from fusion.ros2.messages import grid_from_message

        if self.settings.first_map_only and self.map is not None:
            return
        started = time.perf_counter()
        try:
            grid = grid_from_message(msg, self.settings.houghloc__max_map_cells)
            segment_map = extract_segments(grid, name=self.settings.map_topic)  # map build's
        except ValueError as err:
            self.get_logger().error(f"map on {self.settings.map_topic} not used: {err}")
            return
        self.map, self.map_source = segment_map, f"topic {self.settings.map_topic}"
        self.get_logger().info(
            f"map from {self.settings.map_topic}: {msg.info.width} × {msg.info.height} cells, "
            f"{len(segment_map)} walls, built in {time.perf_counter() - started:.2f} s")
        if self.localizer is not None:
            self._go_on("new map")

    def _on_reinitialize(self, request: Any, response: Any) -> Any:
        """nav2's ``reinitialize_global_localization``: forget the pose, search the whole map."""
        self._restart(None, None, "global localization requested")
        return response

    def _on_nomotion(self, request: Any, response: Any) -> Any:
        """nav2's ``request_nomotion_update`` makes AMCL use the next scan though the robot did
        not move; houghloc uses every scan already, so there is nothing to force."""
        return response

    def _go_on(self, reason: str) -> None:
        """Start again from the estimate: every pose held is published first."""
        self._report(self._order.drain())
        self._restart(*self._current(), reason)

    def _restart(self, pose: NDArray[np.float64] | None, cov: NDArray[np.float64] | None,
                 reason: str) -> None:
        self._report(self._order.drain())  # the poses of the localizer that ends
        self._begin = Start(pose, cov, reason)
        self.localizer, self._last = None, None  # the next scan starts a new one
        if self.outputs is not None:
            self.outputs.state(f"lost ({reason})" if pose is None else f"tracking ({reason})")

    # --------------------------------------------------------------------------- localizing
    def _release_waiting(self) -> None:
        """Poses that waited ``odom_wait`` of wall time for the odometry are published without."""
        self._report(self._order.overdue(time.monotonic()))

    def _localize(self, scan: Scan) -> None:
        if self.map is None:
            self.dropped_scans += 1
            self._warn_once("no-map", f"no map yet: scans are dropped until one comes on "
                            f"{self.settings.map_topic} (or give --map)")
            return
        if self.localizer is not None and scan.sensor not in self.localizer.config.sensors:
            # a laser heard for the first time: go on from the estimate with its mount known
            self._go_on(f"laser {scan.sensor} added")
        if self.localizer is None:
            self.localizer = self._start(scan.t)
        try:
            estimate = self.localizer.on_scan(scan.t, scan.ranges, scan.angles, scan.sensor,
                                              scan.max_range)
        except (ValueError, KeyError) as err:  # e.g. a scan no sensor could take
            self.dropped_scans += 1
            self.get_logger().warning(f"scan at {scan.t:.3f} dropped: {err}")
            return
        self.scans += 1
        self._report(self._order.localized(estimate, estimate.t,
                                           self.localizer.tracker.odometry_time,
                                           time.monotonic()))

    def _report(self, due: list[Held]) -> None:
        """Publish the poses whose time has come (:class:`fusion.time_order.TimeOrder`), oldest
        first, each at its scan's time as the filter holds it now."""
        if not due:
            return
        assert self.localizer is not None and self.outputs is not None  # they came from it
        for held in due:
            estimate = settled(held, self.localizer.tracker)
            self._last = estimate
            # map → odom only with the wheels' reading at the scan's stamp: composed with the
            # last reading before it, the transform would be off by the motion since
            covered = self._odometry.newest_time >= estimate.t
            self.outputs.estimate(estimate, self.localizer.manager,
                                  self._odometry.at(estimate.t) if covered else None)

    def _start(self, t: float) -> Localizer:
        """A Localizer for the robot as it is now: each laser's mount from /tf_static when it
        is there, the pose given (or global localization), the odometry up to ``t``."""
        config = self._with_lasers(self.config)
        cov = self._begin.cov
        if cov is not None:
            sigma_xy = math.sqrt(max(cov[0, 0], cov[1, 1], 1e-8))
            sigma_theta = math.degrees(math.sqrt(max(cov[2, 2], 1e-10)))
            raw = config.as_dict()
            raw["filter"].update(initial_sigma_xy=min(sigma_xy, MAX_INITIAL_SIGMA_XY),
                                 initial_sigma_theta_deg=min(sigma_theta, 180.0))
            config = LocalizerConfig.from_dict(raw, "initialpose")
        assert self.map is not None
        try:
            localizer = Localizer(self.map, config, self._begin.pose, self.rerun)
        except ValueError as err:  # a pose outside the map: not where the robot can be
            self.get_logger().warning(f"initial pose refused ({err}): global localization")
            self._begin = GLOBAL
            localizer = Localizer(self.map, config.model_copy(update={"initial_pose": None}),
                                  None, self.rerun)
        before = self._odometry.last_before(t)
        if before is not None:  # the reading the pose is given at: the increments start there
            localizer.on_odometry(*before)
        return localizer

    def _with_lasers(self, config: LocalizerConfig) -> LocalizerConfig:
        """The config with one sensor per laser heard so far, each at its /tf_static mount."""
        laser = config.laser
        assert laser is not None
        raw = config.as_dict()
        for sensor, frame in self._frames.items():
            mount = self._static.planar(self.settings.base_frame_id, frame)
            entry = raw["sensors"].setdefault(sensor, dict(raw["sensors"][laser]))
            if mount is not None:
                entry["mount"] = list(mount)
                self.get_logger().info("{} mount from /tf_static ({}): x {:.3f} y {:.3f} "
                                       "θ {:.4f}".format(sensor, frame, *mount))
            elif sensor != laser:
                self._warn_once(f"mount-{sensor}", f"{sensor} ({frame}) has no mount on "
                                "/tf_static: the config's laser mount is used")
        return LocalizerConfig.from_dict(raw, "lasers")

    def _current(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The last pose published and its covariance (the filter's, before any scan)."""
        if self._last is not None:
            return self._last.pose, self._last.cov
        assert self.localizer is not None
        return self.localizer.tracker.pose, self.localizer.tracker.cov

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def _save_pose(self) -> None:
        if self.localizer is None or not self._active:
            return
        try:
            save_pose(self.settings.saved_pose_filepath, *self._current(),
                      self.settings.global_frame_id)
        except OSError as err:
            self._warn_once("save", f"pose not saved: {err}")

"""The node as nav2's AMCL drop-in, over the real middleware (ROS 2 Kilted's PyPI wheels): started
through the lifecycle services as nav2's lifecycle manager starts it, parameters by AMCL's names,
the map from the map topic, AMCL's services, the hypotheses, the diagnostics, two lasers, and a
restart after ``kill -9`` from the saved pose.

Skipped, saying why, when the ``ros2`` extra is not installed (``make ros2``, which ``make test``
runs).
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from array import array
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

try:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Empty
except ImportError as exc:
    pytest.skip(f"the ros2 extra is not installed ({exc}): `make ros2` installs it, and "
                "failed or was not run", allow_module_level=True)
from fusion.ros2.tf2_msgs import available as tf2_msgs_available

if not tf2_msgs_available():
    pytest.skip("tf2_msgs is not installed: `python -m fusion.ros2.tf2_msgs` builds it",
                allow_module_level=True)

from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, TransformStamped
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from benchmarks.bench_ros2 import EPOCH, MOUNT, _odometry, _transform, office_run
from fusion.bench.data import MapSource
from fusion.config import LocalizerConfig
from fusion.ros2.messages import (
    grid_from_message,
    planar_pose,
    ros_covariance,
    set_grid,
    set_planar_pose,
    set_stamp,
    stamp_seconds,
)
from fusion.ros2.node import LocalizerNode
from fusion.ros2.outputs import LATCHED
from fusion.ros2.saved_pose import load_pose

REAR_MOUNT = (-0.25, 0.05, math.pi)
"""A second laser looking backwards, for the two-laser test."""
TIMEOUT = 10.0
"""s for any one answer of the node (a hang guard, not a speed limit)."""
POSITION_M = 0.05
"""m: the office's poses through the node are within 1 cm (test_ros2_node); 5 cm catches a
wrong map, mount or start without flaking."""


@pytest.fixture(scope="module")
def office():
    run, ranges = office_run(seconds=20.0, seed=5)
    assert run.laser is not None
    rear = run.laser.mounted(REAR_MOUNT).all()[0]
    return run, ranges, rear


def _own_domain() -> int:
    """A DDS domain for this test process alone: the node's topics have AMCL's names, which
    other test processes' nodes publish too."""
    return 110 + os.getpid() % 100


class Client:
    """A ROS 2 context with the node (or not) and a client node spinning in a thread."""

    def __init__(self, node_factory: Callable[[Any], Any] | None, domain: int | None = None):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=_own_domain() if domain is None else domain)
        self.node = node_factory(self.context) if node_factory else None
        self.client = rclpy.create_node("nav2_like_client", context=self.context)
        self.got = threading.Condition()
        self.poses: list[tuple[float, np.ndarray]] = []
        self.states: list[str] = []
        self.clouds: list[int] = []
        self.diagnostics: list[tuple[int, str]] = []
        self.odom_sent = -math.inf  # the stamp of the last odometry sent
        c = self.client
        c.create_subscription(PoseWithCovarianceStamped, "amcl_pose", self._on_pose, 100)
        c.create_subscription(String, "houghloc/state", self._on_state, LATCHED)
        c.create_subscription(PoseArray, "particle_cloud",
                              lambda m: self._add(self.clouds, len(m.poses)), 10)
        c.create_subscription(DiagnosticArray, "/diagnostics", lambda m: self._add(
            self.diagnostics, (m.status[0].level[0] if isinstance(m.status[0].level, bytes)
                               else m.status[0].level, m.status[0].message)), 10)
        # how many subscriptions each input topic has ever matched: a node killed with -9 stays
        # matched until its DDS lease runs out (20 s), so a restarted node's subscriptions are
        # known by this count growing, not by the count of those matched now
        self.matched: dict[str, int] = {"scan": 0, "scan_rear": 0, "odom": 0}
        self.scan_pub = c.create_publisher(LaserScan, "scan", 10,
                                           event_callbacks=self._on_matched("scan"))
        self.rear_pub = c.create_publisher(LaserScan, "scan_rear", 10,
                                           event_callbacks=self._on_matched("scan_rear"))
        self.odom_pub = c.create_publisher(Odometry, "odom", 100,
                                           event_callbacks=self._on_matched("odom"))
        self.static_pub = c.create_publisher(TFMessage, "/tf_static", LATCHED)
        self.map_pub = c.create_publisher(OccupancyGrid, "map", LATCHED)
        self.executor = SingleThreadedExecutor(context=self.context)
        if self.node is not None:
            self.executor.add_node(self.node)
        self.executor.add_node(c)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_matched(self, topic: str) -> PublisherEventCallbacks:
        def matched(info: Any) -> None:
            with self.got:
                self.matched[topic] = info.total_count
                self.got.notify_all()
        return PublisherEventCallbacks(matched=matched)

    def _add(self, where: list, value: Any) -> None:
        with self.got:
            where.append(value)
            self.got.notify_all()

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self._add(self.poses, (stamp_seconds(msg.header.stamp) - EPOCH,
                               np.array(planar_pose(msg.pose.pose))))

    def _on_state(self, msg: String) -> None:
        self._add(self.states, msg.data)

    def wait(self, condition: Callable[[], bool], what: str, seconds: float = TIMEOUT) -> None:
        with self.got:
            if not self.got.wait_for(condition, seconds):
                raise TimeoutError(f"no answer in {seconds} s: {what}")

    def call(self, service_type: Any, name: str, request: Any) -> Any:
        client = self.client.create_client(service_type, name)
        assert client.wait_for_service(timeout_sec=TIMEOUT), f"no service {name}"
        future = client.call_async(request)
        deadline = time.monotonic() + TIMEOUT
        while not future.done():
            assert time.monotonic() < deadline, f"{name} did not answer"
            time.sleep(0.01)
        self.client.destroy_client(client)
        return future.result()

    def transition(self, node: str, transition: int) -> int:
        """As nav2's lifecycle manager: change_state, then get_state to confirm."""
        answer = self.call(ChangeState, f"{node}/change_state",
                           ChangeState.Request(transition=Transition(id=transition)))
        assert answer.success, f"transition {transition} refused"
        return int(self.call(GetState, f"{node}/get_state", GetState.Request()).current_state.id)

    def send_mounts(self, t: float) -> None:
        self.static_pub.publish(TFMessage(transforms=[
            _transform(TransformStamped(), "base_footprint", "laser", t, MOUNT),
            _transform(TransformStamped(), "base_footprint", "laser_rear", t, REAR_MOUNT)]))

    def stream(self, run: Any, ranges: np.ndarray, scans: range, rear: np.ndarray | None = None,
               expect: bool = True) -> None:
        """The run's scans in ``scans``, each followed by the odometry up to just past it (the
        node holds a scan until the odometry reaches it); with ``expect``, each scan waits for
        its pose (both lasers' with ``rear``)."""
        cfg = run.config.laser
        if expect:  # a message sent before the node's subscription is matched is lost
            publishers = [self.scan_pub, self.odom_pub] + ([self.rear_pub] if rear is not None
                                                           else [])
            self.wait_matched(publishers)
        for k in scans:
            t = float(run.scan_t[k])
            before = len(self.poses)
            self.scan_pub.publish(self._scan(run, ranges[k], t, "laser", cfg))
            if rear is not None:
                self.rear_pub.publish(self._scan(run, rear[k], t, "laser_rear", cfg))
            for ot, pose in zip(run.odom_t, run.odom_pose, strict=True):
                if self.odom_sent < ot <= t + 0.05:
                    self.odom_pub.publish(_odometry(Odometry(), EPOCH + ot, pose))
                    self.odom_sent = ot
            if expect:
                n = 1 if rear is None else 2
                self.wait(lambda b=before + n: len(self.poses) >= b, f"the poses of scan {k}")

    @staticmethod
    def wait_matched(publishers: list[Any], seconds: float = TIMEOUT) -> None:
        """Until every publisher has a subscriber: DDS discovery is asynchronous."""
        deadline = time.monotonic() + seconds
        while any(p.get_subscription_count() == 0 for p in publishers):
            if time.monotonic() > deadline:
                raise TimeoutError(f"no subscriber in {seconds} s on "
                                   f"{[p.topic_name for p in publishers]}")
            time.sleep(0.02)

    @staticmethod
    def _scan(run: Any, r: np.ndarray, t: float, frame: str, cfg: Any) -> LaserScan:
        scan = LaserScan()
        scan.header.frame_id = frame
        set_stamp(scan.header.stamp, EPOCH + t)
        scan.angle_min = float(run.angles[0])
        scan.angle_increment = float(run.angles[1] - run.angles[0])
        scan.angle_max = scan.angle_min + scan.angle_increment * (len(r) - 1)
        scan.range_min, scan.range_max = float(cfg.min_range), float(cfg.max_range)
        scan.ranges = array("f", r.astype(np.float32).tobytes())
        return scan

    def errors(self, run: Any) -> np.ndarray:
        index = {round(t, 6): k for k, t in enumerate(run.scan_t)}
        return np.array([np.hypot(*(p[:2] - run.scan_truth[index[round(t, 6)]][:2]))
                         for t, p in self.poses])

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=TIMEOUT)
        if self.node is not None:
            self.node.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.context)
        self.thread.join(TIMEOUT)


def _amcl_parameters(start: np.ndarray, **more: Any) -> list[Parameter]:
    """A nav2 bringup's ``amcl:`` block, AMCL's particle-filter settings included."""
    values = {"base_frame_id": "base_footprint", "odom_frame_id": "odom",
              "global_frame_id": "map", "scan_topic": "scan", "set_initial_pose": True,
              "initial_pose.x": float(start[0]), "initial_pose.y": float(start[1]),
              "initial_pose.yaw": float(start[2]), "transform_tolerance": 1.0,
              "alpha1": 0.2, "max_particles": 2000, "laser_model_type": "likelihood_field",
              **more}
    return [Parameter(k, value=v) for k, v in values.items()]


def _office_grid(run: Any, shift: float = 0.0) -> OccupancyGrid:
    """The office's walls drawn into a grid (the benchmark's AMCL map) as map_server publishes
    it, moved by ``shift`` in x."""
    grid = MapSource(segment_map_path=run.map_path).grid
    msg = set_grid(OccupancyGrid(), grid)
    msg.header.frame_id = "map"
    msg.info.origin.position.x += shift
    return msg


def test_a_grid_goes_through_its_message_and_back(office):
    run, _, _ = office
    grid = MapSource(segment_map_path=run.map_path).grid
    back = grid_from_message(_office_grid(run), max_cells=10**8)
    assert back.origin == pytest.approx(grid.origin) and back.resolution == grid.resolution
    assert (back.occupied == grid.occupied).all() and (back.free == grid.free).all()
    with pytest.raises(ValueError, match="more than the 1000"):
        grid_from_message(_office_grid(run), max_cells=1000)
    rotated = _office_grid(run)
    rotated.info.origin.orientation.z, rotated.info.origin.orientation.w = 0.38, 0.92
    with pytest.raises(ValueError, match="rotated"):
        grid_from_message(rotated, max_cells=10**8)


def test_started_by_the_lifecycle_protocol_with_amcls_parameters(office):
    """Unconfigured until configured, silent while inactive, localizing while active, and back:
    the services nav2's lifecycle manager calls, in its order."""
    run, ranges, _ = office
    config = LocalizerConfig.from_yaml("office-laser")
    h = Client(lambda ctx: LocalizerNode(
        run.map, config, name="amcl", autostart=False, context=ctx,
        parameter_overrides=_amcl_parameters(run.scan_truth[0])))
    try:
        assert h.transition("amcl", Transition.TRANSITION_CONFIGURE) == State.PRIMARY_STATE_INACTIVE
        h.send_mounts(EPOCH)
        h.wait(lambda: h.node._static.planar("base_footprint", "laser") is not None, "/tf_static")
        h.stream(run, ranges, range(0, 3), expect=False)
        time.sleep(0.5)
        assert h.poses == []  # inactive: no pose, as AMCL before activation
        assert h.transition("amcl", Transition.TRANSITION_ACTIVATE) == State.PRIMARY_STATE_ACTIVE
        h.stream(run, ranges, range(3, 60))
        np.testing.assert_allclose(h.node.localizer.initial_pose, run.scan_truth[0])
        assert h.errors(run).max() <= POSITION_M
        assert any(s.startswith("tracking (initial pose from parameters)") for s in h.states)
        h.wait(lambda: any(level == 0 and "localized" in m for level, m in h.diagnostics),
               "an OK diagnostic status")
        assert h.clouds and all(n >= 1 for n in h.clouds)
        assert h.transition("amcl", Transition.TRANSITION_DEACTIVATE) == \
            State.PRIMARY_STATE_INACTIVE
        before = len(h.poses)
        h.stream(run, ranges, range(60, 63), expect=False)
        time.sleep(0.5)
        assert len(h.poses) == before
        assert h.states[-1] == "inactive"
        kept = h.node.localizer  # activated again: AMCL goes on from its last pose
        assert h.transition("amcl", Transition.TRANSITION_ACTIVATE) == State.PRIMARY_STATE_ACTIVE
        h.wait(lambda: h.states[-1] == "tracking (resumed)", "the resumed state")
        h.stream(run, ranges, range(63, 70))
        assert h.node.localizer is kept and h.errors(run).max() <= POSITION_M
        assert h.transition("amcl", Transition.TRANSITION_DEACTIVATE) == \
            State.PRIMARY_STATE_INACTIVE
        assert h.transition("amcl", Transition.TRANSITION_CLEANUP) == \
            State.PRIMARY_STATE_UNCONFIGURED
        assert h.node.localizer is None and h.node.outputs is None
        assert h.transition("amcl", Transition.TRANSITION_CONFIGURE) == \
            State.PRIMARY_STATE_INACTIVE  # configured again after a cleanup, as nav2 may
        assert h.transition("amcl", Transition.TRANSITION_INACTIVE_SHUTDOWN) == \
            State.PRIMARY_STATE_FINALIZED
        assert h.node.outputs is None
    finally:
        h.close()


def test_the_map_comes_from_the_map_topic_and_services_answer(office):
    """No --map: map_server's grid becomes the segment map; reinitialize_global_localization
    forgets the pose; first_map_only keeps the first map."""
    run, ranges, _ = office
    config = LocalizerConfig.from_yaml("office-laser")
    h = Client(lambda ctx: LocalizerNode(
        None, config, context=ctx,
        parameter_overrides=_amcl_parameters(run.scan_truth[0], first_map_only=True)))
    try:
        h.send_mounts(EPOCH)
        h.map_pub.publish(_office_grid(run))
        h.wait(lambda: h.node.map is not None, "the map built from the topic")
        assert len(h.node.map) >= 0.8 * len(run.map)
        h.stream(run, ranges, range(0, 40))
        assert h.errors(run).max() <= POSITION_M
        h.map_pub.publish(_office_grid(run, shift=3.0))  # first_map_only: ignored
        time.sleep(0.5)
        h.stream(run, ranges, range(40, 50))
        assert h.errors(run)[-10:].max() <= POSITION_M
        h.call(Empty, "request_nomotion_update", Empty.Request())
        h.call(Empty, "reinitialize_global_localization", Empty.Request())
        h.wait(lambda: "lost (global localization requested)" in h.states, "the new state")
        h.stream(run, ranges, range(50, 52))
        assert h.node.localizer is not None and h.node.localizer.initial_pose is None
        if tf2_msgs_available("nav2_msgs.srv"):  # built with tf2_msgs (make ros2)
            from nav2_msgs.srv import SetInitialPose

            request = SetInitialPose.Request()
            request.pose.header.frame_id = "map"
            set_planar_pose(request.pose.pose.pose, run.scan_truth[52])
            request.pose.pose.covariance = ros_covariance(np.diag([0.01, 0.01, 0.001]))
            h.call(SetInitialPose, "set_initial_pose", request)
            h.wait(lambda: "tracking (initial pose received)" in h.states, "the set pose")
            h.stream(run, ranges, range(52, 56))
            np.testing.assert_allclose(h.node.localizer.initial_pose, run.scan_truth[52])
    finally:
        h.close()


def test_a_new_map_on_the_topic_replaces_the_old_one(office):
    """Without ``first_map_only`` a new map replaces the old: the walls are built again and the
    robot goes on from its estimate in the new map."""
    run, ranges, _ = office
    h = Client(lambda ctx: LocalizerNode(
        None, LocalizerConfig.from_yaml("office-laser"), context=ctx,
        parameter_overrides=_amcl_parameters(run.scan_truth[0])))
    try:
        h.send_mounts(EPOCH)
        h.map_pub.publish(_office_grid(run))
        h.wait(lambda: h.node.map is not None, "the first map")
        h.stream(run, ranges, range(0, 20))
        first = h.node.map
        h.map_pub.publish(_office_grid(run))
        h.wait(lambda: h.node.map is not first, "the second map")
        h.wait(lambda: "tracking (new map)" in h.states, "the restart in the new map")
        h.stream(run, ranges, range(20, 40))
        assert h.errors(run).max() <= POSITION_M
    finally:
        h.close()


def test_always_reset_initial_pose_starts_again_on_activation(office):
    """With ``always_reset_initial_pose``, activating again starts from ``initial_pose.*``
    rather than going on from the last pose, as AMCL does."""
    run, ranges, _ = office
    h = Client(lambda ctx: LocalizerNode(
        run.map, LocalizerConfig.from_yaml("office-laser"), context=ctx,
        parameter_overrides=_amcl_parameters(run.scan_truth[0],
                                             always_reset_initial_pose=True)))
    try:
        h.send_mounts(EPOCH)
        h.stream(run, ranges, range(0, 20))
        first = h.node.localizer
        assert h.transition("houghloc", Transition.TRANSITION_DEACTIVATE) == \
            State.PRIMARY_STATE_INACTIVE
        assert h.transition("houghloc", Transition.TRANSITION_ACTIVATE) == \
            State.PRIMARY_STATE_ACTIVE
        assert h.states[-1] == "tracking (initial pose from parameters)"
        assert h.node.localizer is None  # the next scan starts one at the parameters' pose
        h.odom_sent = -math.inf  # the odometry from the start again, as for a robot put back
        h.stream(run, ranges, range(0, 5))
        assert h.node.localizer is not first
        np.testing.assert_allclose(h.node.localizer.initial_pose, run.scan_truth[0])
    finally:
        h.close()


def test_two_lasers_each_at_its_mount_from_tf_static(office):
    """A front and a rear laser on their own topics: both fused, each with its /tf_static
    mount; the poses stay on the truth."""
    run, ranges, rear = office
    config = LocalizerConfig.from_yaml("office-laser")
    h = Client(lambda ctx: LocalizerNode(
        run.map, config, context=ctx, parameter_overrides=_amcl_parameters(
            run.scan_truth[0], **{"houghloc.scan_topics": ["scan", "scan_rear"]})))
    try:
        h.send_mounts(EPOCH)
        h.wait(lambda: h.node._static.planar("base_footprint", "laser_rear") is not None,
               "/tf_static")
        h.stream(run, ranges, range(0, 60), rear=rear)
        assert len(h.poses) == 120 and h.node.dropped_scans == 0
        sensors = h.node.localizer.config.sensors
        np.testing.assert_allclose(sensors["laser_1"].mount, REAR_MOUNT, atol=1e-9)
        np.testing.assert_allclose(sensors["laser"].mount, MOUNT, atol=1e-9)
        assert h.errors(run).max() <= POSITION_M
    finally:
        h.close()


def test_a_restart_after_kill_9_starts_at_the_saved_pose(office, tmp_path):
    """``houghloc ros2``, run as AMCL with a nav2 parameters file, saves its pose; killed with
    SIGKILL and started again without a pose, it starts at the saved one and tracks; a saved
    pose too old is not used."""
    run, ranges, _ = office
    saved = tmp_path / "pose.json"
    domain = _own_domain()
    # a nav2 bringup's parameters file, the node under AMCL's name
    params = tmp_path / "nav2_params.yaml"
    params.write_text(f"""amcl:
  ros__parameters:
    base_frame_id: base_footprint
    global_frame_id: map
    odom_frame_id: odom
    scan_topic: scan
    laser_model_type: likelihood_field
    max_particles: 2000
    update_min_d: 0.25
    saved_pose_filepath: {saved}
    houghloc:
      save_pose_period: 0.2
""")
    command = [sys.executable, "-m", "fusion", "ros2", "--map", str(run.map_path), "--config",
               "office-laser", "--ros-args", "--params-file", str(params), "-r", "__node:=amcl"]
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    first = subprocess.Popen([*command[:6], "--initial-pose", *map(str, run.scan_truth[0]),
                              *command[6:]], env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    h = Client(None, domain)
    try:
        h.wait(lambda: any("tracking" in s for s in h.states), "the first node", 60.0)
        h.send_mounts(EPOCH)
        time.sleep(0.5)
        h.stream(run, ranges, range(0, 80))
        time.sleep(0.6)  # a save or two after the last scan
        first.send_signal(signal.SIGKILL)
        first.wait(TIMEOUT)
        pose = load_pose(saved)
        assert np.hypot(*(pose.pose[:2] - run.scan_truth[79][:2])) <= POSITION_M

        h.states.clear()
        second = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        try:
            h.wait(lambda: any("saved pose" in s for s in h.states), "the restart", 60.0)
            h.send_mounts(EPOCH)
            time.sleep(0.5)
            first_new = len(h.poses)
            h.stream(run, ranges, range(80, 120))
            errors = h.errors(run)[first_new:]
            # the first pose is the saved one moved by the odometry from its reading on: the
            # robot drove on from scan 79 to 80 while no node ran
            travelled = np.hypot(*(run.scan_truth[80][:2] - run.scan_truth[79][:2]))
            assert errors[0] <= travelled + POSITION_M
            assert errors[1:].max() <= POSITION_M
        finally:
            second.send_signal(signal.SIGTERM)
            second.wait(20)

        doc = json.loads(saved.read_text())
        doc["saved_at"] -= 3600.0  # an hour ago: the robot may have been carried since
        saved.write_text(json.dumps(doc))
        h.states.clear()
        third = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
        try:
            h.wait(lambda: any(s.startswith("lost (global localization)") for s in h.states),
                   "the restart with an old pose", 60.0)
        finally:
            third.send_signal(signal.SIGTERM)
            third.wait(20)
    finally:
        if first.poll() is None:
            first.kill()
        h.close()


def test_the_map_topic_timing_names_each_building_and_the_peer():
    """``python -m benchmarks.bench_ros2 --grid``: the real buildings' grids, padded to
    2000 × 2000 cells, each to a segment map, beside nav2's AMCL on the same grid (the
    figures are in docs/ros2.md; no time is asserted)."""
    from benchmarks.bench_real import DATA
    from benchmarks.bench_ros2 import main

    if not DATA.is_dir():
        pytest.skip(f"real logs not found at {DATA}")
    times = main(["--grid"])
    assert set(times) == {"aces", "intel", "fr079"}
    assert all(t > 0 for t in times.values())

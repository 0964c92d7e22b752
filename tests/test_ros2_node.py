"""The ROS 2 node over the real middleware (ROS 2 Kilted's PyPI wheels, Fast DDS), in one process:
a simulated office run published on /scan, /odom, /tf_static and /initialpose, the poses, the
map → odom transform and the state received back and checked against the simulator's truth.

Skipped, saying why, when the ``ros2`` extra is not installed (``make ros2``, which ``make test``
runs; it needs the wheels from PyPI, CMake and a C compiler for tf2_msgs).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

try:
    import rclpy
except ImportError as exc:
    pytest.skip(f"rclpy is not installed ({exc}): `make ros2` installs the ros2 extra, and "
                "failed or was not run", allow_module_level=True)
from fusion.ros2.tf2_msgs import available as tf2_msgs_available

if not tf2_msgs_available():
    pytest.skip("tf2_msgs is not installed: `python -m fusion.ros2.tf2_msgs` builds it",
                allow_module_level=True)

from benchmarks.bench_ros2 import office_run, stream_through_node
from fusion.config import LocalizerConfig
from fusion.ros2.run import STOP_CHECK_SECONDS
from houghloc.geometry import compose

RESET_AT = 150
"""The scan before which /initialpose moves the robot 30 cm and 3° off its true pose."""
ATE_M = 0.01
"""m: the simulated office with its own configuration (0.13 cm through the node, as offline)."""
SETTLE_S = 2.0
"""s for a start known to RViz's 0.5 m to settle, where the first scan sees a corridor."""


@pytest.fixture(scope="module")
def through_node():
    run, ranges = office_run(seconds=30.0, seed=5)
    off = run.scan_truth[RESET_AT] + np.array([0.3, -0.2, 0.05])
    result = stream_through_node(run, ranges, LocalizerConfig.from_yaml("office-laser"),
                                 resets={RESET_AT: off})
    return run, result, off


def test_every_scan_gets_its_pose_and_the_poses_match_the_truth(through_node):
    run, result, _ = through_node
    assert result.sent == len(run.scan_t) == len(result.t)
    np.testing.assert_allclose(result.t, run.scan_t, atol=1e-6)  # the scans' own stamps
    errors = result.errors(run)
    assert np.sqrt(np.mean(errors**2)) <= ATE_M
    assert errors.max() <= 5 * ATE_M
    assert result.states[-1].startswith("tracking, localized")
    # the integrity output: a probability with every pose, sure in the office (the node's
    # median is 0.97: its covariance is the one at the scan, before the odometry after it)
    assert len(result.localized) >= len(result.t) - 5
    assert all(0.0 <= p <= 1.0 for p in result.localized)
    assert np.median(result.localized) > 0.9


def test_initialpose_starts_the_localizer_again_where_rviz_says(through_node):
    run, result, off = through_node
    np.testing.assert_allclose(result.started_from[0], run.scan_truth[0], atol=1e-9)
    np.testing.assert_allclose(result.started_from[RESET_AT], off, atol=1e-9)
    assert sum("initial pose received" in s for s in result.states) == 2
    # 36 cm and 3° off, with RViz's σ (0.5 m, 15°): the first scan's fix corrects it
    assert result.errors(run)[RESET_AT] <= ATE_M


def test_map_to_odom_puts_the_odometry_on_the_pose(through_node):
    """/tf's map → odom composed with the odometry at the scan's time is the published pose."""
    run, result, _ = through_node
    odometry = {round(t, 6): pose for t, pose in zip(run.odom_t, run.odom_pose, strict=True)}
    checked = 0
    for t, pose in zip(result.t, result.poses, strict=True):
        key = round(t, 6)
        if key in odometry and key in result.tf:
            np.testing.assert_allclose(compose(result.tf[key], odometry[key]), pose, atol=1e-6)
            checked += 1
    assert checked >= 0.9 * len(result.t)


def test_the_node_shuts_down_cleanly(through_node):
    """The stream stops the executor, destroys both nodes and shuts the context down; it raises
    when the executor's thread is still alive after that (a hang guard, not a speed limit)."""
    _, result, _ = through_node
    assert math.isfinite(result.shutdown_seconds)


@pytest.mark.parametrize(("signum", "sigint"), [
    (signal.SIGINT, signal.SIG_DFL), (signal.SIGTERM, signal.SIG_DFL),
    (signal.SIGTERM, signal.SIG_IGN)], ids=["SIGINT", "SIGTERM", "SIGINT-ignored"])
def test_the_command_runs_the_node_until_a_signal(signum, sigint, tmp_path):
    """`houghloc ros2` comes up (its latched state arrives), then stops cleanly on a signal.
    Started with SIGINT ignored (a background job of a shell without job control), it keeps
    SIGINT ignored and stops on SIGTERM."""
    from std_msgs.msg import String

    from fusion.ros2.outputs import LATCHED

    # a DDS domain of its own: no crosstalk with other tests
    domain = str(50 + int(signum) + (10 if sigint is signal.SIG_IGN else 0))
    env = {**os.environ, "ROS_DOMAIN_ID": domain}
    node = subprocess.Popen(
        [sys.executable, "-m", "fusion", "ros2", "--map", "office", "--config", "office-laser",
         "--ros-args", "-r", "__node:=houghloc_cli"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(domain))
    try:
        client = rclpy.create_node("houghloc_probe", context=context)
        states: list[str] = []
        client.create_subscription(String, "houghloc/state", lambda m: states.append(m.data),
                                   LATCHED)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(client)
        # a cold start compiles the kernels: about 45 s alone, more beside other test processes
        deadline = time.monotonic() + 180.0
        # (configured, then active and lost: no pose given; a late probe gets only the last)
        while not any(s.startswith("lost") for s in states) and time.monotonic() < deadline \
                and node.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        assert states and states[-1].startswith("lost"), \
            node.stderr.read() if node.poll() else ""
        if sigint is signal.SIG_IGN:
            node.send_signal(signal.SIGINT)
            with pytest.raises(subprocess.TimeoutExpired):  # ignored: the node spins on
                node.wait(timeout=10 * STOP_CHECK_SECONDS)
        node.send_signal(signum)
        _, err = node.communicate(timeout=20)
    finally:
        if node.poll() is None:
            node.kill()
        rclpy.shutdown(context=context)
    assert node.returncode == 0, err
    assert "Traceback" not in err and "warning" not in err
    assert err.endswith("houghloc: 0 scans localized, 0 dropped\n")


def test_bad_messages_are_dropped_with_a_warning_and_the_node_goes_on() -> None:
    """Each callback gets what a faulty driver or a stray click sends; none may raise (an
    exception in a callback ends the executor), and the good scans after them still localize.
    The callbacks are called directly: the fault is in the message, not in its transport."""
    from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    from benchmarks.bench_ros2 import EPOCH, _odometry
    from fusion.ros2.messages import ros_covariance, set_planar_pose, set_stamp
    from fusion.ros2.node import LocalizerNode

    run, _ = office_run(seconds=3.0, seed=2)
    ranges = run.ranges  # the laser at the base's origin: the broken /tf_static is not used
    context = rclpy.Context()
    rclpy.init(context=context)
    node = LocalizerNode(run.map, LocalizerConfig.from_yaml("office-laser"), None,
                         context=context)
    cfg = run.config.laser

    def scan(t: float, r, increment: float = float(run.angles[1] - run.angles[0]),
             frame: str = "laser") -> LaserScan:
        msg = LaserScan()
        msg.header.frame_id = frame
        set_stamp(msg.header.stamp, t)
        msg.angle_min, msg.angle_increment = float(run.angles[0]), increment
        msg.range_min, msg.range_max = float(cfg.min_range), float(cfg.max_range)
        msg.ranges = [float(v) for v in r]
        return msg

    def initial(pose, cov=(0.25, 0.25, 0.07)) -> PoseWithCovarianceStamped:
        msg = PoseWithCovarianceStamped()
        set_planar_pose(msg.pose.pose, np.asarray(pose, dtype=float))
        msg.pose.covariance = ros_covariance(np.diag(cov))
        return msg

    try:
        bad_mount = TransformStamped()
        bad_mount.header.frame_id, bad_mount.child_frame_id = "base_footprint", "laser"
        bad_mount.transform.translation.x = float("nan")
        no_rotation = TransformStamped()
        no_rotation.header.frame_id, no_rotation.child_frame_id = "base_footprint", "laser"
        no_rotation.transform.rotation.w = 0.0  # a quaternion of zero length
        node._on_tf_static(TFMessage(transforms=[bad_mount, no_rotation]))
        node._on_initial_pose(initial([np.nan, 0.0, 0.0]))  # dropped
        node._on_initial_pose(initial([1e7, -1e7, 0.0], cov=(-1.0, 1e30, 1e30)))
        t0 = EPOCH + run.scan_t[0]
        node._on_odometry(_odometry(Odometry(), t0, [np.nan, 0.0, 0.0]))  # dropped
        node._on_odometry(_odometry(Odometry(), t0, run.odom_pose[0]))
        for msg in (scan(t0, []), scan(t0, [np.nan] * 361), scan(t0, [np.inf] * 361),
                    scan(t0, [1e300] * 361), scan(t0, ranges[0], increment=np.nan),
                    scan(t0, ranges[0], increment=0.0), scan(-5.0, ranges[0]),
                    scan(t0 + 1e6, ranges[0])):
            node._on_scan(msg)
        node._release_waiting()
        time.sleep(node.settings.houghloc__odom_wait)
        node._release_waiting()  # every bad scan has gone through or been dropped
        assert node.localizer is not None and np.isfinite(node.localizer.pose).all()
        assert node.localizer.initial_pose is None  # the absurd pose was refused
        node._on_initial_pose(initial(run.scan_truth[0]))
        odometry = list(zip(run.odom_t, run.odom_pose, strict=True))
        for t, r in zip(run.scan_t, ranges, strict=True):
            for ot, pose in [o for o in odometry if t - 0.1 < o[0] <= t]:
                node._on_odometry(_odometry(Odometry(), EPOCH + ot, pose))
            node._on_scan(scan(EPOCH + t, r))
        final = node.localizer.pose
        assert np.hypot(*(final[:2] - run.scan_truth[-1][:2])) < 0.05
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_houghloc_ros2_in_its_own_process_localizes_the_run() -> None:
    """As on a robot: `houghloc ros2` in a process of its own, the run published from this one."""
    run, ranges = office_run(seconds=10.0, seed=7)
    result = stream_through_node(run, ranges, LocalizerConfig(), separate="office-laser",
                                 timeout=10.0)
    assert len(result.t) == result.sent == len(run.scan_t)
    # The start pose comes as RViz sends it, known to 0.5 m: the first scans see only the
    # office's corridor and place the robot along it within that (7 cm off at first); from
    # the first full fixes on it is as offline.
    errors = result.errors(run)
    settled = np.asarray(result.t) >= result.t[0] + SETTLE_S
    assert errors.max() <= 0.1
    assert np.sqrt(np.mean(errors[settled] ** 2)) <= ATE_M
    assert len(result.tf) >= 0.9 * len(result.t)


def test_the_node_and_the_replay_give_the_same_poses_on_the_same_out_of_order_stream():
    """One owner of time ordering (fusion.time_order): the same stream, in the same arrival
    order, through the node's callbacks and through ``replay``, gives the same pose at every
    scan, bit for bit, as published and as written. The stream is out of order as drivers send
    it: every scan comes before the odometry reading at its own stamp (its pose is published
    once that reading comes), and the readings of 1.5 s come late, all at once, after the scans
    of that time (whose poses are published when the next scan comes). The callbacks are called
    directly so that the arrival order is the test's, not the middleware's; what the node
    publishes is recorded where it hands each pose to its publishers."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan

    from benchmarks.bench_ros2 import EPOCH, _odometry
    from fusion.io.rosbag import odometry_event, scan_event
    from fusion.localizer import Localizer
    from fusion.replay import replay
    from fusion.ros2.messages import set_stamp
    from fusion.ros2.node import LocalizerNode
    from fusion.time_order import settled

    class Published(LocalizerNode):
        """The node, recording each pose as it hands it to its publishers."""

        def __init__(self, *args, **kwargs) -> None:
            self.published: list[tuple[float, np.ndarray, str]] = []
            super().__init__(*args, **kwargs)

        def _report(self, due) -> None:
            for held in due:
                est = settled(held, self.localizer.tracker)
                self.published.append((est.t, est.pose.copy(), str(est.status)))
            super()._report(due)

    run, _ = office_run(seconds=10.0, seed=3)
    config = LocalizerConfig.from_yaml("office-laser")
    cfg = run.config.laser
    increment = float(run.angles[1] - run.angles[0])

    def scan(t: float, r) -> LaserScan:
        msg = LaserScan()
        msg.header.frame_id = "laser"
        set_stamp(msg.header.stamp, EPOCH + t)
        msg.angle_min, msg.angle_increment = float(run.angles[0]), increment
        msg.angle_max = float(run.angles[0]) + increment * (len(r) - 1)
        msg.range_min, msg.range_max = float(cfg.min_range), float(cfg.max_range)
        msg.ranges = [float(v) for v in r]
        return msg

    late = (4.0, 5.5)  # the odometry of these seconds comes after the scans of them
    stream: list = [_odometry(Odometry(), EPOCH + run.odom_t[0], run.odom_pose[0])]
    held: list = []
    readings = iter(zip(run.odom_t[1:], run.odom_pose[1:], strict=True))
    reading = next(readings, None)
    for t, r in zip(run.scan_t, run.ranges, strict=True):
        while reading is not None and reading[0] < t:  # the readings before the scan
            (held if late[0] <= reading[0] < late[1] else stream).append(
                _odometry(Odometry(), EPOCH + reading[0], reading[1]))
            reading = next(readings, None)
        stream.append(scan(t, r))  # the scan, then the reading at its stamp
        if held and t >= late[1]:
            stream.extend(held)
            held = []
    assert sum(isinstance(m, LaserScan) for m in stream) == len(run.scan_t)

    context = rclpy.Context()
    rclpy.init(context=context)
    node = Published(run.map, config, run.scan_truth[0], context=context)
    try:
        for msg in stream:
            if isinstance(msg, LaserScan):
                node._on_scan(msg)
            else:
                node._on_odometry(msg)
        node._report(node._order.drain())  # the stream ended
        assert node.localizer is not None
        used = node.localizer.config
        start = node.localizer.initial_pose
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)

    events = [scan_event(m, used.laser, 0, {}) if isinstance(m, LaserScan) else odometry_event(m)
              for m in stream]
    replayed = replay(events, Localizer(run.map, used, start), progress=False)

    published = node.published
    assert len(published) == len(replayed.t) == len(run.scan_t)
    for (t_node, pose_node, status_node), t_replay, pose_replay, status_replay in zip(
            published, replayed.t, replayed.poses, replayed.statuses, strict=True):
        assert t_node == t_replay and status_node == str(status_replay)
        assert np.array_equal(pose_node, pose_replay), (t_node - EPOCH, pose_node - pose_replay)
    errors = np.hypot(*(replayed.poses[:, :2] - run.scan_truth[:, :2]).T)
    without = (run.scan_t >= late[0]) & (run.scan_t < late[1] + 0.5)
    assert errors[~without].max() < 0.02
    assert errors[without].max() < 0.25  # the readings of those 1.5 s came too late to be used


def test_a_pose_published_without_its_odometry_comes_without_a_map_to_odom_transform():
    """Scans whose odometry reading has come get their pose and map → odom on /tf; a scan whose
    odometry never comes gets its pose after ``odom_wait`` but no transform: composed with the
    reading before the scan, the transform would be off by the motion since (the robot drives
    at 0.3 m/s here, 3 cm a scan)."""
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    from benchmarks.bench_ros2 import EPOCH, _odometry
    from fusion.ros2.messages import set_stamp, stamp_seconds
    from fusion.ros2.node import LocalizerNode

    run, _ = office_run(seconds=3.0, seed=2)
    cfg = run.config.laser
    increment = float(run.angles[1] - run.angles[0])

    def scan(t: float, r) -> LaserScan:
        msg = LaserScan()
        msg.header.frame_id = "laser"
        set_stamp(msg.header.stamp, EPOCH + t)
        msg.angle_min, msg.angle_increment = float(run.angles[0]), increment
        msg.angle_max = float(run.angles[0]) + increment * (len(r) - 1)
        msg.range_min, msg.range_max = float(cfg.min_range), float(cfg.max_range)
        msg.ranges = [float(v) for v in r]
        return msg

    context = rclpy.Context()
    rclpy.init(context=context)
    node = LocalizerNode(run.map, LocalizerConfig.from_yaml("office-laser"), run.scan_truth[0],
                         context=context)
    client = rclpy.create_node("tf_probe", context=context)
    tf_scans: list[float] = []
    client.create_subscription(TFMessage, "/tf", lambda m: tf_scans.extend(
        stamp_seconds(tf.header.stamp) - node.transform_tolerance - EPOCH
        for tf in m.transforms), 100)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(client)
    try:
        assert node.outputs is not None and node.outputs.tf_pub is not None
        deadline = time.monotonic() + 10.0
        while (node.outputs.tf_pub.get_subscription_count() == 0
               and time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.05)
        readings = list(zip(run.odom_t, run.odom_pose, strict=True))
        covered = run.scan_t[:5]
        for t, r in zip(covered, run.ranges[:5], strict=True):  # the odometry reaches each
            for ot, pose in [o for o in readings if t - 0.1 < o[0] <= t + 0.02]:
                node._on_odometry(_odometry(Odometry(), EPOCH + ot, pose))
            node._on_scan(scan(t, r))
        last = covered[-1] + 0.02
        lone = float(run.scan_t[5])  # its odometry never comes
        node._on_scan(scan(lone, run.ranges[5]))
        assert node.scans == 6
        time.sleep(node.settings.houghloc__odom_wait)
        node._release_waiting()
        deadline = time.monotonic() + 5.0
        while len(tf_scans) < 5 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(10):  # a transform for the lone scan would have come by now
            executor.spin_once(timeout_sec=0.05)
        assert lone > last
        np.testing.assert_allclose(sorted(tf_scans), covered, atol=1e-6)
        assert node._last is not None and abs(node._last.t - (EPOCH + lone)) < 1e-6
    finally:
        executor.shutdown()
        client.destroy_node()
        node.destroy_node()
        rclpy.shutdown(context=context)

"""The ROS 2 node's throughput and latency: a simulated office run published over ROS 2.

One process, the real middleware (ROS 2 Kilted's rclpy with Fast DDS, from PyPI): a client node
publishes the run's ``/tf_static`` (the laser 20 cm ahead of the base), ``/initialpose``, and its
odometry and scans in time order as fast as the node keeps up (each scan's pose is awaited before
the next scan goes out), and receives ``amcl_pose``, ``/tf`` and ``houghloc/state``.

Prints scans/s through the node and the latency from a scan's publication to its pose's arrival
(median, 95th percentile, max), beside the same run replayed without ROS (``houghloc run``'s
path), and the accuracy against the simulator's truth. Needs the ``ros2`` extra (``make ros2``).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import threading
import time
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.config import LocalizerConfig
from fusion.sim import SimRun, scenario_preset, simulate

MOUNT = (0.20, -0.05, 0.10)
"""The laser on the robot's base (m, m, rad), sent on /tf_static."""
EPOCH = 1.7e9
"""s: the published stamps start at a real date (0 reads as "unset" in ROS)."""
RVIZ_COVARIANCE = (0.25, 0.25, 0.06853891945200942)
"""RViz's "2D Pose Estimate": σ 0.5 m in x and y, 15° in heading."""


@dataclass
class NodeRun:
    """What came back from the node, scan by scan (stamps in the run's own clock)."""

    t: list[float] = field(default_factory=list)
    poses: list[NDArray[np.float64]] = field(default_factory=list)
    tf: dict[float, NDArray[np.float64]] = field(default_factory=dict)  # scan t → map → odom
    states: list[str] = field(default_factory=list)
    localized: list[float] = field(default_factory=list)  # houghloc/localized, as published
    latencies: list[float] = field(default_factory=list)  # s, scan published → pose received
    seconds: float = 0.0  # wall time of the streaming
    sent: int = 0
    shutdown_seconds: float = math.nan  # executor stopped, nodes destroyed, context down
    started_from: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    """Scan index of each /initialpose → the initial pose of the Localizer that took it."""

    @property
    def scans_per_second(self) -> float:
        return len(self.t) / self.seconds if self.seconds > 0 else math.nan

    def errors(self, run: SimRun) -> NDArray[np.float64]:
        """Position error (m) of every returned pose against the truth."""
        index = {round(t, 6): k for k, t in enumerate(run.scan_t)}
        return np.array([float(np.hypot(*(pose[:2] - run.scan_truth[index[round(t, 6)]][:2])))
                         for t, pose in zip(self.t, self.poses, strict=True)])


def office_run(seconds: float = 60.0, seed: int = 5) -> tuple[SimRun, NDArray[np.float64]]:
    """The simulated office and its scans from the mounted laser."""
    run = simulate(scenario_preset("office-laser", seed=seed, duration=seconds))
    assert run.laser is not None
    return run, run.laser.mounted(MOUNT).all()[0]


def stream_through_node(run: SimRun, ranges: NDArray[np.float64], config: LocalizerConfig,
                        resets: dict[int, NDArray[np.float64]] | None = None,
                        timeout: float = 5.0, logger: object = None,
                        separate: str | None = None) -> NodeRun:
    """Start the node and a client in one process, send the run, collect what comes back.

    ``resets``: scan index → a pose sent on /initialpose (with RViz's covariance) just before
    that scan; the first scan always gets the true start pose that way (the node itself starts
    with none). ``logger``: the node's Rerun recording, if any. Raises TimeoutError when the
    node does not answer a scan in ``timeout``. ``separate``: the name of a packaged config to
    run the node with as ``houghloc ros2`` in a process of its own, as on a robot (``config``
    is then unused), on a DDS domain of its own."""
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import Float32, String
    from tf2_msgs.msg import TFMessage

    from fusion.ros2.messages import (
        planar_pose,
        planar_transform,
        ros_covariance,
        set_planar_pose,
        set_stamp,
        stamp_seconds,
    )
    from fusion.ros2.node import LocalizerNode
    from fusion.ros2.outputs import LATCHED
    from fusion.ros2.settings import NodeSettings

    resets = {0: run.scan_truth[0], **(resets or {})}
    out = NodeRun()
    got = threading.Condition()
    context = rclpy.Context()
    process = None
    if separate is None:
        rclpy.init(context=context)
        node = LocalizerNode(run.map, config, None, logger, context=context)  # type: ignore[arg-type]
        tolerance = node.transform_tolerance
    else:
        domain = 40 + os.getpid() % 50
        process = subprocess.Popen(
            [sys.executable, "-m", "fusion", "ros2", "--map", str(run.map_path), "--config",
             separate], env={**os.environ, "ROS_DOMAIN_ID": str(domain)},
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        rclpy.init(context=context, domain_id=domain)
        tolerance = NodeSettings().transform_tolerance  # the node's default
    client = rclpy.create_node("houghloc_client", context=context)

    def on_pose(msg: PoseWithCovarianceStamped) -> None:
        with got:
            out.t.append(stamp_seconds(msg.header.stamp) - EPOCH)
            out.poses.append(np.array(planar_pose(msg.pose.pose)))
            out.latencies.append(time.perf_counter() - sent_at[-1])
            got.notify_all()

    def on_tf(msg: TFMessage) -> None:
        for tf in msg.transforms:
            scan_t = stamp_seconds(tf.header.stamp) - tolerance - EPOCH
            out.tf[round(scan_t, 6)] = np.array(planar_transform(tf.transform))

    def on_state(msg: String) -> None:
        with got:
            out.states.append(msg.data)
            got.notify_all()

    def on_localized(msg: Float32) -> None:
        out.localized.append(float(msg.data))

    pose_sub = client.create_subscription(PoseWithCovarianceStamped, "amcl_pose", on_pose,
                                          100)
    tf_sub = client.create_subscription(TFMessage, "/tf", on_tf, 100)
    every_state = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
    state_sub = client.create_subscription(String, "houghloc/state", on_state, every_state)
    localized_sub = client.create_subscription(Float32, "houghloc/localized", on_localized, 100)
    scan_pub = client.create_publisher(LaserScan, "scan", 10)
    odom_pub = client.create_publisher(Odometry, "odom", 100)
    initial_pub = client.create_publisher(PoseWithCovarianceStamped, "initialpose", 10)
    static_pub = client.create_publisher(TFMessage, "/tf_static", LATCHED)
    executor = SingleThreadedExecutor(context=context)
    if process is None:
        executor.add_node(node)
    executor.add_node(client)
    spinner = threading.Thread(target=executor.spin, name="ros2-executor", daemon=True)
    spinner.start()
    sent_at: list[float] = [time.perf_counter()]

    def wait(condition, what: str, seconds: float = timeout) -> None:
        with got:
            if not got.wait_for(condition, seconds):
                raise TimeoutError(f"the node did not answer in {seconds} s: {what}")

    try:
        wait(lambda: all(p.get_subscription_count() for p in
                         (scan_pub, odom_pub, initial_pub, static_pub))
             and all(s.get_publisher_count() for s in (pose_sub, tf_sub, state_sub, localized_sub)),
             "discovery", 60.0 if process is not None else timeout)  # a cold start compiles
        static = TFMessage(transforms=[_transform(TransformStamped(), "base_footprint", "laser",
                                                  EPOCH + run.scan_t[0], MOUNT)])
        static_pub.publish(static)
        cfg = run.config.laser
        angle_min, increment = float(run.angles[0]), float(run.angles[1] - run.angles[0])
        odometry = iter(zip(run.odom_t, run.odom_pose, strict=True))
        next_odometry = next(odometry, None)
        started = time.perf_counter()
        for k, (t, r) in enumerate(zip(run.scan_t, ranges, strict=True)):
            if k in resets:
                taken = _initial_poses_taken(out.states)
                msg = PoseWithCovarianceStamped()
                msg.header.frame_id = "map"
                set_stamp(msg.header.stamp, EPOCH + t)
                set_planar_pose(msg.pose.pose, resets[k])
                msg.pose.covariance = ros_covariance(np.diag(RVIZ_COVARIANCE))
                initial_pub.publish(msg)
                # (the latched state of the node's start may arrive meanwhile: wait for this one)
                wait(lambda n=taken: _initial_poses_taken(out.states) > n, "the initial pose")
            scan = LaserScan()
            scan.header.frame_id = "laser"
            set_stamp(scan.header.stamp, EPOCH + t)
            scan.angle_min, scan.angle_increment = angle_min, increment
            scan.angle_max = angle_min + increment * (len(r) - 1)
            scan.range_min, scan.range_max = float(cfg.min_range), float(cfg.max_range)
            scan.ranges = array("f", r.astype(np.float32).tobytes())  # no per-element checks
            expected = len(out.t) + 1
            sent_at.append(time.perf_counter())
            scan_pub.publish(scan)
            out.sent += 1
            # the odometry up to the scan, and past it when none is at its time: the node
            # holds a scan until the odometry reaches it
            last = -math.inf
            while next_odometry is not None and (next_odometry[0] <= t or last < t):
                odom_pub.publish(_odometry(Odometry(), EPOCH + next_odometry[0],
                                           next_odometry[1]))
                last, next_odometry = next_odometry[0], next(odometry, None)
            wait(lambda e=expected: len(out.t) >= e, f"scan {k} at t = {t:.2f} s")
            if k in resets and process is None and node.localizer is not None:
                out.started_from[k] = np.array(node.localizer.initial_pose)
        out.seconds = time.perf_counter() - started
    finally:
        stopping = time.perf_counter()
        executor.shutdown(timeout_sec=timeout)
        if process is None:
            node.destroy_node()
        else:
            process.send_signal(signal.SIGTERM)
            _, err = process.communicate(timeout=20)
            if process.returncode != 0:
                raise RuntimeError(f"houghloc ros2 exited {process.returncode}: {err}")
        client.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout)
        if spinner.is_alive():
            raise RuntimeError("the executor thread did not stop")
        out.shutdown_seconds = time.perf_counter() - stopping
    return out


def _initial_poses_taken(states: list[str]) -> int:
    return sum("initial pose received" in s for s in states)


def _transform(tf, parent: str, child: str, t: float, pose) -> object:
    from fusion.ros2.messages import set_planar_transform, set_stamp

    tf.header.frame_id, tf.child_frame_id = parent, child
    set_stamp(tf.header.stamp, t)
    set_planar_transform(tf.transform, np.asarray(pose, dtype=float))
    return tf


def _odometry(msg, t: float, pose) -> object:
    from fusion.ros2.messages import set_planar_pose, set_stamp

    msg.header.frame_id, msg.child_frame_id = "odom", "base_footprint"
    set_stamp(msg.header.stamp, t)
    set_planar_pose(msg.pose.pose, pose)
    return msg


def replay_rate(run: SimRun, config: LocalizerConfig) -> float:
    """Scans/s of the same run replayed without ROS (from its events, laser at the origin)."""
    from fusion.localizer import Localizer
    from fusion.replay import replay

    loc = Localizer(run.map, config, run.scan_truth[0])
    started = time.perf_counter()
    result = replay(run.events(), loc, progress=False)
    return len(result.t) / (time.perf_counter() - started)


def plot(run: SimRun, result: NodeRun, resets: dict[int, NDArray[np.float64]],
         path: str) -> None:
    """The map, the true path, the poses the node published and the /initialpose sent."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 5.2), layout="constrained")
    for start, end in zip(run.map.starts, run.map.ends, strict=True):
        ax.plot([start[0], end[0]], [start[1], end[1]], color="0.55", lw=1.2)
    ax.plot(run.scan_truth[:, 0], run.scan_truth[:, 1], color="black", lw=3, alpha=0.25,
            label="simulator's truth")
    poses = np.array(result.poses)
    ax.plot(poses[:, 0], poses[:, 1], color="tab:blue", lw=1,
            label="amcl_pose, received over ROS 2")
    for k, pose in resets.items():
        ax.annotate("", xy=pose[:2] + 0.6 * np.array([np.cos(pose[2]), np.sin(pose[2])]),
                    xytext=pose[:2], arrowprops={"arrowstyle": "->", "color": "tab:red"})
        ax.plot(*pose[:2], "o", color="tab:red", ms=5,
                label="/initialpose (RViz's σ)" if k == min(resets) else None)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    errors = result.errors(run)
    ax.set_title(f"The ROS 2 node on the simulated office: {len(result.t)} scans, "
                 f"ATE {np.sqrt(np.mean(errors**2)) * 100:.2f} cm, "
                 f"{result.scans_per_second:.0f} scans/s through the middleware")
    ax.legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


GRID_CELLS = 2000
"""The map topic's grid side for the timing: 2000 × 2000 cells (100 m square at 5 cm)."""


def time_map_topic(names: tuple[str, ...] = ("aces", "intel", "fr079")) -> dict[str, float]:
    """Seconds from a ``map_server`` grid of 2000 × 2000 cells to the node's segment map (the
    message converted, the walls extracted), for the real buildings' same-run grids padded to
    that size, beside nav2's AMCL computing its likelihood field from the same grid."""
    import time as clock

    from nav_msgs.msg import OccupancyGrid as GridMessage

    from fusion.bench.data import RunData
    from fusion.bench.spec import Protocol, load_spec
    from fusion.mapping import OccupancyGrid
    from fusion.mapping.segments import extract_segments
    from fusion.ros2.messages import grid_from_message, set_grid

    spec = load_spec(Path(__file__).with_name("real.yaml"))
    times = {}
    for run in (r for r in spec.runs if r.name in names and r.log.exists()):
        grid = RunData.load(run, spec.max_dt).pieces(Protocol.SAME_RUN)[0].map_source.grid
        occupied = np.zeros((GRID_CELLS, GRID_CELLS), dtype=bool)
        free = np.zeros_like(occupied)
        rows, cols = min(grid.shape[0], GRID_CELLS), min(grid.shape[1], GRID_CELLS)
        occupied[:rows, :cols] = grid.occupied[:rows, :cols]
        free[:rows, :cols] = grid.free[:rows, :cols]
        msg = set_grid(GridMessage(), OccupancyGrid.from_masks(occupied, free, grid.resolution,
                                                               grid.origin))
        started = clock.perf_counter()
        segments = extract_segments(grid_from_message(msg, GRID_CELLS**2))
        times[run.name] = clock.perf_counter() - started
        peer = _nav2_field_seconds(msg)
        ratio = f"{times[run.name] / peer:.2f}× nav2 AMCL's likelihood field ({peer:.2f} s)" \
            if peer == peer else "nav2's AMCL not built (make peers)"
        print(f"  {run.name:6s} grid {GRID_CELLS} × {GRID_CELLS}: {len(segments)} walls in "
              f"{times[run.name]:.2f} s; {ratio}")
    if not times:
        print("  real logs not found: nothing timed")
    return times


def _nav2_field_seconds(msg) -> float:
    """nav2's AMCL taking the same grid (its likelihood field up to 2 m), NaN when not built."""
    import time as clock

    from fusion.bench.methods import AMCL_NAV2
    from fusion.bench.nav2_amcl import Nav2Amcl, Nav2AmclUnavailable

    try:
        filt = Nav2Amcl(min_particles=500, max_particles=2000, alpha_slow=0.0, alpha_fast=0.0,
                        alpha=AMCL_NAV2["alpha"])
    except Nav2AmclUnavailable:
        return math.nan
    data = np.asarray(msg.data, dtype=np.int8).reshape(msg.info.height, msg.info.width)
    started = clock.perf_counter()
    filt.set_map(data, msg.info.resolution, (msg.info.origin.position.x,
                                             msg.info.origin.position.y),
                 "likelihood_field", AMCL_NAV2, AMCL_NAV2["max_beams"])
    return clock.perf_counter() - started


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--plot", metavar="PNG", help="draw the run (docs/images/ros2_node.png)")
    parser.add_argument("--rrd", metavar="FILE", help="record the node's run for Rerun")
    parser.add_argument("--separate", action="store_true",
                        help="the node as `houghloc ros2` in its own process, as on a robot")
    parser.add_argument("--grid", action="store_true",
                        help="only time the map topic's grid → segment map (2000 × 2000 cells)")
    args = parser.parse_args(argv)
    try:
        import rclpy  # noqa: F401
        from tf2_msgs.msg import TFMessage  # noqa: F401
    except ImportError as exc:
        print(f"not available: {exc} (make ros2 installs the ros2 extra and tf2_msgs)")
        return {}
    if args.grid:
        print("map topic → segment map")
        return time_map_topic()
    run, ranges = office_run(args.duration)
    config = LocalizerConfig.from_yaml("office-laser")
    middle = len(run.scan_t) // 2
    resets = {0: run.scan_truth[0], middle: run.scan_truth[middle] + np.array([0.3, -0.2, 0.05])}
    logger = None
    if args.rrd:
        from fusion.rerun_logger import RerunLogger

        logger = RerunLogger(args.rrd)
    result = stream_through_node(run, ranges, config, resets=resets, logger=logger,
                                 separate="office-laser" if args.separate else None)
    if logger is not None:
        logger.close()
    if args.plot:
        plot(run, result, resets, args.plot)
    offline = replay_rate(run, config)
    latency = np.array(result.latencies[1:]) * 1e3
    errors = result.errors(run)
    figures = {"scans": len(result.t), "sent": result.sent,
               "scans_per_second": result.scans_per_second, "offline_scans_per_second": offline,
               "latency_ms_median": float(np.median(latency)),
               "latency_ms_p95": float(np.percentile(latency, 95)),
               "latency_ms_max": float(latency.max()),
               "ate_rmse_m": float(np.sqrt(np.mean(errors**2))),
               "shutdown_seconds": result.shutdown_seconds}
    where = "in its own process" if args.separate else "in the client's process"
    print(f"ROS 2 node {where}, simulated office ({args.duration:.0f} s, {result.sent} scans "
          f"sent, {len(result.t)} poses back)")
    print(f"  through the node : {figures['scans_per_second']:7.0f} scans/s "
          f"(offline replay of the same run: {offline:.0f} scans/s; "
          f"{figures['scans_per_second'] / offline:.2f}×)")
    print(f"  latency          : median {figures['latency_ms_median']:.2f} ms, "
          f"95 % {figures['latency_ms_p95']:.2f} ms, max {figures['latency_ms_max']:.1f} ms "
          "(scan published → pose received)")
    print(f"  ATE              : {figures['ate_rmse_m'] * 100:.2f} cm RMSE; shutdown "
          f"{figures['shutdown_seconds']:.2f} s")
    return figures


if __name__ == "__main__":
    main()

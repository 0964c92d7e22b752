"""The ``houghloc`` command line's parser: every command, option and help text (the commands
themselves: :mod:`fusion.cli`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

MAX_SIM_SECONDS = 1.0e6
"""s: eleven days of simulated driving; a longer simulation is a typo."""


def _duration(text: str) -> float:
    """An argparse type: a finite, positive number of seconds, at most MAX_SIM_SECONDS."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and 0 < value <= MAX_SIM_SECONDS):
        raise argparse.ArgumentTypeError(
            f"{text} s: a duration must be finite, positive and at most {MAX_SIM_SECONDS:g} s")
    return value



def build_parser(version: str) -> argparse.ArgumentParser:
    """Every command and option, with its help; ``handler`` names the command to run."""
    parser = argparse.ArgumentParser(
        prog="houghloc",
        description="Mobile-robot self-localization by the Hough transform, fused with wheel "
                    "odometry in an EKF.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("--version", action="version", version=f"houghloc {version}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser("demo", help="simulate the paper's RoboCup scenario and localize it",
                          description="Simulate the paper's RoboCup field (a laser robot among "
                          "three moving robots), localize it, write runs/demo/ and print "
                          "odometry-only vs fused accuracy.")
    demo.add_argument("--out", type=Path, default=Path("runs/demo"))
    demo.add_argument("--duration", type=_duration, default=300.0,
                      help="seconds (default 300)")
    demo.add_argument("--seed", type=int, default=0)
    _recording_options(demo)
    demo.set_defaults(handler="demo")

    run = sub.add_parser("run", help="localize a log",
                         description="Localize a log (CARMEN .log/.gz, Intel .mat, ROS bag, or a "
                         "`houghloc sim` directory). Writes DIR/trajectory.tum (one TUM line per "
                         "scan), DIR/metrics.json and DIR/run.rrd.")
    run.add_argument("--map", required=True, type=Path,
                     help="segment map YAML, or a packaged map's name (e.g. office)")
    run.add_argument("--log", required=True, type=Path, help="the log to replay")
    run.add_argument("--out", required=True, type=Path, help="output directory")
    run.add_argument("--config", type=Path,
                     help="localizer YAML, a packaged config's name (e.g. intel-laser), or an "
                          "earlier run's metrics.json (default: 2D laser + odometry)")
    run.add_argument("--initial-pose", nargs=3, type=float, metavar=("X", "Y", "THETA"),
                     help="the pose at the log's first scan, in the map (m, m, rad; odometry "
                     "before that scan is skipped); default: the config's initial_pose, else "
                     "global localization")
    run.add_argument("--scan-topic", metavar="TOPIC",
                     help="ROS bags: the LaserScan topic (default /scan, else the only one)")
    run.add_argument("--odom-topic", metavar="TOPIC",
                     help="ROS bags: the Odometry topic (default /odom, else the only one)")
    run.add_argument("--gt", type=Path, help="ground truth for errors in metrics.json: a TUM "
                     "trajectory, or a corrected CARMEN log (the poses its scans carry)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--strict", action="store_true",
                     help="exit with status 3 when the run ends lost or most scans were not "
                          "localized (tracking)")
    _recording_options(run)
    run.set_defaults(handler="run")

    sim = sub.add_parser("sim", help="generate a simulated scenario",
                         description="Simulate a scenario and write log.carmen, gt.tum, map.yaml, "
                         "scenario.yaml (and camera.points for camera scenarios).")
    sim.add_argument("--scenario", default="robocup-laser",
                     help="preset name (robocup-laser, robocup-camera, office-laser, "
                          "building: a floor plan and a faulty robot drawn from --seed) or a "
                          "scenario YAML")
    sim.add_argument("--out", required=True, type=Path)
    sim.add_argument("--seed", type=int, default=0,
                     help="the random draw (for building, the building itself too)")
    sim.add_argument("--duration", type=_duration, help="seconds (default: the preset's)")
    sim.set_defaults(handler="sim")

    ev = sub.add_parser("eval", help="score a trajectory",
                        description="ATE (RMSE and max, position and heading) and the lost "
                        "fraction (> 0.3 m or > 5°) against ground truth; relation errors "
                        "(Kümmerle et al. 2009) against a relations file.")
    ev.add_argument("--est", required=True, type=Path, help="estimated trajectory (TUM)")
    ev.add_argument("--gt", type=Path, help="ground truth or reference poses: a TUM trajectory, "
                    "or a corrected CARMEN log (the poses its scans carry)")
    ev.add_argument("--relations", type=Path, help="relations file: t1 t2 dx dy dz r p yaw")
    ev.add_argument("--time-offset", type=float, default=0.0,
                    help="seconds subtracted from the relations' timestamps")
    ev.add_argument("--align", action="store_true",
                    help="SE(2)-align the estimate first (for paths in their own frame)")
    ev.add_argument("--max-dt", type=float, default=0.02, help="association tolerance (s)")
    ev.set_defaults(handler="eval")

    sw = sub.add_parser(
        "sweep", help="benchmark runs × settings × methods × protocols on Dask",
        description="Run every (run, setting, method, protocol) of a spec as one Dask task and "
        "write DIR/results.csv (a row per task, appended as each finishes), DIR/summary.md, "
        "DIR/summary.png and DIR/trajectories/. A re-run with the same DIR skips the tasks "
        "already there. Methods: houghloc, odometry, icp, amcl, amcl-tuned (the peers need "
        "pip install 'houghloc[peers]'), mrpt (Debian mrpt-apps). Protocols: same-run, "
        "held-out-map, global-start.")
    sw.add_argument("--spec", required=True, type=Path, help="the sweep spec (YAML)")
    sw.add_argument("--out", required=True, type=Path, help="output directory")
    sw.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="an existing Dask scheduler (default: a LocalCluster on this machine)")
    sw.add_argument("--workers", type=int, metavar="N",
                    help="LocalCluster worker processes (default: one per core)")
    sw.add_argument("--retry-errors", action="store_true",
                    help="run again the tasks whose earlier row is an error")
    sw.add_argument("--no-progress", action="store_true", help="no progress bar")
    sw.set_defaults(handler="sweep")

    ros2 = sub.add_parser(
        "ros2", help="run the ROS 2 node, a drop-in for nav2's AMCL (pip install "
        "'houghloc[ros2]')",
        description="Localize on a robot, in place of nav2's AMCL: a lifecycle node that takes "
        "scan, odom, initialpose, /tf_static and the map topic (map_server's OccupancyGrid) "
        "and publishes amcl_pose, map -> odom on /tf, particle_cloud (PoseArray), "
        "houghloc/localized, houghloc/state and /diagnostics; services "
        "reinitialize_global_localization and request_nomotion_update. ROS arguments follow "
        "--ros-args, e.g. --ros-args --params-file nav2_params.yaml -r __node:=amcl: AMCL's "
        "parameters by AMCL's names (base_frame_id, odom_frame_id, global_frame_id, scan_topic, "
        "map_topic, set_initial_pose, initial_pose.{x,y,yaw}, always_reset_initial_pose, "
        "first_map_only, transform_tolerance, tf_broadcast, initialize_at_saved_pose, "
        "saved_pose_filepath), houghloc's under houghloc.* (docs/ros2.md).")
    ros2.add_argument("--map", type=Path,
                      help="segment map YAML, or a packaged map's name (default: houghloc.map, "
                           "else built from the map topic)")
    ros2.add_argument("--config", type=Path,
                      help="localizer YAML or a packaged config's name (default: "
                           "houghloc.config, else the defaults)")
    ros2.add_argument("--initial-pose", nargs=3, type=float, metavar=("X", "Y", "THETA"),
                      help="start here (default: the config's initial_pose, else the saved "
                           "pose, else global localization until /initialpose)")
    ros2.add_argument("--managed", action="store_true",
                      help="wait for a lifecycle manager (nav2's) to configure and activate "
                           "the node (default: configure and activate at once)")
    ros2.add_argument("--rrd", type=Path, help="also record the run to this Rerun file")
    ros2.add_argument("--serve", action="store_true",
                      help="also serve the Rerun web viewer on localhost")
    ros2.set_defaults(handler="ros2")

    cf = sub.add_parser(
        "config", help="print the settings: defaults, a file's, or the reference",
        description="Print a localizer configuration as YAML, each setting under its meaning: "
        "the defaults, or a file overlaid on them (what a run would use). --reference prints "
        "the parameter reference (Markdown, docs/parameters.md).")
    shown = cf.add_mutually_exclusive_group(required=True)
    shown.add_argument("--defaults", action="store_true", help="the default configuration")
    shown.add_argument("--show", type=Path, metavar="CFG",
                       help="a config file, packaged name or metrics.json, with the defaults")
    shown.add_argument("--reference", action="store_true",
                       help="every setting's default and meaning, as Markdown")
    cf.set_defaults(handler="config")

    mp = sub.add_parser("map", help="segment maps").add_subparsers(dest="map_command",
                                                                   required=True)
    build = mp.add_parser("build", help="build a segment map from a corrected log or a grid",
                          description="Scans at the corrected poses (or a ROS map_server grid) → "
                          "occupancy grid → segments → map YAML, with a PNG of the segments "
                          "over the grid beside it.")
    src = build.add_mutually_exclusive_group(required=True)
    src.add_argument("--log", type=Path, help="corrected CARMEN log")
    src.add_argument("--grid", type=Path, help="ROS map_server YAML (with its PGM)")
    build.add_argument("--out", required=True, type=Path, help="map YAML to write")
    build.add_argument("--resolution", type=float, default=0.05, help="grid cell (m)")
    build.add_argument("--min-length", type=float, default=0.5, help="shortest segment (m)")
    build.set_defaults(handler="map_build")
    return parser


def _recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-rerun", action="store_true", help="do not record run.rrd")
    p.add_argument("--serve", action="store_true",
                   help="also serve the Rerun web viewer on localhost")


# ------------------------------------------------------------------------------------- commands

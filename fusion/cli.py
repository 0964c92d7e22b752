"""The ``houghloc`` command line. It parses, calls the library, prints; the work lives elsewhere.

    houghloc demo                      the paper's RoboCup scenario, simulated and localized
    houghloc run --map M --log L --out D [--config C] [--initial-pose X Y THETA] [--gt GT.tum]
    houghloc sim --scenario NAME --out D [--seed S] [--duration SEC]
    houghloc eval --est EST.tum --gt GT.tum [--relations FILE --time-offset S]
    houghloc map build (--log CORRECTED_LOG | --grid ROS_MAP.yaml) --out MAP.yaml
    houghloc sweep --spec SPEC.yaml --out DIR [--scheduler tcp://HOST:PORT] [--workers N]
    houghloc ros2 --map M [--config C] [--initial-pose X Y THETA] [--ros-args ...]
    houghloc config (--defaults | --show CFG | --reference)
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from fusion.visualize import NullLogger

EXIT_BAD_INPUT = 2
EXIT_NOT_LOCALIZED = 3


class CliError(Exception):
    """A problem the user can fix; printed without a traceback."""


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


class _Stop:
    """The signal that interrupted the command: SIGTERM (what kill, timeout, systemd and CI
    send) is handled as Ctrl-C is, and the exit status says which (128 + its number)."""

    signal = signal.SIGINT

    @classmethod
    def on_terminate(cls, signum: int, _frame: object) -> None:
        cls.signal = signal.Signals(signum)
        raise KeyboardInterrupt

    @classmethod
    def exit_code(cls) -> int:
        return 128 + int(cls.signal)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:  # ROS's own arguments (remappings, parameters) go to rclpy
        argv, ros_args = argv[:argv.index("--ros-args")], argv[argv.index("--ros-args"):]
    args = parser.parse_args(argv)
    if ros_args and args.command != "ros2":
        parser.error("--ros-args is for `houghloc ros2`")
    args.ros_args = ros_args
    logging.basicConfig(level=logging.WARNING, format="houghloc: warning: %(message)s")
    logging.captureWarnings(True)
    warnings.simplefilter("default")
    # other packages' deprecations are theirs to fix, not the user's to read
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    warnings.filterwarnings("default", category=DeprecationWarning, module=r"(fusion|houghloc)\b")
    _Stop.signal = signal.SIGINT
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _Stop.on_terminate)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"houghloc: interrupted ({_Stop.signal.name})", file=sys.stderr)
        return _Stop.exit_code()
    except BrokenPipeError:  # `houghloc config --defaults | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + int(signal.SIGPIPE)
    except Exception as exc:  # every failure is a message, not a traceback
        if getattr(args, "debug", False):
            raise
        print(f"houghloc: error: {_describe(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("houghloc")
    except PackageNotFoundError:
        return "0+unknown"


def _describe(exc: Exception) -> str:
    from fusion.bench.spec import SpecError
    from fusion.config import ConfigError
    from fusion.io.errors import LogError
    from houghloc.segment_map import MapError

    if isinstance(exc, MapError | ConfigError | LogError | CliError | SpecError | ValueError):
        return str(exc)
    if isinstance(exc, FileNotFoundError | PermissionError | IsADirectoryError):
        return f"{exc.strerror}: {exc.filename}"
    return f"{type(exc).__name__}: {exc} (run with --debug for the traceback)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="houghloc",
        description="Mobile-robot self-localization by the Hough transform, fused with wheel "
                    "odometry in an EKF.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("--version", action="version", version=f"houghloc {_version()}")
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
    demo.set_defaults(func=cmd_demo)

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
    run.add_argument("--gt", type=Path, help="ground truth (TUM) for errors in metrics.json")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--strict", action="store_true",
                     help="exit with status 3 when the run ends lost or most scans were not "
                          "localized (tracking)")
    _recording_options(run)
    run.set_defaults(func=cmd_run)

    sim = sub.add_parser("sim", help="generate a simulated scenario",
                         description="Simulate a scenario and write log.carmen, gt.tum, map.yaml, "
                         "scenario.yaml (and camera.points for camera scenarios).")
    sim.add_argument("--scenario", default="robocup-laser",
                     help="preset name (robocup-laser, robocup-camera, office-laser) or a "
                          "scenario YAML")
    sim.add_argument("--out", required=True, type=Path)
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--duration", type=_duration, help="seconds (default: the preset's)")
    sim.set_defaults(func=cmd_sim)

    ev = sub.add_parser("eval", help="score a trajectory",
                        description="ATE (RMSE and max, position and heading) and the lost "
                        "fraction (> 0.3 m or > 5°) against ground truth; relation errors "
                        "(Kümmerle et al. 2009) against a relations file.")
    ev.add_argument("--est", required=True, type=Path, help="estimated trajectory (TUM)")
    ev.add_argument("--gt", type=Path, help="ground truth or reference poses (TUM)")
    ev.add_argument("--relations", type=Path, help="relations file: t1 t2 dx dy dz r p yaw")
    ev.add_argument("--time-offset", type=float, default=0.0,
                    help="seconds subtracted from the relations' timestamps")
    ev.add_argument("--align", action="store_true",
                    help="SE(2)-align the estimate first (for paths in their own frame)")
    ev.add_argument("--max-dt", type=float, default=0.02, help="association tolerance (s)")
    ev.set_defaults(func=cmd_eval)

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
    sw.set_defaults(func=cmd_sweep)

    ros2 = sub.add_parser(
        "ros2", help="run the ROS 2 node (pip install 'houghloc[ros2]')",
        description="Localize on a robot: subscribe scan, odom, initialpose and /tf_static; "
        "publish houghloc/pose (PoseWithCovarianceStamped, as amcl_pose), map -> odom on /tf and "
        "houghloc/state. ROS arguments follow --ros-args, e.g. --ros-args -r scan:=/base_scan "
        "-p base_frame:=base_link (parameters: map_frame, odom_frame, base_frame, scan_topic, "
        "odom_topic, publish_tf, transform_tolerance, odom_wait).")
    ros2.add_argument("--map", required=True, type=Path,
                      help="segment map YAML, or a packaged map's name")
    ros2.add_argument("--config", type=Path,
                      help="localizer YAML or a packaged config's name (default: the defaults)")
    ros2.add_argument("--initial-pose", nargs=3, type=float, metavar=("X", "Y", "THETA"),
                      help="start here (default: the config's initial_pose, else global "
                           "localization until /initialpose)")
    ros2.add_argument("--rrd", type=Path, help="also record the run to this Rerun file")
    ros2.add_argument("--serve", action="store_true",
                      help="also serve the Rerun web viewer on localhost")
    ros2.set_defaults(func=cmd_ros2)

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
    cf.set_defaults(func=cmd_config)

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
    build.set_defaults(func=cmd_map_build)
    return parser


def _recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-rerun", action="store_true", help="do not record run.rrd")
    p.add_argument("--serve", action="store_true",
                   help="also serve the Rerun web viewer on localhost")


# ------------------------------------------------------------------------------------- commands
def cmd_run(args: argparse.Namespace) -> int:
    from fusion.config import LocalizerConfig
    from fusion.evaluation import Trajectory
    from fusion.run_log import open_source, run_log
    from houghloc import SegmentMap

    config = LocalizerConfig.from_yaml(
        None if args.config is None else _packaged(args.config, "config"))
    segment_map = SegmentMap.from_yaml(_packaged(args.map, "map"))
    source = open_source(args.log, config, args.scan_topic, args.odom_topic)
    if source.origin is not None:
        print(source.origin)
    gt_path = args.gt or source.ground_truth
    logger = _make_logger(args, args.out / "run.rrd")
    run = run_log(source, segment_map, initial_pose=_initial_pose(args, source.config),
                  reference=Trajectory.from_tum(gt_path) if gt_path else None, out=args.out,
                  logger=logger, progress=False if args.no_progress else None,
                  description=args.log.name,
                  metrics_extra={"map": str(args.map), "log_path": str(args.log),
                                 "ground_truth": str(gt_path) if gt_path else None})
    result, loc, doc = run.result, run.localizer, run.metrics
    summary, warned = run_summary(result, loc)
    print(summary)
    for text in warned:
        print(f"houghloc: warning: {text}", file=sys.stderr)
    for kind, info in (run.read_stats.by_kind().items() if run.read_stats is not None else ()):
        print(f"houghloc: warning: {args.log}: {info['count']} × {kind} (first: "
              f"{info['first']})", file=sys.stderr)
    if "ate" in doc:
        _print_accuracy_rows([("houghloc", doc)])
    print(f"wrote {args.out / 'trajectory.tum'}, {args.out / 'metrics.json'}"
          + ("" if args.no_rerun else f", {args.out / 'run.rrd'}"))
    if not result.interrupted:  # the results first, then the viewer as long as it is wanted
        _serve_until_interrupted(args, logger)
    logger.close()
    if result.interrupted:
        return _Stop.exit_code()
    if args.strict and not loc.localized:
        print("houghloc: --strict: the run was not localized (see above)", file=sys.stderr)
        return EXIT_NOT_LOCALIZED
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from fusion.config import LocalizerConfig
    from fusion.evaluation import Trajectory
    from fusion.replay import accuracy, write_metrics
    from fusion.resources import find_config
    from fusion.run_log import run_log
    from fusion.sim import scenario_preset, simulate, write_run

    print(f"Simulating the RoboCup field: {args.duration:.0f} s, a laser robot among three "
          f"moving robots (seed {args.seed}) ...")
    sim = simulate(scenario_preset("robocup-laser", seed=args.seed, duration=args.duration))
    args.out.mkdir(parents=True, exist_ok=True)
    write_run(sim, args.out / "sim")
    truth = Trajectory(sim.truth_t, sim.truth)
    logger = _make_logger(args, args.out / "run.rrd")
    config = LocalizerConfig.from_yaml(find_config("robocup-laser"))
    run = run_log(sim.events(), sim.map, config, initial_pose=sim.odom_truth[0],  # kick-off
                  reference=truth, out=args.out, logger=logger,
                  metrics_extra={"scenario": "robocup-laser", "seed": args.seed})
    result, fused = run.result, run.metrics
    odometry_only = Trajectory(sim.odom_t, sim.odom_in_map())
    dead_reckoning = accuracy(_resampled(odometry_only, result.t), truth)
    write_metrics(args.out / "metrics.json", {**fused, "odometry_only": dead_reckoning})
    print()
    _print_accuracy_rows([("odometry only", dead_reckoning), ("houghloc (fused)", fused)])
    print(f"\n{len(result.t)} scans, {result.scans_per_second:.0f} scans/s; "
          f"outputs in {args.out}/ (trajectory.tum, metrics.json"
          + ("" if args.no_rerun else ", run.rrd — open it with `rerun "
             f"{args.out / 'run.rrd'}`") + ")")
    if not result.interrupted:
        _serve_until_interrupted(args, logger)
    logger.close()
    return _Stop.exit_code() if result.interrupted else 0


def cmd_sim(args: argparse.Namespace) -> int:
    from fusion.sim import load_scenario, scenario_preset, simulate, write_run

    path = Path(args.scenario)
    if path.suffix in (".yaml", ".yml"):
        cfg = load_scenario(path)
        cfg = cfg.model_copy(update={"seed": args.seed} | (
            {"duration": args.duration} if args.duration else {}))
    else:
        cfg = scenario_preset(args.scenario, seed=args.seed, duration=args.duration)
    run = simulate(cfg)
    paths = write_run(run, args.out)
    print(f"simulated {cfg.name}: {len(run.scan_t)} scans, {len(run.cam_t)} camera frames, "
          f"{len(run.odom_t)} odometry readings over {cfg.duration:.0f} s")
    for name, p in paths.items():
        print(f"  {name:10s} {p}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from fusion.evaluation import ATE, Alignment, LostFraction, RelationError, Trajectory
    from fusion.io.relations import read_relations

    if args.gt is None and args.relations is None:
        raise CliError("give --gt (ground truth) and/or --relations")
    est = Trajectory.from_tum(args.est)
    if args.gt is not None:
        ref = Trajectory.from_tum(args.gt)
        align = Alignment.SE2 if args.align else Alignment.NONE
        ate = ATE(alignment=align, max_dt=args.max_dt).compute(est, ref)
        if len(ate.position_errors) == 0:
            raise CliError(f"no pose of {args.est} is within {args.max_dt} s of one in {args.gt}")
        lost = LostFraction(max_dt=args.max_dt).compute(est, ref)
        p, h = ate.position, ate.heading_deg
        print(f"matched {len(ate.position_errors)} of {len(est)} poses"
              + (" (SE(2)-aligned)" if args.align else ""))
        print(f"ATE position  RMSE {p['rmse'] * 100:8.2f} cm   max {p['max'] * 100:8.2f} cm")
        print(f"ATE heading   RMSE {h['rmse']:8.3f} deg  max {h['max']:8.3f} deg")
        print(f"lost (> 0.3 m or > 5°): {lost.fraction * 100:.2f} % ({lost.count} poses)")
    if args.relations is not None:
        rel = RelationError(max_dt=args.max_dt).compute(
            est, read_relations(args.relations, args.time_offset))
        d = rel.as_dict()
        print(f"relations: {d.get('count')} used, {d.get('missing')} without a pose")
        print(f"  translational  mean {d.get('translation_mean_m', float('nan')):.4f} m   "
              f"std {d.get('translation_std_m', float('nan')):.4f} m")
        mean, std = (math.radians(d.get(k, float("nan"))) for k in
                     ("rotation_mean_deg", "rotation_std_deg"))
        print(f"  rotational     mean {mean:.4f} rad   std {std:.4f} rad")
    return 0


def run_summary(result: Any, loc: Any) -> tuple[str, list[str]]:
    """What became of the scans, in words (how many, how fast, by status), and the warnings
    when the run did not end localized."""
    statuses = ", ".join(f"{k} {v}" for k, v in sorted(loc.stats.statuses.items(),
                                                        key=lambda kv: -kv[1]))
    text = (f"{result.scans} scans in {result.seconds['total']:.1f} s "
            f"({result.scans_per_second:.0f} scans/s); by status: {statuses or 'none'}")
    warned = []
    if loc.manager.state.value != "tracking":
        warned.append(f"the run ended {loc.manager.state.value}: not localized at the end")
    if loc.stats.tracked_fraction < 0.5 and result.scans:
        warned.append(f"only {100 * loc.stats.tracked_fraction:.0f} % of the scans were "
                      "localized (tracking)")
    return text, warned


def cmd_sweep(args: argparse.Namespace) -> int:
    from fusion.bench import load_spec, run_sweep

    if args.workers is not None and args.workers < 1:
        raise CliError("--workers must be at least 1")
    spec = load_spec(args.spec)
    outcome = run_sweep(spec, args.out, scheduler=args.scheduler, workers=args.workers,
                        progress=False if args.no_progress else None,
                        retry_errors=args.retry_errors)
    print(f"{outcome.ran} tasks run, {outcome.skipped} already in {args.out}, "
          f"{outcome.failed} failed; wrote {args.out / 'results.csv'}, "
          f"{args.out / 'summary.md'}, {args.out / 'summary.png'}")
    return 0


def cmd_ros2(args: argparse.Namespace) -> int:
    from fusion.config import LocalizerConfig
    from houghloc import SegmentMap

    try:
        from fusion.ros2.node import run_node
    except ImportError as exc:
        raise CliError(f"the ROS 2 node needs the ros2 extra: pip install 'houghloc[ros2]' "
                       f"({exc})") from None
    config = LocalizerConfig.from_yaml(
        None if args.config is None else _packaged(args.config, "config"))
    segment_map = SegmentMap.from_yaml(_packaged(args.map, "map"))
    initial_pose = _initial_pose(args, config)
    logger: Any = NullLogger()
    if args.rrd is not None or args.serve:
        from fusion.rerun_logger import RerunLogger

        logger = RerunLogger(args.rrd, serve=args.serve)
    try:
        return run_node(segment_map, config, initial_pose, logger, args.ros_args)
    finally:
        logger.close()


def cmd_config(args: argparse.Namespace) -> int:
    from fusion.config import LocalizerConfig
    from fusion.config_reference import commented_yaml, reference_markdown

    if args.reference:
        print(reference_markdown(), end="")
    else:
        config = LocalizerConfig.from_yaml(args.show)  # None: the defaults
        print(f"# houghloc {_version()}: {'the defaults' if args.show is None else args.show}")
        print(commented_yaml(config))
    return 0


def cmd_map_build(args: argparse.Namespace) -> int:
    try:
        from fusion.mapping import build_map
    except ImportError as exc:
        raise CliError(f"the map builder is not available ({exc})") from None
    source = args.log or args.grid
    m = build_map(source, args.out, resolution=args.resolution, min_length=args.min_length)
    print(f"{len(m)} segments ({m.n_lines} lines) → {args.out} and {args.out.with_suffix('.png')}")
    return 0


# -------------------------------------------------------------------------------------- helpers
def _packaged(path: Path, kind: str) -> Path:
    """A --map or --config as a file: the path given, or the packaged one of that name; a
    CliError that lists the packaged ones when neither exists."""
    from fusion.resources import configs_dir, find, maps_dir, packaged_names

    directory = maps_dir() if kind == "map" else configs_dir()
    found = find(path, directory)
    if not found.exists():
        raise CliError(f"{kind} {path}: file not found (packaged {kind}s: "
                       f"{', '.join(packaged_names(directory))})")
    return found


def _initial_pose(args: argparse.Namespace, config: Any) -> np.ndarray | None:
    """--initial-pose, else the config's ``initial_pose``, else None (global localization)."""
    pose = args.initial_pose if args.initial_pose is not None else config.initial_pose
    if pose is None:
        return None
    if not all(math.isfinite(v) for v in pose):
        raise CliError("--initial-pose must be three finite numbers")
    return np.asarray(pose, dtype=float)


def _make_logger(args: argparse.Namespace, path: Path):
    if args.no_rerun and not args.serve:
        return NullLogger()
    try:
        from fusion.rerun_logger import RerunLogger
    except ImportError:
        return NullLogger()
    return RerunLogger(None if args.no_rerun else path, serve=args.serve)


def _serve_until_interrupted(args: argparse.Namespace, logger: Any) -> None:
    """With --serve the viewer lives as long as the logger: keep it up until Ctrl-C."""
    if not getattr(args, "serve", False) or not hasattr(logger, "web_url"):
        return
    logger.flush()
    print(f"Rerun web viewer on {logger.web_url} (localhost only) — Ctrl-C to stop")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print()


def _resampled(traj, t: np.ndarray):
    """A trajectory sampled at times t (nearest earlier sample), for like-for-like errors."""
    from fusion.evaluation import Trajectory

    idx = np.clip(np.searchsorted(traj.t, t, side="right") - 1, 0, len(traj.t) - 1)
    return Trajectory(t, traj.poses[idx])


def _print_accuracy_rows(rows: list[tuple[str, dict]]) -> None:
    header = (f"{'':18s} {'ATE RMSE':>10s} {'ATE max':>10s} {'heading RMSE':>13s} "
              f"{'heading max':>12s} {'lost':>7s}")
    print(header)
    print("-" * len(header))
    for name, doc in rows:
        ate, lost = doc.get("ate", {}), doc.get("lost", {})
        print(f"{name:18s} {_cm(ate.get('position_rmse_m'))} {_cm(ate.get('position_max_m'))} "
              f"{_deg(ate.get('heading_rmse_deg'), 13)} {_deg(ate.get('heading_max_deg'), 12)} "
              f"{(lost.get('lost_fraction') or 0) * 100:6.1f}%")


def _cm(v: float | None) -> str:
    if v is None:
        return f"{'–':>10s}"
    return f"{v * 100:7.2f} cm" if v < 1.0 else f"{v:8.2f} m"


def _deg(v: float | None, width: int) -> str:
    return f"{'–':>{width}s}" if v is None else f"{v:{width - 4}.3f} deg"


if __name__ == "__main__":
    sys.exit(main())

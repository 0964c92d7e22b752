"""The ``houghloc`` command line. It parses, calls the library, prints; the work lives elsewhere.

    houghloc demo                      the paper's RoboCup scenario, simulated and localized
    houghloc run --map M --log L --out D [--config C] [--initial-pose X Y THETA] [--gt GT]
    houghloc sim --scenario NAME --out D [--seed S] [--duration SEC]
    houghloc eval --est EST.tum --gt GT [--relations FILE --time-offset S]
    houghloc map build (--log CORRECTED_LOG | --grid ROS_MAP.yaml) --out MAP.yaml
    houghloc sweep --spec SPEC.yaml --out DIR [--scheduler tcp://HOST:PORT] [--workers N]
    houghloc ros2 [--map M] [--config C] [--initial-pose X Y THETA] [--managed] [--ros-args ...]
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

from fusion.cli_parser import build_parser
from fusion.visualize import NullLogger
from houghloc import __version__

EXIT_BAD_INPUT = 2
EXIT_NOT_LOCALIZED = 3


class CliError(Exception):
    """A problem the user can fix; printed without a traceback."""


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
    parser = build_parser(__version__)
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
        return int(HANDLERS[args.handler](args) or 0)
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
                  reference=Trajectory.from_reference(gt_path) if gt_path else None, out=args.out,
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
        ref = Trajectory.from_reference(args.gt)
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
        from fusion.ros2.run import run_node
    except ImportError as exc:
        raise CliError(f"the ROS 2 node needs the ros2 extra: pip install 'houghloc[ros2]' "
                       f"({exc})") from None
    config = None if args.config is None else \
        LocalizerConfig.from_yaml(_packaged(args.config, "config"))
    segment_map = None if args.map is None else SegmentMap.from_yaml(_packaged(args.map, "map"))
    initial_pose = _initial_pose(args, config or LocalizerConfig())
    logger: Any = NullLogger()
    if args.rrd is not None or args.serve:
        from fusion.rerun_logger import RerunLogger

        logger = RerunLogger(args.rrd, serve=args.serve)
    try:
        return run_node(segment_map, config, initial_pose, logger, args.ros_args, args.managed)
    finally:
        logger.close()


def cmd_config(args: argparse.Namespace) -> int:
    from fusion.config import LocalizerConfig
    from fusion.config_reference import commented_yaml, reference_markdown

    if args.reference:
        print(reference_markdown(), end="")
    else:
        config = LocalizerConfig.from_yaml(args.show)  # None: the defaults
        print(f"# houghloc {__version__}: {'the defaults' if args.show is None else args.show}")
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



# the parser's ``handler`` of each command → the function that runs it
HANDLERS = {"demo": cmd_demo, "run": cmd_run, "sim": cmd_sim, "eval": cmd_eval, "sweep": cmd_sweep,
            "ros2": cmd_ros2, "config": cmd_config, "map_build": cmd_map_build}


if __name__ == "__main__":
    sys.exit(main())

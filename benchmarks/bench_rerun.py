"""Replay speed with the Rerun recording on and off (the same log, the same run).

Targets: with recording on, at least 30 % of the scans per second without it on the simulated
office, and at least 1000 scans/s on the Intel lab's log (no scan odometry; skipped when the
real data is not beside the repository). The recording batches its time series and its Hough
images (``send_columns``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from fusion import Localizer, LocalizerConfig
from fusion.replay import replay
from fusion.rerun_logger import RerunLogger
from fusion.sim import scenario_preset, simulate

CONFIG = Path(__file__).resolve().parents[1] / "fusion" / "configs" / "office-laser.yaml"


def replay_rate(run, events, logger=None) -> float:
    loc = Localizer(run.map, LocalizerConfig.from_yaml(CONFIG), run.odom_truth[0], logger)
    started = time.perf_counter()
    result = replay(events, loc, progress=False)
    if logger is not None:
        logger.close()  # the footer of the .rrd is part of the cost
    return len(result.t) / (time.perf_counter() - started)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--intel-scans", type=int, default=None,
                        help="replay only the first N scans of the Intel log (default: all)")
    args = parser.parse_args(argv)
    run = simulate(scenario_preset("office-laser", seed=1, duration=args.duration))
    events = list(run.events())
    rates: dict[str, list[float]] = {"off": [], "on": [], "on, image every 10": []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.rounds):  # alternate, so both see the same machine load
            rates["off"].append(replay_rate(run, events))
            rates["on"].append(replay_rate(run, events, RerunLogger(Path(tmp) / f"a{k}.rrd")))
            rates["on, image every 10"].append(replay_rate(
                run, events, RerunLogger(Path(tmp) / f"b{k}.rrd", accumulator_every=10)))
        size = (Path(tmp) / "a0.rrd").stat().st_size / 1e6
    best = {k: max(v) for k, v in rates.items()}
    print(f"office-laser, {args.duration:.0f} s simulated, {len(run.scan_t)} scans "
          f"(best of {args.rounds} alternating rounds)")
    for name, rate in best.items():
        print(f"   Rerun {name:20s} {rate:7.0f} scans/s   {rate / best['off'] * 100:5.1f} % of off")
    print(f"   recording size {size:.1f} MB  (target: on ≥ 30 % of off)")
    results = {"ratio_on_off": best["on"] / best["off"],
               **{f"rate_{k}": v for k, v in best.items()}}
    results.update(intel_rates(args.rounds, args.intel_scans))
    return results


def intel_rates(rounds: int, scans: int | None = None) -> dict:
    """The Intel lab's log (its first ``scans``; all 5505 by default) replayed with the
    recording off and on."""
    from benchmarks.bench_real import datasets, overridden_config
    from fusion.io import from_first_scan, open_log
    from houghloc import SegmentMap

    intel = next(d for d in datasets() if d.name == "intel")
    if not intel.log.exists():
        print(f"   Intel: skipped, {intel.log} is not present")
        return {}
    config = overridden_config(intel.config, ["scan_odometry.enabled=false"])
    segment_map = SegmentMap.from_yaml(intel.map)
    events = list(from_first_scan(open_log(intel.log)[0], scans))
    rates: dict[str, list[float]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(rounds):
            for name in rates:
                logger = RerunLogger(Path(tmp) / f"intel{k}.rrd") if name == "on" else None
                loc = Localizer(segment_map, config, intel.initial_pose, logger)
                started = time.perf_counter()
                result = replay(iter(events), loc, progress=False)
                if logger is not None:
                    logger.close()
                rates[name].append(len(result.t) / (time.perf_counter() - started))
    best = {k: max(v) for k, v in rates.items()}
    print(f"Intel lab, {len(result.t)} scans, no scan odometry (best of {rounds}): recording off "
          f"{best['off']:.0f} scans/s, on {best['on']:.0f} scans/s (target on ≥ 1000)")
    return {"intel_rate_off": best["off"], "intel_rate_on": best["on"]}


if __name__ == "__main__":
    main()

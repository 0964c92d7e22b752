"""Replay speed with the Rerun recording on and off (the same log, the same run).

Target: with recording on, at least 30 % of the scans per second without it. The recording
batches its time series (``send_columns``) and logs the Hough image every few scans.
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

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "office-laser.yaml"


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
    return {"ratio_on_off": best["on"] / best["off"], **{f"rate_{k}": v for k, v in best.items()}}


if __name__ == "__main__":
    main()

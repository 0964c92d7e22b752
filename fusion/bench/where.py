"""Where a sweep of generated buildings lost its poses: each lost pose is put in the part of the
building, or of the run, it was lost in, so that a change can be aimed at the place that loses
most and its effect read place by place (docs/benchmark.md#generated-buildings).

    python -m fusion.bench.where OUT      # OUT: a sweep's output folder

The places, the first that applies: the odometry gap (and one second after it); the recovery
allowance after a kidnap; after a kidnap, lost until the estimate is right for good (not
recovered); then by where the robot truly is: the featureless corridor west of the main one, the
second corridor south of the hall, the hall, the rooms, the main corridor.
"""

from __future__ import annotations

import csv
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.bench.generated import RECOVERY_ALLOWANCE, recovery_times, scenario_config
from fusion.evaluation import Trajectory
from fusion.integrity import LOCALIZED_HEADING_DEG, LOCALIZED_POSITION
from fusion.sim.building import GENERATOR_VERSION, Plan, draw_plan

PLACES = ("odometry gap", "kidnap allowance", "after a kidnap", "featureless corridor",
          "second corridor", "hall", "rooms", "main corridor")
GAP_AFTER = 1.0
"""s after an odometry gap still counted in it (the filter takes the first readings after)."""


def plan_of(seed: int) -> Plan:
    """The floor plan of a seed, drawn as the generator draws it."""
    return draw_plan(np.random.default_rng(np.random.SeedSequence([GENERATOR_VERSION, seed])))


def places(seed: int, t: NDArray[np.float64], truth: NDArray[np.float64],
           lost: NDArray[np.bool_], duration: float | None = None) -> NDArray[np.object_]:
    """The place (one of :data:`PLACES`) of each pose of a run of building ``seed`` at times
    ``t``, whose true poses are ``truth`` (N×3) and of which ``lost`` were lost."""
    plan = plan_of(seed)
    cfg = scenario_config("building", seed, duration)
    x0, x1, y0, y1 = plan.corridor
    hall_south = min(min(a[1], b[1]) for name, a, b in plan.walls if name.startswith("hall"))
    x, y = truth[:, 0], truth[:, 1]
    out = np.full(len(t), "main corridor", dtype=object)
    out[(x >= x0) & (x <= x1) & ((y < y0) | (y > y1))] = "rooms"
    out[x > x1] = "hall"
    out[(x > x1) & (y < hall_south)] = "second corridor"
    out[x < x0] = "featureless corridor"
    for tk in (cfg.start_time + k.t for k in cfg.kidnaps):
        back = tk + recovery_times(t, lost, [tk])[0]
        out[(t >= tk + RECOVERY_ALLOWANCE) & (t < back)] = "after a kidnap"
        out[(t >= tk) & (t < tk + RECOVERY_ALLOWANCE)] = "kidnap allowance"
    for gap in cfg.odometry_gaps:
        start = cfg.start_time + gap.t
        out[(t >= start) & (t < start + gap.duration + GAP_AFTER)] = "odometry gap"
    return out


def lost_poses(estimate: Trajectory, truth: Trajectory) -> tuple[NDArray, NDArray]:
    """The true pose at each estimated one (nearest in time) and which are lost (beyond the
    integrity bounds)."""
    nearest = np.clip(np.searchsorted(truth.t, estimate.t), 0, len(truth.t) - 1)
    earlier = np.clip(nearest - 1, 0, len(truth.t) - 1)
    pick = np.where(np.abs(truth.t[earlier] - estimate.t) < np.abs(truth.t[nearest] - estimate.t),
                    earlier, nearest)
    true = truth.poses[pick]
    off = np.hypot(*(estimate.poses[:, :2] - true[:, :2]).T)
    turned = np.degrees(np.abs((estimate.poses[:, 2] - true[:, 2] + np.pi) % (2 * np.pi) - np.pi))
    return true, (off > LOCALIZED_POSITION) | (turned > LOCALIZED_HEADING_DEG)


def where_lost(out: Path, method: str = "houghloc") -> dict[str, tuple[int, int]]:
    """For a sweep's output folder: per place, the lost poses of ``method`` and on how many
    seeds, over its runs of generated buildings (the simulated runs' truth is read from the
    cache, :func:`fusion.sim.building.map_cache_dir`)."""
    from fusion.bench.generated import simulated
    from fusion.bench.spec import RunSpec

    poses: Counter[str] = Counter()
    seeds: dict[str, set[int]] = {p: set() for p in PLACES}
    with (out / "results.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["method"] == method and r["status"] == "ok"
                and r["run"].startswith("building-")]
    for row in rows:
        seed = int(row["run"].rsplit("-", 1)[1])
        estimate = Trajectory.from_tum(out / "trajectories" / f"{row['task_id']}.tum")
        run = simulated(RunSpec(name=row["run"], scenario="building", seed=seed))
        assert run.reference is not None
        truth, lost = lost_poses(estimate, Trajectory.from_tum(run.reference))
        where = places(seed, estimate.t, truth, lost)
        for place in PLACES:
            n = int(np.sum(lost & (where == place)))
            if n:
                poses[place] += n
                seeds[place].add(seed)
    return {p: (poses[p], len(seeds[p])) for p in PLACES}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or not (Path(args[0]) / "results.csv").is_file():
        print("usage: python -m fusion.bench.where OUT   (OUT: a sweep's output folder, with "
              "results.csv)", file=sys.stderr)
        return 2
    table = where_lost(Path(args[0]))
    print("| where | lost poses | seeds |\n|---|---|---|")
    for place, (n, k) in sorted(table.items(), key=lambda item: -item[1][0]):
        print(f"| {place} | {n} | {k} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

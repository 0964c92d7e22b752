"""Simulated runs in a sweep: a spec's ``scenario`` run is simulated by its task, written once
to a folder of the cache (:func:`fusion.sim.building.map_cache_dir`) and then read like any
``houghloc sim`` directory, so every method is fed the same log.

Scored as the other runs, and, where the scenario kidnaps the robot, by the time to recover
(:func:`recovery_times`) and the lost share outside the recovery allowance.
"""

from __future__ import annotations

import functools
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.bench.spec import RunSpec
from fusion.sim.config import ScenarioConfig

RECOVERY_ALLOWANCE = 5.0
"""s after a kidnap within which a localizer is expected to be right again; the lost share
outside these windows is ``lost_outside_kidnap_frac``."""
RECOVERY_HOLD = 5.0
"""s: recovered means right and staying right for this long (or to the end of the run)."""


@functools.lru_cache(maxsize=8)
def scenario_config(scenario: str, seed: int, duration: float | None) -> ScenarioConfig:
    """The scenario of a run (drawn once per process: a building's kidnap is placed by driving
    its tour)."""
    from fusion.sim import scenario_preset

    return scenario_preset(scenario, seed=seed, duration=duration)


def _config(run: RunSpec) -> ScenarioConfig:
    assert run.scenario is not None
    return scenario_config(run.scenario, run.seed, run.duration)


def simulated(run: RunSpec) -> RunSpec:
    """The run with ``log``, ``map`` and ``reference`` pointing at its simulation, written the
    first time it is asked for (atomically: a folder renamed into place, so two workers never
    read half a run)."""
    from fusion.sim import simulate, write_run
    from fusion.sim.building import GENERATOR_VERSION, map_cache_dir

    cfg = _config(run)
    folder = map_cache_dir() / "runs" / (
        f"{run.scenario}-v{GENERATOR_VERSION}-{run.seed}-{cfg.duration:g}s")
    if not (folder / "gt.tum").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)
        partial = Path(tempfile.mkdtemp(prefix=f".{folder.name}-", dir=folder.parent))
        write_run(simulate(cfg), partial)
        try:
            os.replace(partial, folder)
        except OSError:  # another worker was first: its copy is the same run
            shutil.rmtree(partial, ignore_errors=True)
    return run.model_copy(update={"log": folder, "map": folder / "map.yaml",
                                  "reference": folder / "gt.tum"})


def kidnap_times(run: RunSpec) -> list[float]:
    """When the scenario kidnaps the robot (the log's clock)."""
    cfg = _config(run)
    return [cfg.start_time + k.t for k in cfg.kidnaps]


def recovery_times(t: NDArray[np.float64], lost: NDArray[np.bool_], kidnaps: list[float]
                   ) -> list[float]:
    """For each kidnap, seconds until the estimate is right and stays right for
    :data:`RECOVERY_HOLD` (or to the end of the run); ``inf`` when it never is."""
    order = np.argsort(t)
    t, lost = t[order], np.asarray(lost, dtype=bool)[order]
    # each run of right poses: where it starts, and the time it lasts to (the next lost pose,
    # or past the end)
    right = ~lost
    edges = np.diff(np.concatenate(([0], right.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    until = np.where(ends < len(t), t[np.minimum(ends, len(t) - 1)], math.inf)
    out = []
    for tk in kidnaps:
        # a run counts from its first pose at or after the kidnap
        first = np.maximum(starts, np.searchsorted(t, tk))
        held = (first < ends) & (until - t[np.minimum(first, len(t) - 1)] >= RECOVERY_HOLD)
        out.append(float(t[first[held][0]] - tk) if held.any() else math.inf)
    return out


def outside_allowance(t: NDArray[np.float64], kidnaps: list[float]) -> NDArray[np.bool_]:
    """Which poses are outside every kidnap's recovery allowance."""
    keep = np.ones(len(t), dtype=bool)
    for tk in kidnaps:
        keep &= ~((t >= tk) & (t < tk + RECOVERY_ALLOWANCE))
    return keep

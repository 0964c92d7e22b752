"""Simulated runs in a sweep: a spec's ``scenario`` run is simulated by its task, written once
to a folder of the cache (:func:`fusion.sim.building.map_cache_dir`) and then read like any
``houghloc sim`` directory, so every method is fed the same log.

Scored as the other runs, and, where the scenario kidnaps the robot, by the time to recover
(:func:`recovery_times`) and the lost share outside the recovery allowance.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.bench.spec import RunSpec

RECOVERY_ALLOWANCE = 5.0
"""s after a kidnap within which a localizer is expected to be right again; the lost share
outside these windows is ``lost_outside_kidnap_frac``."""
RECOVERY_HOLD = 5.0
"""s: recovered means right and staying right for this long (or to the end of the run)."""


def scenario_config(run: RunSpec):
    from fusion.sim import scenario_preset

    assert run.scenario is not None
    return scenario_preset(run.scenario, seed=run.seed, duration=run.duration)


def simulated(run: RunSpec) -> RunSpec:
    """The run with ``log``, ``map`` and ``reference`` pointing at its simulation, written the
    first time it is asked for (atomically: a folder renamed into place, so two workers never
    read half a run)."""
    from fusion.sim import simulate, write_run
    from fusion.sim.building import GENERATOR_VERSION, map_cache_dir

    cfg = scenario_config(run)
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
    cfg = scenario_config(run)
    return [cfg.start_time + k.t for k in cfg.kidnaps]


def recovery_times(t: NDArray[np.float64], lost: NDArray[np.bool_], kidnaps: list[float]
                   ) -> list[float]:
    """For each kidnap, seconds until the estimate is right and stays right for
    :data:`RECOVERY_HOLD` (or to the end of the run); ``inf`` when it never is."""
    order = np.argsort(t)
    t, lost = t[order], lost[order]
    out = []
    for tk in kidnaps:
        after = np.flatnonzero(t >= tk)
        found = math.inf
        for i in after:
            if lost[i]:
                continue
            window = (t >= t[i]) & (t < t[i] + RECOVERY_HOLD)
            if not lost[window].any():
                found = float(t[i] - tk)
                break
        out.append(found)
    return out


def outside_allowance(t: NDArray[np.float64], kidnaps: list[float]) -> NDArray[np.bool_]:
    """Which poses are outside every kidnap's recovery allowance."""
    keep = np.ones(len(t), dtype=bool)
    for tk in kidnaps:
        keep &= ~((t >= tk) & (t < tk + RECOVERY_ALLOWANCE))
    return keep

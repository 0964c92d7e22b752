"""A simulated run localized from its known start pose and scored against its ground truth:
the unit of the fusion experiments (tests, benchmarks, notebooks)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.config import LocalizerConfig
from fusion.evaluation import ATE, ATEResult, LostFraction, Trajectory, nees
from fusion.localizer import Localizer
from fusion.replay import ReplayResult, replay
from fusion.sim import SimRun
from fusion.tracker import PoseTracker


@dataclass
class Localized:
    """One simulated run localized from its known start pose, with its errors."""

    run: SimRun
    result: ReplayResult
    localizer: Localizer
    ate: ATEResult

    @property
    def position_rmse(self) -> float:
        return self.ate.position["rmse"]

    @property
    def heading_rmse_deg(self) -> float:
        return self.ate.heading_deg["rmse"]

    @property
    def lost(self) -> int:
        return LostFraction().from_ate(self.ate).count

    def nees_per_scan(self) -> NDArray[np.float64]:
        """eᵀP⁻¹e of every output pose against the truth at its time."""
        ref = self.run.truth[self.ate.association.ref_index]
        errors = np.column_stack((self.result.poses[:, :2] - ref[:, :2], self.ate.heading_errors))
        return nees(errors, self.result.covs).values


def localize_simulated(run: SimRun, config: LocalizerConfig,
                       tracker: PoseTracker | None = None) -> Localized:
    """Replay ``run`` through a localizer started at the true start pose (``tracker`` replaces
    its filter, e.g. to inject faults) and score every output pose."""
    loc = Localizer(run.map, config, initial_pose=run.odom_truth[0])
    if tracker is not None:
        loc.tracker = tracker
    result = replay(run.events(), loc, progress=False)
    ate = ATE().compute(result.trajectory, Trajectory(run.truth_t, run.truth))
    if not ate.association.matched == len(result.t) > 0:  # an unscored pose would hide errors
        raise ValueError(f"{len(result.t) - ate.association.matched} poses without ground truth")
    return Localized(run, result, loc, ate)


class OutlierInjectingTracker(PoseTracker):
    """A tracker that shifts a ``fraction`` of the fixes by ``shift`` metres in a random direction
    (deterministic by ``seed``) and remembers the times of the shifted ones: gross outliers for
    gating experiments (pass it to :func:`localize_simulated`). Build it with
    ``OutlierInjectingTracker.from_config(config.filter, pose, fraction=…, seed=…)``."""

    def __init__(self, *tracker_args: Any, fraction: float, seed: int, shift: float = 1.0,
                 **tracker_kwargs: Any) -> None:
        super().__init__(*tracker_args, **tracker_kwargs)
        self.fraction, self.shift = fraction, shift
        self.rng = np.random.default_rng(seed)
        self.injected_times: list[float] = []

    def apply(self, t: float, z: ArrayLike, r: ArrayLike, basis: ArrayLike | None = None):
        if self.rng.random() < self.fraction:
            direction = self.rng.uniform(-np.pi, np.pi)
            z = np.asarray(z, dtype=float) + self.shift * np.array(
                [np.cos(direction), np.sin(direction), 0.0])
            self.injected_times.append(t)
        return super().apply(t, z, r, basis)

"""The error metrics: ATE, RPE, the "lost" fraction, Kümmerle relation errors. Each is a small
class configured once whose ``compute`` returns a result with per-sample errors, a few
statistics and ``as_dict()`` (:mod:`fusion.evaluation` says how trajectories are paired).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.evaluation.trajectory import (
    DEFAULT_MAX_DT,
    Alignment,
    Association,
    DeltaUnit,
    Trajectory,
    align_se2,
    associate,
    nearest_reference,
    statistics,
)
from fusion.integrity import LOCALIZED_HEADING_DEG, LOCALIZED_POSITION
from fusion.io.relations import Relations
from houghloc.geometry import compose, relative, wrap_angle

# -- trajectories and batched pose algebra -----------------------------------------------------


# -- association and alignment -------------------------------------------------------------------


# -- ATE -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ATEResult:
    """Absolute errors of the matched poses (after alignment, if any)."""

    association: Association
    transform: NDArray[np.float64]
    position_errors: NDArray[np.float64]
    heading_errors: NDArray[np.float64]
    alignment: Alignment

    @property
    def position(self) -> dict[str, float]:
        return statistics(self.position_errors)

    @property
    def heading_deg(self) -> dict[str, float]:
        return statistics(np.degrees(np.abs(self.heading_errors)))

    def as_dict(self) -> dict[str, Any]:
        position, heading = self.position, self.heading_deg
        return {
            "alignment": self.alignment.value,
            "transform": self.transform.tolist(),
            **self.association.as_dict(),
            "position_rmse_m": position["rmse"],
            "position_mean_m": position["mean"],
            "position_max_m": position["max"],
            "heading_rmse_deg": heading["rmse"],
            "heading_max_deg": heading["max"],
        }


@dataclass(frozen=True)
class ATE:
    """Absolute trajectory error: position (m) and heading (rad; reported in degrees)."""

    alignment: Alignment = Alignment.NONE
    max_dt: float = DEFAULT_MAX_DT

    def compute(self, est: Trajectory, ref: Trajectory) -> ATEResult:
        match = associate(est.t, ref.t, self.max_dt)
        e = est.poses[match.est_index]
        r = ref.poses[match.ref_index]
        transform = np.zeros(3)
        if self.alignment == Alignment.SE2:
            transform = align_se2(e, r)
            e = compose(transform, e)
        position = np.hypot(e[:, 0] - r[:, 0], e[:, 1] - r[:, 1])
        heading = np.asarray(wrap_angle(e[:, 2] - r[:, 2]), dtype=float)
        return ATEResult(match, transform, position, heading, Alignment(self.alignment))


# -- lost fraction ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class LostResult:
    lost: NDArray[np.bool_]
    max_position: float
    max_heading_deg: float

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.lost))

    @property
    def fraction(self) -> float:
        return float(np.mean(self.lost)) if self.lost.size else float("nan")

    def as_dict(self) -> dict[str, Any]:
        return {
            "lost_fraction": self.fraction,
            "lost": self.count,
            "evaluated": int(self.lost.size),
            "max_position_m": self.max_position,
            "max_heading_deg": self.max_heading_deg,
        }


@dataclass(frozen=True)
class LostFraction:
    """The fraction of matched poses off by more than ``max_position`` m or ``max_heading_deg``."""

    max_position: float = LOCALIZED_POSITION
    max_heading_deg: float = LOCALIZED_HEADING_DEG
    max_dt: float = DEFAULT_MAX_DT

    def compute(self, est: Trajectory, ref: Trajectory) -> LostResult:
        return self.from_ate(ATE(Alignment.NONE, self.max_dt).compute(est, ref))

    def from_ate(self, ate: ATEResult) -> LostResult:
        lost = (ate.position_errors > self.max_position) | (
            np.abs(ate.heading_errors) > np.radians(self.max_heading_deg)
        )
        return LostResult(lost, self.max_position, self.max_heading_deg)


# -- RPE -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RelativeResult:
    """Errors of relative motions: translation (m), rotation (rad; reported in degrees)."""

    translation_errors: NDArray[np.float64]
    rotation_errors: NDArray[np.float64]

    @property
    def count(self) -> int:
        return len(self.translation_errors)

    @property
    def translation(self) -> dict[str, float]:
        return statistics(self.translation_errors)

    @property
    def rotation_deg(self) -> dict[str, float]:
        return statistics(np.degrees(self.rotation_errors))

    def as_dict(self) -> dict[str, Any]:
        tr, rot = self.translation, self.rotation_deg
        return {
            "count": self.count,
            "translation_mean_m": tr["mean"],
            "translation_std_m": tr["std"],
            "translation_rmse_m": tr["rmse"],
            "translation_max_m": tr["max"],
            "rotation_mean_deg": rot["mean"],
            "rotation_std_deg": rot["std"],
            "rotation_rmse_deg": rot["rmse"],
            "rotation_max_deg": rot["max"],
        }


def relative_errors(
    est_from: ArrayLike, est_to: ArrayLike, ref_motion: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Translation and rotation errors of the estimated motions ``(⊖est_from) ⊕ est_to`` against the
    reference motions (N×3), as Kümmerle et al. 2009: ‖Δ translation‖ and |wrap(Δ yaw)|."""
    est_motion = relative(est_from, est_to)
    ref_motion = np.asarray(ref_motion, dtype=float).reshape(-1, 3)
    d = est_motion - ref_motion
    return np.hypot(d[:, 0], d[:, 1]), np.abs(np.asarray(wrap_angle(d[:, 2]), dtype=float))


@dataclass(frozen=True)
class RPE:
    """Relative pose error over a fixed ``delta`` (frames, seconds or metres travelled along the
    reference), between time-associated poses."""

    delta: float = 1.0
    unit: DeltaUnit = DeltaUnit.SECONDS
    max_dt: float = DEFAULT_MAX_DT

    def compute(self, est: Trajectory, ref: Trajectory) -> RelativeResult:
        match = associate(est.t, ref.t, self.max_dt)
        order = np.argsort(ref.t[match.ref_index], kind="stable")
        e = est.poses[match.est_index][order]
        r = ref.poses[match.ref_index][order]
        t = ref.t[match.ref_index][order]
        i, j = self._pairs(t, r)
        tr, rot = relative_errors(e[i], e[j], relative(r[i], r[j]))
        return RelativeResult(tr, rot)

    def _pairs(
        self, t: NDArray[np.float64], r: NDArray[np.float64]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        n = len(t)
        i = np.arange(n)
        if self.unit == DeltaUnit.FRAMES:
            j = i + int(self.delta)
        else:
            if self.unit == DeltaUnit.SECONDS:
                axis = t
            else:
                steps = np.hypot(np.diff(r[:, 0]), np.diff(r[:, 1]))
                axis = np.concatenate(([0.0], np.cumsum(steps)))
            j = np.searchsorted(axis, axis + self.delta, side="left")
        valid = (j < n) & (j > i)
        return i[valid], j[valid]


# -- relations (Kümmerle et al. 2009) --------------------------------------------------------------


@dataclass(frozen=True)
class RelationResult(RelativeResult):
    """Relation errors; ``missing`` counts relations without an estimated pose at t1 or t2."""

    missing: int = 0
    total: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {**super().as_dict(), "missing": self.missing, "relations": self.total}


@dataclass(frozen=True)
class RelationError:
    """Kümmerle et al. 2009: for each reference relation (t1, t2, δ), the estimated relative pose
    (⊖pose(t1)) ⊕ pose(t2) against δ; poses are the estimates nearest in time within ``max_dt``."""

    max_dt: float = DEFAULT_MAX_DT

    def compute(self, est: Trajectory, relations: Relations) -> RelationResult:
        total = len(relations)
        if len(est) == 0:
            empty = np.empty(0)
            return RelationResult(empty, empty, missing=total, total=total)
        i1, dt1 = nearest_reference(est.t, np.asarray(relations.t1, dtype=float))
        i2, dt2 = nearest_reference(est.t, np.asarray(relations.t2, dtype=float))
        found = (dt1 <= self.max_dt) & (dt2 <= self.max_dt)
        tr, rot = relative_errors(
            est.poses[i1[found]], est.poses[i2[found]], relations.delta[found]
        )
        return RelationResult(tr, rot, missing=int(total - found.sum()), total=total)


# -- filter consistency ----------------------------------------------------------------------------


# -- reporting -------------------------------------------------------------------------------------



"""Trajectory evaluation: association, ATE, RPE, "lost" fraction, Kümmerle relation errors, NEES.

In the spirit of ``evo``: each metric is a small class configured once (``ATE(alignment=...)``)
whose ``compute`` returns a result with per-sample errors, a few statistics and ``as_dict()`` for
``metrics.json``. Units: metres for positions; headings are radians in the arrays and degrees in
the reported statistics (the ``_deg`` keys), as in Kümmerle et al. 2009.

Estimated and reference trajectories are paired by timestamp (``associate``): each estimate takes
the nearest reference within ``max_dt`` (default 0.02 s), one to one. The localizer and the
reference are both in the ``map`` frame, so ATE uses no alignment by default; ``Alignment.SE2``
(closed-form 2D Kabsch/Umeyama without scale) is for paths in their own frame, like odometry.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from fusion.io.relations import Relations
from houghloc.geometry import compose, relative, wrap_angle

DEFAULT_MAX_DT = 0.02


class Statistic(StrEnum):
    RMSE = "rmse"
    MEAN = "mean"
    MEDIAN = "median"
    STD = "std"
    MIN = "min"
    MAX = "max"


class Alignment(StrEnum):
    """How the estimate is aligned to the reference before ATE."""

    NONE = "none"
    SE2 = "se2"


class DeltaUnit(StrEnum):
    """What the RPE's ``delta`` counts."""

    FRAMES = "frames"
    SECONDS = "seconds"
    METERS = "meters"


def statistics(values: ArrayLike) -> dict[str, float]:
    """RMSE, mean, median, std, min, max of a 1-D array (NaN for an empty one)."""
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        return {s.value: float("nan") for s in Statistic}
    return {
        Statistic.RMSE.value: float(np.sqrt(np.mean(v**2))),
        Statistic.MEAN.value: float(np.mean(v)),
        Statistic.MEDIAN.value: float(np.median(v)),
        Statistic.STD.value: float(np.std(v)),
        Statistic.MIN.value: float(np.min(v)),
        Statistic.MAX.value: float(np.max(v)),
    }


# -- trajectories and batched pose algebra -----------------------------------------------------


@dataclass(frozen=True)
class Trajectory:
    """Timestamps ``t`` (N,) and planar poses ``poses`` N×3 (x, y, θ)."""

    t: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).ravel()
        poses = np.asarray(self.poses, dtype=float).reshape(-1, 3)
        if len(t) != len(poses):
            raise ValueError(f"{len(t)} timestamps but {len(poses)} poses")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "poses", poses)

    def __len__(self) -> int:
        return len(self.t)

    @classmethod
    def from_tum(cls, path: Any) -> Trajectory:
        from fusion.io.tum import read_tum

        return cls(*read_tum(path))


# -- association and alignment -------------------------------------------------------------------


@dataclass(frozen=True)
class Association:
    """Index pairs (estimate, reference) matched by time, in the estimate's order."""

    est_index: NDArray[np.intp]
    ref_index: NDArray[np.intp]
    n_est: int
    n_ref: int
    max_dt: float

    @property
    def matched(self) -> int:
        return len(self.est_index)

    def as_dict(self) -> dict[str, Any]:
        return {
            "matched": self.matched,
            "estimated": self.n_est,
            "reference": self.n_ref,
            "max_dt": self.max_dt,
        }


def associate(est_t: ArrayLike, ref_t: ArrayLike, max_dt: float = DEFAULT_MAX_DT) -> Association:
    """Pair each estimate with the nearest reference time within ``max_dt``, one to one (when two
    estimates claim one reference, the closer in time wins). Times need not be sorted."""
    est_t = np.asarray(est_t, dtype=float).ravel()
    ref_t = np.asarray(ref_t, dtype=float).ravel()
    empty = np.empty(0, dtype=np.intp)
    if est_t.size == 0 or ref_t.size == 0:
        return Association(empty, empty, est_t.size, ref_t.size, max_dt)
    nearest, dt = _nearest(ref_t, est_t)
    est_idx = np.flatnonzero(dt <= max_dt)
    ref_idx, dt = nearest[est_idx], dt[est_idx]
    # One to one: sort by time difference and keep each reference's first (closest) claimant.
    by_dt = np.argsort(dt, kind="stable")
    _, first = np.unique(ref_idx[by_dt], return_index=True)
    keep = np.sort(by_dt[first])
    return Association(est_idx[keep], ref_idx[keep], est_t.size, ref_t.size, max_dt)


def _nearest(
    times: NDArray[np.float64], queries: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Index into ``times`` of the nearest time to each query, and the absolute difference."""
    order = np.argsort(times, kind="stable")
    sorted_t = times[order]
    right = np.clip(np.searchsorted(sorted_t, queries), 1, len(sorted_t) - 1)
    left = right - 1
    if len(sorted_t) == 1:
        left = right = np.zeros_like(right)
    take_left = np.abs(queries - sorted_t[left]) <= np.abs(sorted_t[right] - queries)
    pos = np.where(take_left, left, right)
    return order[pos], np.abs(sorted_t[pos] - queries)


def align_se2(source: ArrayLike, target: ArrayLike) -> NDArray[np.float64]:
    """The rigid transform T = (tx, ty, φ) minimising Σ‖T ⊕ sourceᵢ − targetᵢ‖² over positions
    (closed-form 2D Kabsch/Umeyama without scale). Apply it with ``compose(T, poses)``."""
    src = np.asarray(source, dtype=float)[:, :2]
    dst = np.asarray(target, dtype=float)[:, :2]
    if len(src) != len(dst) or len(src) < 2:
        raise ValueError(f"alignment needs ≥ 2 paired positions, got {len(src)} and {len(dst)}")
    src_mean, dst_mean = src.mean(axis=0), dst.mean(axis=0)
    s, d = src - src_mean, dst - dst_mean
    if not np.any(np.abs(s) > 1e-12):
        raise ValueError("alignment needs positions that are not all identical")
    # For 2D the optimal rotation angle has a closed form (no SVD needed).
    phi = np.arctan2(np.sum(s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0]), np.sum(s * d))
    c, sn = np.cos(phi), np.sin(phi)
    t = dst_mean - np.array(
        [c * src_mean[0] - sn * src_mean[1], sn * src_mean[0] + c * src_mean[1]]
    )
    return np.array([t[0], t[1], phi])


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

    max_position: float = 0.3
    max_heading_deg: float = 5.0
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
        i1, dt1 = _nearest(est.t, np.asarray(relations.t1, dtype=float))
        i2, dt2 = _nearest(est.t, np.asarray(relations.t2, dtype=float))
        found = (dt1 <= self.max_dt) & (dt2 <= self.max_dt)
        tr, rot = relative_errors(
            est.poses[i1[found]], est.poses[i2[found]], relations.delta[found]
        )
        return RelationResult(tr, rot, missing=int(total - found.sum()), total=total)


# -- filter consistency ----------------------------------------------------------------------------


@dataclass(frozen=True)
class NEESResult:
    """Per-sample normalised estimation error squared, its mean and the 95 % band of the mean."""

    values: NDArray[np.float64]
    dof: int
    band: tuple[float, float] = field(default=(float("nan"), float("nan")))

    @property
    def mean(self) -> float:
        return float(np.mean(self.values)) if self.values.size else float("nan")

    @property
    def consistent(self) -> bool:
        """The average NEES lies inside the two-sided 95 % χ² band."""
        return bool(self.band[0] <= self.mean <= self.band[1])

    def as_dict(self) -> dict[str, Any]:
        return {
            "nees_mean": self.mean,
            "nees_band_95": list(self.band),
            "dof": self.dof,
            "samples": int(self.values.size),
            "consistent": self.consistent,
        }


def chi2_band(n: int, dof: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the *average* of n χ²(dof) samples: χ²⁻¹([α/2, 1−α/2], n·dof) / n."""
    if n <= 0:
        return float("nan"), float("nan")
    alpha = 1.0 - confidence
    lo, hi = chi2.ppf([alpha / 2, 1 - alpha / 2], n * dof) / n
    return float(lo), float(hi)


def nees(errors: ArrayLike, covariances: ArrayLike, angle_index: int | None = 2) -> NEESResult:
    """NEES eᵢᵀ Pᵢ⁻¹ eᵢ of N errors (N×d) with covariances (N×d×d); the component ``angle_index``
    of each error is wrapped to [−π, π) first (None: no angle). Also used for NIS with
    innovations and their covariances."""
    e = np.array(errors, dtype=float, ndmin=2)
    p = np.asarray(covariances, dtype=float).reshape(len(e), e.shape[1], e.shape[1])
    if angle_index is not None:
        e[:, angle_index] = wrap_angle(e[:, angle_index])
    # Solve instead of inverting: better conditioned for nearly singular covariances.
    values = np.einsum("ni,ni->n", e, np.linalg.solve(p, e[..., None])[..., 0])
    return NEESResult(values, e.shape[1], chi2_band(len(e), e.shape[1]))


# -- reporting -------------------------------------------------------------------------------------


def summary_table(
    rows: Sequence[Mapping[str, Any]] | Sequence[Sequence[Any]],
    headers: Sequence[str] | None = None,
    precision: int = 4,
) -> str:
    """A plain-text table. ``rows`` are dicts (columns: the union of their keys, in first-seen
    order) or sequences with ``headers``. Floats get ``precision`` significant digits; text is
    left-aligned, numbers right-aligned."""
    if rows and isinstance(rows[0], Mapping):
        dict_rows = [dict(row) for row in rows]  # type: ignore[arg-type]
        columns = list(headers or dict.fromkeys(k for row in dict_rows for k in row))
        values = [[row.get(c, "") for c in columns] for row in dict_rows]
    else:
        columns = list(headers or [])
        values = [list(row) for row in rows]
    ncol = max([len(columns), *(len(v) for v in values)])
    columns += [""] * (ncol - len(columns))
    values = [v + [""] * (ncol - len(v)) for v in values]
    cells = [[_cell(v, precision) for v in row] for row in values]
    widths = [max(len(str(c)), *(len(row[k]) for row in cells)) for k, c in enumerate(columns)]
    lines = []
    if any(columns):
        lines.append("  ".join(str(c).ljust(w) for c, w in zip(columns, widths, strict=True)))
        lines.append("  ".join("-" * w for w in widths))
    for row, raw in zip(cells, values, strict=True):
        parts = [
            c.rjust(w) if isinstance(v, int | float | np.number) else c.ljust(w)
            for c, v, w in zip(row, raw, widths, strict=True)
        ]
        lines.append("  ".join(parts))
    return "\n".join(line.rstrip() for line in lines)


def _cell(value: Any, precision: int) -> str:
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, float | np.floating):
        return f"{float(value):.{precision}g}"
    return str(value)


def window_means(t: ArrayLike, values: ArrayLike, seconds: float) -> NDArray[np.float64]:
    """The mean of ``values`` over each window [t_i, t_i + seconds) that ends inside the data,
    one per start t_i (sorted times); the whole data's mean when it spans less than that.

    With prefix sums S: mean_i = (S[j_i] − S[i]) / (j_i − i), j_i the first index at or past
    t_i + seconds."""
    t = np.asarray(t, float)
    v = np.asarray(values, float)
    if len(t) == 0:
        return np.empty(0)
    ends = np.searchsorted(t, t + seconds, side="left")
    full = t + seconds <= t[-1]
    if not full.any():
        return np.array([v.mean()])
    starts = np.flatnonzero(full)
    sums = np.concatenate(([0.0], np.cumsum(v)))
    return (sums[ends[starts]] - sums[starts]) / (ends[starts] - starts)

"""Trajectories and their pairing by time: the estimate and the reference meet here before any
metric (:mod:`fusion.evaluation.metrics`). Poses are (x, y, θ) in metres and radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

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

    @classmethod
    def from_reference(cls, path: Any) -> Trajectory:
        """A TUM file, or the corrected poses of a CARMEN log (:func:`fusion.io.read_reference`)."""
        from fusion.io import read_reference

        return cls(*read_reference(path))


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
    nearest, dt = nearest_reference(ref_t, est_t)
    est_idx = np.flatnonzero(dt <= max_dt)
    ref_idx, dt = nearest[est_idx], dt[est_idx]
    # One to one: sort by time difference and keep each reference's first (closest) claimant.
    by_dt = np.argsort(dt, kind="stable")
    _, first = np.unique(ref_idx[by_dt], return_index=True)
    keep = np.sort(by_dt[first])
    return Association(est_idx[keep], ref_idx[keep], est_t.size, ref_t.size, max_dt)


def nearest_reference(
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

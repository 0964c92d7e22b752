"""The filter's consistency (NEES against its χ² band) and the tables and windows the reports
print.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from houghloc.geometry import wrap_angle


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

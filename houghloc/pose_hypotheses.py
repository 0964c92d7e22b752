"""Steps 1 and 2 of global set matching (:mod:`houghloc.global_match`): poses from pairs of
observed lines put on pairs of map lines with the same angle between them, and their votes in
pose space.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from houghloc.geometry import TWO_PI
from houghloc.jit import njit
from houghloc.map_lookup import AngleIndex
from houghloc.refine import Lines

if TYPE_CHECKING:
    from houghloc.config import GlobalMatchConfig
    from houghloc.match_result import Neighbourhood


# ---------------------------------------------------------------------------- 1. hypotheses
def observed_pairs(lines: Lines, config: GlobalMatchConfig
                   ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index pairs (i, k), i ≠ k unordered, of strong non-parallel observed lines.

    The best-conditioned pairs come first: long lines (well-determined θ) meeting near 90°
    (well-determined position); only ``max_observed_pairs`` are kept, because one correct pair
    already gives the pose and every pair multiplies the hypotheses.
    """
    strong = np.argsort(-lines.n, kind="stable")[: config.max_observed_lines]
    i, k = np.triu_indices(len(strong), 1)
    i, k = strong[i], strong[k]
    sin_d = np.abs(np.sin(lines.theta[k] - lines.theta[i]))
    ok = sin_d >= math.sin(config.min_pair_angle)
    i, k, sin_d = i[ok], k[ok], sin_d[ok]
    length = lines.s1 - lines.s0
    quality = length[i] * length[k] * sin_d
    order = np.argsort(-quality, kind="stable")[: config.max_observed_pairs]
    return i[order], k[order]


def pair_hypotheses(lines: Lines, pair_i: NDArray[np.intp], pair_k: NDArray[np.intp],
                    index: AngleIndex, config: GlobalMatchConfig,
                    near: Neighbourhood | None = None) -> NDArray[np.float64]:
    """All poses (H×3) from observed pairs and the map pairs with the same angle between them.

    The window half-width is ``angle_tol_sigmas`` σ_δ + ``angle_tol_floor`` (capped), with
    σ_δ² = var θ_i + var θ_k from the lines' covariance; the ragged candidate ranges are walked
    by one compiled loop (:func:`_pair_poses`). With ``near``, poses whose heading is outside it are
    left out before their position is solved (a local search keeps a few percent of them); the
    budget still counts every candidate, so the poses kept are the same as without it.
    """
    d_obs = np.mod(lines.theta[pair_k] - lines.theta[pair_i], TWO_PI)
    sigma = np.sqrt(lines.cov[pair_i, 0, 0] + lines.cov[pair_k, 0, 0])
    tol = np.minimum(config.angle_tol_sigmas * sigma + config.angle_tol_floor,
                     config.angle_tol_max)
    lo = np.searchsorted(index.delta, d_obs - tol, side="left")
    hi = np.searchsorted(index.delta, d_obs + tol, side="right")
    counts = _within_budget(hi - lo, config.max_pair_hypotheses)
    return _pair_poses(lines.theta, lines.rho, pair_i, pair_k, lo, counts, index.beta_a,
                       index.beta_b, index.r_a, index.r_b, index.n_inv, near is not None,
                       near.pose[2] if near is not None else 0.0,
                       near.radius_theta if near is not None else 0.0, float(tol.max()))


@njit
def _pair_poses(theta: NDArray, rho: NDArray, pair_i: NDArray, pair_k: NDArray, lo: NDArray,
                counts: NDArray, beta_a: NDArray, beta_b: NDArray, r_a: NDArray, r_b: NDArray,
                n_inv: NDArray, use_near: bool, near_theta: float, near_radius: float,
                tol_max: float) -> NDArray:
    """The poses of :func:`pair_hypotheses`, ``counts[p]`` index entries from ``lo[p]`` for each
    observed pair p: θ = β − θ_obs from either line, their circular mean; (x, y) = N⁻¹ (r − ρ).
    With a neighbourhood, a pose whose heading is outside it is left out before its position is
    solved (θ is within half the angle window of θ_a: a first cut on θ_a alone)."""
    # with a neighbourhood a few percent of the candidates are kept: the array grows as needed
    # rather than holding them all (megabytes, each page touched for the first time)
    out = np.empty((min(counts.sum(), 4096) if use_near else counts.sum(), 3))
    h = 0
    for p in range(len(pair_i)):
        i, k = pair_i[p], pair_k[p]
        for e in range(lo[p], lo[p] + counts[p]):
            th_a = beta_a[e] - theta[i]
            if use_near and abs(_mod_two_pi(th_a - near_theta + np.pi) - np.pi) > (
                    near_radius + tol_max):
                continue
            th_b = beta_b[e] - theta[k]
            half = 0.5 * (_mod_two_pi(th_b - th_a + np.pi) - np.pi)
            th = _mod_two_pi(th_a + half + np.pi) - np.pi
            if use_near and abs(_mod_two_pi(th - near_theta + np.pi) - np.pi) > near_radius:
                continue
            if h == len(out):
                out = np.concatenate((out, np.empty_like(out)))
            rhs_a, rhs_b = r_a[e] - rho[i], r_b[e] - rho[k]
            out[h, 0] = n_inv[e, 0, 0] * rhs_a + n_inv[e, 0, 1] * rhs_b
            out[h, 1] = n_inv[e, 1, 0] * rhs_a + n_inv[e, 1, 1] * rhs_b
            out[h, 2] = th
            h += 1
    return out[:h]


@njit
def _mod_two_pi(u: float) -> float:
    """``u % TWO_PI`` bit for bit (Python's and Numba's floor modulo: ``fmod``, then + 2π when
    negative), without ``fmod`` where ``u`` lies within a period of [0, 2π): the remainder is
    then ``u`` itself, ``u − 2π`` (exact, by Sterbenz's lemma, as ``fmod``'s) or ``u + 2π``
    (the modulo's own correction, rounded the same). A local search's candidate loop calls it
    on every candidate: on Freiburg 079's, 1.9–2.4 ms a call instead of 4.6–5.6 with ``%``."""
    if 0.0 < u < TWO_PI:
        return u
    if TWO_PI <= u < 2.0 * TWO_PI:
        return u - TWO_PI
    if -TWO_PI < u < 0.0:
        return u + TWO_PI
    return u % TWO_PI  # zero (its sign), far outside, NaN


def _within_budget(counts: NDArray[np.intp], budget: int) -> NDArray[np.intp]:
    """Candidate counts with the pairs beyond the budget set to zero.

    The index tells, before any pose is computed, how many map pairs each observed pair matches.
    Pairs arrive best-conditioned first (long lines, well-determined angles); they are taken in
    that order while the total stays within ``budget`` (the first always), so in a large map of
    right angles, where every pair matches thousands of map pairs, the cost stops growing with
    the square of the map. (Taking the rarest angles first would be cheaper still, but a rare
    angle is most often a short spurious piece.)
    """
    take = np.cumsum(counts) <= budget
    take[0] = True
    return np.where(take, counts, 0)


# ---------------------------------------------------------------------------- 2. votes
def vote_cells(poses: NDArray, config: GlobalMatchConfig) -> tuple[NDArray, NDArray]:
    """Bin poses in (x, y, θ); return one pose per occupied cell (its members' mean) and the count
    of hypotheses in it, best-voted first, at most ``max_cells_cheap``."""
    q = np.column_stack((np.floor(poses[:, :2] / config.vote_cell_xy),
                         np.floor(np.mod(poses[:, 2], TWO_PI) / config.vote_cell_theta)))
    q = q.astype(np.int64)
    q -= q.min(axis=0)
    # one integer key per cell: a 1-D unique is several times faster than unique over rows
    key = np.ravel_multi_index(q.T, tuple(q.max(axis=0) + 1))
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    n_cells = len(counts)
    # mean pose per cell: positions averaged, θ as a circular mean
    sums = np.zeros((n_cells, 4))
    for col, values in enumerate((poses[:, 0], poses[:, 1], np.cos(poses[:, 2]),
                                  np.sin(poses[:, 2]))):
        sums[:, col] = np.bincount(inverse, values, minlength=n_cells)
    cells = np.column_stack((sums[:, :2] / counts[:, None], np.arctan2(sums[:, 3], sums[:, 2])))
    order = top_indices(counts.astype(float), config.max_cells_cheap)
    return cells[order], counts[order]


def top_indices(values: NDArray, m: int) -> NDArray[np.intp]:
    """Indices of the m largest values, largest first (a partition, then a small sort)."""
    if len(values) > m:
        part = np.argpartition(-values, m - 1)[:m]
    else:
        part = np.arange(len(values))
    return part[np.argsort(-values[part], kind="stable")]


def row_chunks(n_rows: int, cost_per_row: int, budget: int = 2_000_000):
    """Slices of ``n_rows`` rows, each costing about ``budget`` elements of temporary memory."""
    step = max(1, budget // max(cost_per_row, 1))
    for start in range(0, n_rows, step):
        yield slice(start, min(start + step, n_rows))

"""Steps 1 and 2 of global set matching (:mod:`houghloc.global_match`): poses from pairs of
observed lines put on pairs of map lines with the same angle between them, and their votes in
pose space.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from houghloc.geometry import TWO_PI, mod_two_pi
from houghloc.jit import njit
from houghloc.map_lookup import AngleIndex
from houghloc.neighbourhood import Neighbourhood, in_neighbourhood
from houghloc.refine import Lines

if TYPE_CHECKING:
    from houghloc.config import GlobalMatchConfig


# ---------------------------------------------------------------------------- 1. hypotheses
def observed_pairs(lines: Lines, config: GlobalMatchConfig
                   ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index pairs (i, k), i ≠ k unordered, of strong non-parallel observed lines.

    The best-conditioned pairs come first: long lines (well-determined θ) meeting near 90°
    (well-determined position); only ``max_observed_pairs`` are kept, because one correct pair
    already gives the pose and every pair multiplies the hypotheses.
    """
    strong = np.argsort(-lines.n, kind="stable")[: config.max_observed_lines]
    i, k = _pairs_of(len(strong))
    i, k = strong[i], strong[k]
    sin_d = np.abs(np.sin(lines.theta[k] - lines.theta[i]))
    ok = sin_d >= math.sin(config.min_pair_angle)
    i, k, sin_d = i[ok], k[ok], sin_d[ok]
    length = lines.s1 - lines.s0
    quality = length[i] * length[k] * sin_d
    order = np.argsort(-quality, kind="stable")[: config.max_observed_pairs]
    return i[order], k[order]


@lru_cache(maxsize=64)
def _pairs_of(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``np.triu_indices(n, 1)``, read-only, built once per n (a dozen lines at most: building
    them cost more than the rest of choosing the pairs)."""
    i, k = np.triu_indices(n, 1)
    i.flags.writeable = k.flags.writeable = False
    return i, k


def pair_hypotheses(lines: Lines, pair_i: NDArray[np.intp], pair_k: NDArray[np.intp],
                    index: AngleIndex, config: GlobalMatchConfig,
                    near: Neighbourhood | None = None,
                    box: tuple[NDArray, NDArray] | None = None) -> NDArray[np.float64]:
    """All poses (H×3) from observed pairs and the map pairs with the same angle between them.

    The window half-width is ``angle_tol_sigmas`` σ_δ + ``angle_tol_floor`` (capped), with
    σ_δ² = var θ_i + var θ_k from the lines' covariance; the ragged candidate ranges are walked
    by one compiled loop (:func:`_pair_poses`). With ``near``, only the poses inside it
    (:meth:`Neighbourhood.contains`); those whose heading is outside it are left out before their
    position is solved (a local search keeps a few percent of them). With ``box`` (its lower and
    upper corners), only the poses whose position lies in it. The budget counts every candidate
    (:func:`candidate_count`), so the poses kept are those of the whole map's hypotheses that pass
    both cuts, in the same order.
    """
    lo, counts, tol_max = _windows(lines, pair_i, pair_k, index, config)
    box_lo, box_hi = (np.full(2, -np.inf), np.full(2, np.inf)) if box is None else box
    return _pair_poses(lines.theta, lines.rho, pair_i, pair_k, lo, counts, index.beta_a,
                       index.beta_b, index.r_a, index.r_b, index.n_inv, index.cos_a,
                       index.sin_a, near is not None,
                       *(near.kernel_args() if near is not None else (0.0, 0.0, 0.0, 0.0, 0.0)),
                       tol_max, float(box_lo[0]), float(box_lo[1]), float(box_hi[0]),
                       float(box_hi[1]))


def candidate_count(lines: Lines, pair_i: NDArray[np.intp], pair_k: NDArray[np.intp],
                    index: AngleIndex, config: GlobalMatchConfig) -> int:
    """How many candidates :func:`pair_hypotheses` solves or cuts: every map pair within the
    observed pairs' windows, up to the budget (what its work is counted by)."""
    return int(_windows(lines, pair_i, pair_k, index, config)[1].sum())


def _windows(lines: Lines, pair_i: NDArray[np.intp], pair_k: NDArray[np.intp],
             index: AngleIndex, config: GlobalMatchConfig
             ) -> tuple[NDArray[np.intp], NDArray[np.intp], float]:
    """Each observed pair's range of the angle index (first entry, count within the budget),
    and the widest window's half-width."""
    d_obs = np.mod(lines.theta[pair_k] - lines.theta[pair_i], TWO_PI)
    sigma = np.sqrt(lines.cov[pair_i, 0, 0] + lines.cov[pair_k, 0, 0])
    tol = np.minimum(config.angle_tol_sigmas * sigma + config.angle_tol_floor,
                     config.angle_tol_max)
    lo = np.searchsorted(index.delta, d_obs - tol, side="left")
    hi = np.searchsorted(index.delta, d_obs + tol, side="right")
    return lo, _within_budget(hi - lo, config.max_pair_hypotheses), float(tol.max())


@njit
def _pair_poses(theta: NDArray, rho: NDArray, pair_i: NDArray, pair_k: NDArray, lo: NDArray,
                counts: NDArray, beta_a: NDArray, beta_b: NDArray, r_a: NDArray, r_b: NDArray,
                n_inv: NDArray, cos_a: NDArray, sin_a: NDArray, use_near: bool,
                near_x: float, near_y: float,
                near_theta: float, near_xy_sq: float, near_radius: float, tol_max: float,
                box_x0: float, box_y0: float, box_x1: float, box_y1: float) -> NDArray:
    """The poses of :func:`pair_hypotheses`, ``counts[p]`` index entries from ``lo[p]`` for each
    observed pair p: θ = β − θ_obs from either line, their circular mean; (x, y) = N⁻¹ (r − ρ);
    kept when inside the box (and the neighbourhood). With a neighbourhood, a pose whose
    heading is outside it is left out before its position is solved (θ is within half the
    angle window of θ_a: a first cut on θ_a alone, then the exact one on θ), and so is one whose
    line a puts it too far from the centre (the position lies on that line's hypothesis
    x cos β_a + y sin β_a = r_a − ρ_i, at least as far from the centre as the line is)."""
    # with a neighbourhood a few percent of the candidates are kept: the array grows as needed
    # rather than holding them all (megabytes, each page touched for the first time)
    out = np.empty((min(counts.sum(), 4096) if use_near else counts.sum(), 3))
    # θ_a = β_a − θ_i within near_radius + tol_max of the centre's heading c is
    # cos(β_a − (θ_i + c)) ≥ cos(near_radius + tol_max): a product per candidate, no modulo.
    # The bound is widened by a microradian, so the cut keeps a superset and the exact test
    # on θ below decides.
    reach = near_radius + tol_max + 1e-6
    bound = math.cos(reach) if reach < np.pi else -2.0
    # The position's cut: the line's distance from the centre, |r_a − ρ_i − (c_x cos β_a +
    # c_y sin β_a)|, is at most the position's. The solve below meets line a to rounding
    # (10⁻¹³ m on a building), so a micrometre's margin keeps a superset here too.
    gap = math.sqrt(near_xy_sq) + 1e-6
    # the cut is a pass over the window that only lists the survivors (no branch to mispredict
    # on every candidate); they are solved after it, in the window's order
    passed = np.empty(counts.max() if use_near and len(counts) else 0, np.intp)
    h = 0
    for p in range(len(pair_i)):
        i, k = pair_i[p], pair_k[p]
        m = counts[p]
        if use_near:
            cos_c, sin_c = math.cos(theta[i] + near_theta), math.sin(theta[i] + near_theta)
            rho_i = rho[i]
            m = 0
            for e in range(lo[p], lo[p] + counts[p]):
                passed[m] = e
                off_line = r_a[e] - rho_i - (near_x * cos_a[e] + near_y * sin_a[e])
                m += (cos_a[e] * cos_c + sin_a[e] * sin_c >= bound) & (abs(off_line) <= gap)
        for q in range(m):
            e = passed[q] if use_near else lo[p] + q
            rhs_a, rhs_b = r_a[e] - rho[i], r_b[e] - rho[k]
            x = n_inv[e, 0, 0] * rhs_a + n_inv[e, 0, 1] * rhs_b
            y = n_inv[e, 1, 0] * rhs_a + n_inv[e, 1, 1] * rhs_b
            if not (box_x0 <= x <= box_x1 and box_y0 <= y <= box_y1):
                continue
            # the position is tested before the heading is solved: of a local search's
            # candidates, most of those with a heading near its centre lie elsewhere
            dx, dy = x - near_x, y - near_y  # in_neighbourhood's own test, which decides
            if use_near and not dx * dx + dy * dy <= near_xy_sq:
                continue
            th_a = beta_a[e] - theta[i]
            th_b = beta_b[e] - theta[k]
            half = 0.5 * (mod_two_pi(th_b - th_a + np.pi) - np.pi)
            th = mod_two_pi(th_a + half + np.pi) - np.pi
            if use_near and not in_neighbourhood(x, y, th, near_x, near_y, near_theta,
                                                 near_xy_sq, near_radius):
                continue
            if h == len(out):
                out = np.concatenate((out, np.empty_like(out)))
            out[h, 0], out[h, 1], out[h, 2] = x, y, th
            h += 1
    return out[:h]


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
    of hypotheses in it, best-voted first, at most ``max_cells_cheap``.

    Cells are numbered in the order of their (x, y, θ) bin indices (row-major), so that cells
    with equal votes rank the same on every run; the compiled :func:`_cells_of` finds each pose's
    cell by a radix sort of the bin keys, in time linear in the poses, and the means are taken
    only of the cells kept.
    """
    poses = np.ascontiguousarray(poses, dtype=float)
    inverse, counts = _cells_of(poses, config.vote_cell_xy, config.vote_cell_theta)
    order = top_indices(counts.astype(float), config.max_cells_cheap)
    return _cell_means(poses, inverse, order, counts[order]), counts[order]


@njit
def _cells_of(poses: NDArray, cell_xy: float, cell_theta: float
              ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Each pose's cell (numbered by ascending bin key) and each cell's count of poses.

    Bin (⌊x / c⌋, ⌊y / c⌋, ⌊(θ mod 2π) / c_θ⌋), offset to start at 0, has the row-major key
    (q_x · n_y + q_y) · n_θ + q_θ; the keys are sorted by a stable least-significant-digit radix
    sort and the distinct keys numbered in order.
    """
    n = len(poses)
    keys = np.empty(n, np.int64)
    if n:  # two passes over the bins: their lowest and highest indices, then the keys
        low_x = low_y = low_theta = np.iinfo(np.int64).max
        high_y = high_theta = np.iinfo(np.int64).min
        for h in range(n):
            q_x, q_y, q_theta = _bin(poses[h], cell_xy, cell_theta)
            low_x, low_y, low_theta = min(low_x, q_x), min(low_y, q_y), min(low_theta, q_theta)
            high_y, high_theta = max(high_y, q_y), max(high_theta, q_theta)
        n_y, n_theta = high_y - low_y + 1, high_theta - low_theta + 1
        for h in range(n):
            q_x, q_y, q_theta = _bin(poses[h], cell_xy, cell_theta)
            keys[h] = ((q_x - low_x) * n_y + q_y - low_y) * n_theta + q_theta - low_theta
    # as few passes of at most 16-bit digits as the largest key needs, the digits as narrow as
    # those passes allow (a narrow digit's counts stay in cache)
    bits = 1
    while n and (keys.max() >> bits) > 0:
        bits += 1
    passes = (bits + 15) // 16
    width = (bits + passes - 1) // passes
    mask = (1 << width) - 1
    order = np.arange(n)  # the keys travel with their poses' indices: no look-up through them
    spare, spare_keys = np.empty(n, np.int64), np.empty(n, np.int64)
    for shift in range(0, passes * width, width):
        start = np.zeros(mask + 2, np.int64)
        for h in range(n):
            start[((keys[h] >> shift) & mask) + 1] += 1
        for d in range(mask + 1):
            start[d + 1] += start[d]
        for h in range(n):
            d = (keys[h] >> shift) & mask
            spare[start[d]], spare_keys[start[d]] = order[h], keys[h]
            start[d] += 1
        order, spare, keys, spare_keys = spare, order, spare_keys, keys
    inverse = np.empty(n, np.intp)
    counts = np.zeros(n, np.intp)
    cell = -1
    for j in range(n):
        if j == 0 or keys[j] != keys[j - 1]:
            cell += 1
        inverse[order[j]] = cell
        counts[cell] += 1
    return inverse, counts[: cell + 1]


@njit
def _bin(pose: NDArray, cell_xy: float, cell_theta: float) -> tuple[int, int, int]:
    """The vote bin of a pose: (⌊x / c⌋, ⌊y / c⌋, ⌊(θ mod 2π) / c_θ⌋)."""
    return (int(np.floor(pose[0] / cell_xy)), int(np.floor(pose[1] / cell_xy)),
            int(np.floor(mod_two_pi(pose[2]) / cell_theta)))


@njit
def _cell_means(poses: NDArray, inverse: NDArray, cells: NDArray, counts: NDArray
                ) -> NDArray[np.float64]:
    """The mean pose of each of ``cells`` (``counts`` poses each): positions averaged, θ as a
    circular mean (atan2 of the summed sines and cosines), the poses added in their order."""
    rank = np.full(len(inverse), -1, np.intp)
    for j in range(len(cells)):
        rank[cells[j]] = j
    sums = np.zeros((len(cells), 4))
    for h in range(len(inverse)):
        j = rank[inverse[h]]
        if j >= 0:
            sums[j, 0] += poses[h, 0]
            sums[j, 1] += poses[h, 1]
            sums[j, 2] += np.cos(poses[h, 2])
            sums[j, 3] += np.sin(poses[h, 2])
    means = np.empty((len(cells), 3))
    for j in range(len(cells)):
        means[j, 0] = sums[j, 0] / counts[j]
        means[j, 1] = sums[j, 1] / counts[j]
        means[j, 2] = np.arctan2(sums[j, 3], sums[j, 2])
    return means


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

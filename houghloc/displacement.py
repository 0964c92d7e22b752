"""Pose correction from matched lines (docs/method.md §5).

Every match i relates an observed line zᵢ = (θ, ρ) to its reference hᵢ(x̂) seen from the guess.
Both are linear in the pose, so with Δ = (Δx, Δy, Δθ) the correction in the map frame,
    zᵢ − hᵢ(x̂) = Jᵢ Δ + noise,   Jᵢ = [[0, 0, −1], [−cos βᵢ, −sin βᵢ, 0]],   cov Cᵢ,
and weighted least squares gives it in one step:
    Λ = Σ Jᵢᵀ Cᵢ⁻¹ Jᵢ (information),   Δ = Λ⁻¹ Σ Jᵢᵀ Cᵢ⁻¹ (zᵢ − hᵢ).
The θ row makes Δθ the weighted mean of the θ differences (the paper averages them); the ρ rows
make Δt the least-squares solution of Δρᵢ = −nᵢ·Δt. Rotation about the sensor leaves ρ unchanged,
so the two decouple up to the lines' own θ–ρ correlation.

Observability: Δθ is known as soon as one line matches; the translation only along the normals in
view. After marginalising θ out of Λ, a translation direction whose standard deviation exceeds
``max_observable_sigma`` is *unobservable*: with only parallel lines (a corridor) the direction
along them. The solution is confined to the observable subspace — the missing component is never
invented — and the covariance carries ``UNOBSERVED_VARIANCE`` along the unobservable directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig
from houghloc.geometry import inverse_3x3, inverse_small
from houghloc.jit import njit
from houghloc.matching import (
    Matches,
    associate,
    associate_kernel,
    match_settings,
    matches_found,
)
from houghloc.refine import Lines
from houghloc.segment_map import References

UNOBSERVED_VARIANCE = 1.0e6  # m² (or rad²): finite, so no NaN downstream, and plainly "unknown"
_FULL = np.column_stack(((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
_NONE = np.zeros((3, 0))
_INFO_LAYOUT = np.array([[0, 1, 3], [1, 2, 4], [3, 4, 5]])  # Λ from its six distinct sums


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
class Displacement:
    delta: NDArray[np.float64]  # (Δx, Δy, Δθ) in the map frame
    cov: NDArray[np.float64]  # 3×3
    information: NDArray[np.float64]  # 3×3, Λ
    rank: int
    observable: NDArray[np.float64]  # 3×rank orthonormal basis
    unobservable: NDArray[np.float64]  # 3×(3−rank)
    chi2: float  # Σ post-fit squared Mahalanobis residuals
    dof: int  # 2·matches − rank
    matches: Matches | None = None
    beta: NDArray[np.float64] | None = None

    @property
    def per_match(self) -> NDArray[np.float64]:
        """Each match's share of ``chi2``: (r − JΔ)ᵀ C⁻¹ (r − JΔ) (computed when asked: only the
        outlier test needs it)."""
        if self.matches is None or len(self.matches) == 0:
            return np.zeros(0)
        c, r = self.matches.cov, self.matches.residual
        assert self.beta is not None  # set with the matches
        post_0 = r[:, 0] + self.delta[2]  # the residual after the correction: r − J Δ
        post_1 = r[:, 1] + np.cos(self.beta) * self.delta[0] + np.sin(self.beta) * self.delta[1]
        det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2
        return (c[:, 1, 1] * post_0**2 - 2 * c[:, 0, 1] * post_0 * post_1
                + c[:, 0, 0] * post_1**2) / det


def estimate_displacement(matches: Matches, beta: NDArray[np.float64],
                          max_observable_sigma: float) -> Displacement:
    """Weighted least squares of Δ over all matches; ``beta`` is the reference normal per match."""
    if len(matches) == 0:
        return _nothing_matched()
    solved = _solve(np.ascontiguousarray(matches.cov), np.ascontiguousarray(matches.residual),
                    np.ascontiguousarray(beta, dtype=float), max_observable_sigma)
    return _displacement(matches, beta, max_observable_sigma, *solved)


def match_and_solve(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
                    config: HoughConfig) -> tuple[Matches, Displacement]:
    """:func:`houghloc.matching.associate`, then :func:`estimate_displacement` of its matches,
    as one compiled call: a scan's association and its solution cross into Python once."""
    if len(lines) == 0 or len(refs) == 0:
        return associate(lines, refs, pose, pose_cov, config), _nothing_matched()
    li, rj, residual, cov, d2, n_cand, ambiguous, claims, beta, solved = _match_and_solve(
        config.max_observable_sigma, lines.theta, lines.rho, np.ascontiguousarray(lines.cov),
        lines.s0, lines.s1, refs.theta, refs.rho, refs.beta, refs.seg_ref, refs.seg_s0,
        refs.seg_s1, np.ascontiguousarray(pose, dtype=float),
        np.ascontiguousarray(pose_cov, dtype=float), match_settings(config))
    matches = matches_found(lines, None, li, rj, residual, cov, d2, n_cand, ambiguous, claims)
    if len(matches) == 0:
        return matches, _nothing_matched()
    return matches, _displacement(matches, beta, config.max_observable_sigma, *solved)


@njit
def _match_and_solve(max_observable_sigma: float, l_theta: NDArray, l_rho: NDArray,
                     l_cov: NDArray, l_s0: NDArray, l_s1: NDArray, r_theta: NDArray,
                     r_rho: NDArray, r_beta: NDArray, seg_ref: NDArray, seg_s0: NDArray,
                     seg_s1: NDArray, pose: NDArray, pose_cov: NDArray, settings: tuple) -> tuple:
    """:func:`houghloc.matching.associate_kernel` of the lines and references, then
    :func:`_solve` on the matches (with each match's reference normal β)."""
    li, rj, residual, cov, d2, n_cand, ambiguous, claims = associate_kernel(
        l_theta, l_rho, l_cov, l_s0, l_s1, r_theta, r_rho, r_beta, seg_ref, seg_s0, seg_s1,
        pose, pose_cov, settings)
    beta = r_beta[rj]  # each match's reference normal
    return (li, rj, residual, cov, d2, n_cand, ambiguous, claims, beta,
            _solve(cov, residual, beta, max_observable_sigma))


def _nothing_matched() -> Displacement:
    return Displacement(np.zeros(3), np.eye(3) * UNOBSERVED_VARIANCE, np.zeros((3, 3)), 0,
                        np.zeros((3, 0)), np.eye(3), 0.0, 0)


def _displacement(matches: Matches, beta: NDArray, max_observable_sigma: float, terms: NDArray,
                  info: NDArray, b: NDArray, full: bool, delta: NDArray, cov: NDArray,
                  chi2_total: float) -> Displacement:
    """The displacement from :func:`_solve`'s sums and, when the whole pose is observable, its
    solution; otherwise the solution confined to the observable directions
    (:func:`_partial_solution`)."""
    if full:  # the usual case: the whole pose is observed
        return Displacement(delta, cov, info, 3, _FULL, _NONE, chi2_total,
                            max(2 * len(matches) - 3, 0), matches, beta)
    u, v, delta, cov, chi2_total = _partial_solution(terms, info, b, max_observable_sigma,
                                                     UNOBSERVED_VARIANCE)
    rank = u.shape[1]
    return Displacement(delta, cov, info, rank, u, v, chi2_total,
                        max(2 * len(matches) - rank, 0), matches, beta)


@njit
def _partial_solution(terms: NDArray, info: NDArray, b: NDArray, max_observable_sigma: float,
                      unobserved_variance: float) -> tuple:
    """The solution confined to the observable directions, when the whole pose is not.

    Observable translation directions: eigenvectors of the Schur complement
    Λ_tt − Λ_tθ Λ_θθ⁻¹ Λ_θt (θ marginalised out), a symmetric 2×2 solved in closed form; θ is
    always observed. With U those directions (3×k) and V the others: Δ = U (UᵀΛU)⁻¹ Uᵀb,
    C = U (UᵀΛU)⁻¹ Uᵀ + ``unobserved_variance`` V Vᵀ. Returns U, V, Δ, C and the post-fit χ²."""
    l_xx, l_xy, l_yy, l_xt, l_yt, l_tt = terms[0], terms[1], terms[2], terms[3], terms[4], terms[5]
    a, bb, d = l_xx - l_xt * l_xt / l_tt, l_xy - l_xt * l_yt / l_tt, l_yy - l_yt * l_yt / l_tt
    half_gap = math.hypot(0.5 * (a - d), bb)
    phi = 0.5 * math.atan2(2.0 * bb, a - d)  # direction of the larger eigenvalue
    lam = (0.5 * (a + d) - half_gap, 0.5 * (a + d) + half_gap)
    dirs = ((-math.sin(phi), math.cos(phi)), (math.cos(phi), math.sin(phi)))
    seen = np.zeros(2, np.bool_)
    k = 1
    for m in range(2):
        seen[m] = lam[m] > 1.0 / max_observable_sigma**2
        k += seen[m]
    u = np.zeros((3, k))
    v = np.zeros((3, 3 - k))
    u[2, 0] = 1.0
    iu, iv = 1, 0
    for m in range(2):
        if seen[m]:
            u[0, iu], u[1, iu] = dirs[m]
            iu += 1
        else:
            v[0, iv], v[1, iv] = dirs[m]
            iv += 1
    reduced = u.T @ info @ u
    cov_u = inverse_small(reduced)
    delta = u @ (cov_u @ (u.T @ b))
    cov = u @ cov_u @ u.T + unobserved_variance * (v @ v.T)
    cov = 0.5 * (cov + cov.T)
    # post-fit χ² = min over Δ of Σ (r − JΔ)ᵀ W (r − JΔ) = rᵀWr − bᵀΔ (normal equations)
    chi2 = terms[9] - (b[0] * delta[0] + b[1] * delta[1] + b[2] * delta[2])
    return u, v, delta, cov, max(chi2, 0.0)


@njit
def _solve(cov: NDArray, residual: NDArray, beta: NDArray, max_observable_sigma: float
           ) -> tuple:
    """The normal equations' sums, Λ, b and, when the whole pose is observable, its solution
    (:func:`_normal_equations`, :func:`_full_rank_solution`), in one call."""
    terms = _normal_equations(cov, residual, np.cos(beta), np.sin(beta))
    info = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            info[i, j] = terms[_INFO_LAYOUT[i, j]]
    b = -terms[6:9]
    full, delta, out_cov, chi2 = _full_rank_solution(terms, info, b, max_observable_sigma)
    return terms, info, b, full, delta, out_cov, chi2


@njit
def _normal_equations(cov: NDArray, residual: NDArray, nx: NDArray, ny: NDArray) -> NDArray:
    """The ten sums of the normal equations over all matches.

    Per match, with n = (cos β, sin β), W = C⁻¹ = [[w00, w01], [w01, w11]] and residual r:
    Jᵀ W J = [[w11 n nᵀ, w01 n], [w01 nᵀ, w00]],
    Jᵀ W r = [−n (w01 r₀ + w11 r₁), −(w00 r₀ + w01 r₁)]; and rᵀ W r. Returns
    (Λ_xx, Λ_xy, Λ_yy, Λ_xθ, Λ_yθ, Λ_θθ, −b_x, −b_y, −b_θ, rᵀWr).
    """
    terms = np.zeros(10)
    for m in range(len(nx)):
        det = cov[m, 0, 0] * cov[m, 1, 1] - cov[m, 0, 1] ** 2
        w00, w01, w11 = cov[m, 1, 1] / det, -cov[m, 0, 1] / det, cov[m, 0, 0] / det
        r0, r1 = residual[m, 0], residual[m, 1]
        wr = w01 * r0 + w11 * r1
        wr0 = w00 * r0 + w01 * r1
        terms[0] += w11 * nx[m] * nx[m]
        terms[1] += w11 * nx[m] * ny[m]
        terms[2] += w11 * ny[m] * ny[m]
        terms[3] += w01 * nx[m]
        terms[4] += w01 * ny[m]
        terms[5] += w00
        terms[6] += nx[m] * wr
        terms[7] += ny[m] * wr
        terms[8] += wr0
        terms[9] += r0 * wr0 + r1 * wr
    return terms


@njit
def _full_rank_solution(terms: NDArray, info: NDArray, b: NDArray, max_observable_sigma: float
                        ) -> tuple[bool, NDArray, NDArray, float]:
    """Δ = Λ⁻¹ b, its covariance Λ⁻¹ and the post-fit χ², when the whole pose is observable:
    the smaller eigenvalue of the Schur complement Λ_tt − Λ_tθ Λ_θθ⁻¹ Λ_θt (the translation's
    information with θ marginalised out) exceeds 1/``max_observable_sigma``². ``False`` (and
    nothing else meaningful) otherwise."""
    l_xx, l_xy, l_yy, l_xt, l_yt, l_tt = terms[0], terms[1], terms[2], terms[3], terms[4], terms[5]
    a, bb, d = l_xx - l_xt * l_xt / l_tt, l_xy - l_xt * l_yt / l_tt, l_yy - l_yt * l_yt / l_tt
    lam_small = 0.5 * (a + d) - math.hypot(0.5 * (a - d), bb)
    if not lam_small > 1.0 / max_observable_sigma**2:
        return False, b, info, 0.0
    cov = inverse_3x3(info)  # exactly symmetric, as Λ is
    delta = np.zeros(3)
    for i in range(3):
        delta[i] = cov[i, 0] * b[0] + cov[i, 1] * b[1] + cov[i, 2] * b[2]
    # post-fit χ² = min over Δ of Σ (r − JΔ)ᵀ W (r − JΔ) = rᵀWr − bᵀΔ (normal equations)
    chi2 = terms[9] - (b[0] * delta[0] + b[1] * delta[1] + b[2] * delta[2])
    return True, delta, cov, max(chi2, 0.0)

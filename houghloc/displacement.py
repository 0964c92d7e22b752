"""Pose correction from matched lines (DESIGN §3.5).

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

from houghloc.geometry import inverse_3x3
from houghloc.matching import Matches

UNOBSERVED_VARIANCE = 1.0e6  # m² (or rad²): finite, so no NaN downstream, and plainly "unknown"
_FULL = np.column_stack(((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
_NONE = np.zeros((3, 0))
_INFO_LAYOUT = np.array([[0, 1, 3], [1, 2, 4], [3, 4, 5]])  # Λ from its six distinct sums


@dataclass(frozen=True)
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
        post_0 = r[:, 0] + self.delta[2]  # the residual after the correction: r − J Δ
        post_1 = r[:, 1] + np.cos(self.beta) * self.delta[0] + np.sin(self.beta) * self.delta[1]
        det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2
        return (c[:, 1, 1] * post_0**2 - 2 * c[:, 0, 1] * post_0 * post_1
                + c[:, 0, 0] * post_1**2) / det


def estimate_displacement(matches: Matches, beta: NDArray[np.float64],
                          max_observable_sigma: float) -> Displacement:
    """Weighted least squares of Δ over all matches; ``beta`` is the reference normal per match."""
    if len(matches) == 0:
        z = np.zeros((3, 0))
        return Displacement(np.zeros(3), np.eye(3) * UNOBSERVED_VARIANCE, np.zeros((3, 3)), 0,
                            z, np.eye(3), 0.0, 0)
    # Per match, with n = (cos β, sin β), W = C⁻¹ = [[w00, w01], [w01, w11]] and residual r:
    # Jᵀ W J = [[w11 n nᵀ, w01 n], [w01 nᵀ, w00]],
    # Jᵀ W r = [−n (w01 r₀ + w11 r₁), −(w00 r₀ + w01 r₁)]; one column sum gives all entries.
    c = matches.cov
    det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2
    w00, w01, w11 = c[:, 1, 1] / det, -c[:, 0, 1] / det, c[:, 0, 0] / det
    nx, ny = np.cos(beta), np.sin(beta)
    r0, r1 = matches.residual[:, 0], matches.residual[:, 1]
    wr = w01 * r0 + w11 * r1
    wr0 = w00 * r0 + w01 * r1
    terms = np.array((w11 * nx * nx, w11 * nx * ny, w11 * ny * ny, w01 * nx, w01 * ny, w00,
                      nx * wr, ny * wr, wr0, r0 * wr0 + r1 * wr)).sum(axis=1)
    info = terms[_INFO_LAYOUT]
    b = -terms[6:9]

    # Observable translation directions: eigenvectors of the Schur complement
    # Λ_tt − Λ_tθ Λ_θθ⁻¹ Λ_θt (θ marginalised out), a symmetric 2×2 solved in closed form.
    l_xx, l_xy, l_yy, l_xt, l_yt, l_tt = terms[:6].tolist()
    a, bb, d = l_xx - l_xt * l_xt / l_tt, l_xy - l_xt * l_yt / l_tt, l_yy - l_yt * l_yt / l_tt
    half_gap = math.hypot(0.5 * (a - d), bb)
    lam_small = 0.5 * (a + d) - half_gap
    if lam_small > 1.0 / max_observable_sigma**2:  # the usual case: the whole pose is observed
        cov = inverse_3x3(info)  # exactly symmetric, as Λ is
        delta = cov @ b
        u, v = _FULL, _NONE
    else:
        lam = (lam_small, 0.5 * (a + d) + half_gap)
        phi = 0.5 * math.atan2(2.0 * bb, a - d)  # direction of the larger eigenvalue
        dirs = ((-math.sin(phi), math.cos(phi)), (math.cos(phi), math.sin(phi)))
        basis = [(0.0, 0.0, 1.0)]
        blind = []
        for lam_k, (vx, vy) in zip(lam, dirs, strict=True):
            (basis if lam_k > 1.0 / max_observable_sigma**2 else blind).append((vx, vy, 0.0))
        u = np.array(basis).T
        v = np.array(blind).T
        cov_u = np.linalg.inv(u.T @ info @ u)
        delta = u @ (cov_u @ (u.T @ b))
        cov = u @ cov_u @ u.T + UNOBSERVED_VARIANCE * (v @ v.T)
        cov = 0.5 * (cov + cov.T)
    # post-fit χ² = min over Δ of Σ (r − JΔ)ᵀ W (r − JΔ) = rᵀWr − bᵀΔ (normal equations)
    chi2_total = max(float(terms[9] - b @ delta), 0.0)
    rank = u.shape[1]
    return Displacement(delta, cov, info, rank, u, v, chi2_total,
                        max(2 * len(matches) - rank, 0), matches, beta)

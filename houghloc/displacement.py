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

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from houghloc.matching import Matches, hough_jacobians, inv2

UNOBSERVED_VARIANCE = 1.0e6  # m² (or rad²): finite, so no NaN downstream, and plainly "unknown"


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


def estimate_displacement(matches: Matches, beta: NDArray[np.float64],
                          max_observable_sigma: float) -> Displacement:
    """Weighted least squares of Δ over all matches; ``beta`` is the reference normal per match."""
    if len(matches) == 0:
        z = np.zeros((3, 0))
        return Displacement(np.zeros(3), np.eye(3) * UNOBSERVED_VARIANCE, np.zeros((3, 3)), 0,
                            z, np.eye(3), 0.0, 0)
    jac = hough_jacobians(beta)  # M×2×3
    w = inv2(matches.cov)  # Cᵢ⁻¹
    jt_w = jac.transpose(0, 2, 1) @ w  # M×3×2
    info = (jt_w @ jac).sum(axis=0)  # Λ = Σ Jᵀ C⁻¹ J
    b = np.einsum("mij,mj->i", jt_w, matches.residual)  # Σ Jᵀ C⁻¹ r
    info = 0.5 * (info + info.T)

    # Observable translation directions: eigenvectors of the Schur complement
    # Λ_tt − Λ_tθ Λ_θθ⁻¹ Λ_θt (θ marginalised out).
    basis = [np.array([0.0, 0.0, 1.0])]
    blind = []
    schur = info[:2, :2] - np.outer(info[:2, 2], info[2, :2]) / info[2, 2]
    lam, vec = np.linalg.eigh(schur)
    for k in range(2):
        direction = np.array([vec[0, k], vec[1, k], 0.0])
        if lam[k] > 1.0 / max_observable_sigma**2:
            basis.append(direction)
        else:
            blind.append(direction)
    u = np.column_stack(basis)
    v = np.column_stack(blind) if blind else np.zeros((3, 0))
    info_u = u.T @ info @ u
    cov_u = np.linalg.inv(info_u)
    delta = u @ (cov_u @ (u.T @ b))
    cov = u @ cov_u @ u.T + UNOBSERVED_VARIANCE * (v @ v.T)
    post = matches.residual - np.einsum("mij,j->mi", jac, delta)
    chi2_total = float(np.einsum("mi,mij,mj->", post, w, post))
    rank = u.shape[1]
    return Displacement(delta, 0.5 * (cov + cov.T), info, rank, u, v, chi2_total,
                        max(2 * len(matches) - rank, 0))

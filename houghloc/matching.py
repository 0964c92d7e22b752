"""Correspondence between observed lines and the map's reference points (DESIGN §3.5).

Tracking mode, the paper's strategy (i): each observed line is compared with every predicted
reference point by the Mahalanobis distance whose covariance adds the pose uncertainty projected
into the Hough domain (J P Jᵀ) to the line's own (C); pairs outside the χ²(2) gate, or whose
observed piece does not overlap the segment's extent, are not candidates. A line with two
candidates, or two incompatible lines claiming one reference, is ambiguous: reported, not guessed.

Hough-domain Jacobian of a reference seen from pose (x, y, θ), with β its world normal angle:
    θ_r = β − θ,   ρ_r = r − (x cos β + y sin β)   ⇒   J = [[0, 0, −1], [−cos β, −sin β, 0]].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from houghloc.config import HoughConfig
from houghloc.geometry import TWO_PI
from houghloc.refine import Lines
from houghloc.segment_map import References


@dataclass(frozen=True)
class Matches:
    """Accepted pairs and what was left out.

    ``line``/``ref`` index the observed lines and the reference table; ``residual`` is z − h(x̂)
    (Δθ wrapped, Δρ) in the representation that fits; ``cov`` the line's covariance in that
    representation (K×2×2); ``d2`` the squared Mahalanobis distance.
    """

    line: NDArray[np.intp]
    ref: NDArray[np.intp]
    residual: NDArray[np.float64]
    cov: NDArray[np.float64]
    d2: NDArray[np.float64]
    ambiguous_lines: NDArray[np.intp] = field(default_factory=lambda: np.empty(0, np.intp))
    reasons: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.line)


def hough_jacobians(beta: NDArray[np.float64]) -> NDArray[np.float64]:
    """J (L×2×3) of (θ_r, ρ_r) with respect to the pose, for world normal angles β."""
    jac = np.zeros((len(beta), 2, 3))
    jac[:, 0, 2] = -1.0
    jac[:, 1, 0] = -np.cos(beta)
    jac[:, 1, 1] = -np.sin(beta)
    return jac


def inv2(m: NDArray) -> NDArray:
    """Inverses of a stack of 2×2 matrices (closed form: no LAPACK call per matrix)."""
    inv = np.empty_like(m)
    det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
    inv[..., 0, 0] = m[..., 1, 1] / det
    inv[..., 1, 1] = m[..., 0, 0] / det
    inv[..., 0, 1] = -m[..., 0, 1] / det
    inv[..., 1, 0] = -m[..., 1, 0] / det
    return inv


_GATES: dict[float, float] = {}


def gate_threshold(probability: float, dof: int = 2) -> float:
    key = probability + 10 * dof
    if key not in _GATES:
        _GATES[key] = float(chi2.ppf(probability, dof))
    return _GATES[key]


def associate(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
              config: HoughConfig) -> Matches:
    """Gate every (line, reference) pair, check extents, resolve one-to-one or flag ambiguity."""
    k, n_ref = len(lines), len(refs)
    if k == 0 or n_ref == 0:
        e = np.empty(0, np.intp)
        return Matches(e, e, np.empty((0, 2)), np.empty((0, 2, 2)), np.empty(0))
    jac = hough_jacobians(refs.beta)
    s_pose = jac @ pose_cov @ jac.transpose(0, 2, 1)  # L×2×2: J P Jᵀ

    # Both representations of each observed line: (θ, ρ) and (θ + π, −ρ) with cov(θ,ρ) negated.
    flip_cov = lines.cov * np.array([[1.0, -1.0], [-1.0, 1.0]])
    best_d2 = np.full((k, n_ref), np.inf)
    best_res = np.zeros((k, n_ref, 2))
    best_flip = np.zeros((k, n_ref), dtype=bool)
    for flipped, theta, rho, cov in ((False, lines.theta, lines.rho, lines.cov),
                                     (True, lines.theta + np.pi, -lines.rho, flip_cov)):
        res = np.empty((k, n_ref, 2))
        res[..., 0] = (theta[:, None] - refs.theta[None, :] + np.pi) % TWO_PI - np.pi
        res[..., 1] = rho[:, None] - refs.rho[None, :]
        s_inv = inv2(s_pose[None, :, :, :] + cov[:, None, :, :])
        d2 = np.einsum("kli,klij,klj->kl", res, s_inv, res)
        better = d2 < best_d2
        best_d2 = np.where(better, d2, best_d2)
        best_res = np.where(better[..., None], res, best_res)
        best_flip = np.where(better, flipped, best_flip)

    candidate = (best_d2 <= gate_threshold(config.gate_probability)) & _extents_overlap(
        lines, refs, pose, pose_cov, config)
    return _resolve(lines, candidate, best_d2, best_res, best_flip, flip_cov, config)


def _extents_overlap(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
                     config: HoughConfig) -> NDArray[np.bool_]:
    """K×L: does the observed piece, placed in the world at ``pose``, lie on the line's segments?

    Along the reference direction t = (−sin β, cos β) a robot-frame coordinate s maps to
    s + (x, y)·t. The fraction of the observed piece covered by the segments (each widened by a
    slack that grows with the pose uncertainty along t and with the heading uncertainty times the
    distance) must reach ``min_extent_coverage``: a wall seen through a goal mouth or a door is not
    the wall beside the opening.
    """
    t = np.column_stack((-np.sin(refs.beta), np.cos(refs.beta)))  # L×2
    offset = t @ pose[:2]
    var_along = np.einsum("li,ij,lj->l", t, pose_cov[:2, :2], t)  # L
    reach = np.maximum(np.abs(lines.s0), np.abs(lines.s1))  # K
    sigma = np.sqrt(np.maximum(var_along[None, :], 0.0)
                    + reach[:, None] ** 2 * max(pose_cov[2, 2], 0.0))  # K×L
    slack = config.extent_margin + 3.0 * sigma[:, refs.seg_ref]  # K×S
    seg_off = offset[refs.seg_ref]
    length = np.maximum(lines.s1 - lines.s0, 1e-6)[:, None]
    seg_lo = refs.seg_s0[None, :] - slack
    seg_hi = refs.seg_s1[None, :] + slack
    covered = np.zeros((len(lines), len(refs)))
    # the line may have been seen with the flipped normal: then its direction is reversed
    for lo, hi in ((lines.s0, lines.s1), (-lines.s1, -lines.s0)):
        lo_w = lo[:, None] + seg_off[None, :]
        hi_w = hi[:, None] + seg_off[None, :]
        overlap = np.clip(np.minimum(hi_w, seg_hi) - np.maximum(lo_w, seg_lo), 0.0, None)
        per_ref = np.zeros_like(covered)
        np.add.at(per_ref.T, refs.seg_ref, overlap.T)  # sum the segments of each line
        covered = np.maximum(covered, per_ref / length)
    return covered >= config.min_extent_coverage


def _resolve(lines: Lines, candidate: NDArray, d2: NDArray, res: NDArray, flip: NDArray,
             flip_cov: NDArray, config: HoughConfig) -> Matches:
    reasons: list[str] = []
    n_cand = candidate.sum(axis=1)
    ambiguous = n_cand >= 2
    for i in np.flatnonzero(ambiguous)[:3]:
        reasons.append(f"line θ={np.degrees(lines.theta[i]):.1f}° ρ={lines.rho[i]:.2f} m fits "
                       f"{int(n_cand[i])} map lines")
    single = candidate & (n_cand == 1)[:, None]
    li, rj = np.nonzero(single)
    # Two lines claiming one reference: the same wall seen twice is fine (they agree with each
    # other); otherwise neither can be trusted.
    claims = np.bincount(rj, minlength=candidate.shape[1])
    shared = claims[rj] >= 2
    if shared.any():
        for j in np.unique(rj[shared]):
            idx = li[rj == j]
            r = res[idx, j]
            spread = np.abs(r - r.mean(axis=0))
            sig = np.sqrt(np.stack((lines.cov[idx, 0, 0], lines.cov[idx, 1, 1]), -1))
            if np.any(spread > 3.0 * sig + np.array([config.theta_step / 4, config.rho_step / 4])):
                ambiguous[idx] = True
                reasons.append(f"{len(idx)} lines claim one map line")
        keep = ~ambiguous[li]
        li, rj = li[keep], rj[keep]
    cov = np.where(flip[li, rj][:, None, None], flip_cov[li], lines.cov[li])
    return Matches(li, rj, res[li, rj], cov, d2[li, rj], np.flatnonzero(ambiguous),
                   tuple(reasons))

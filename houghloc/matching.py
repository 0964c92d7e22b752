"""Correspondence between observed lines and the map's reference points (DESIGN §3.5).

Tracking mode, the paper's strategy (i): each observed line is compared with every predicted
reference point by the Mahalanobis distance whose covariance adds the pose uncertainty projected
into the Hough domain (J P Jᵀ) to the line's own (C); pairs outside the χ²(2) gate, or whose
observed piece does not overlap the segment's extent, are not candidates. A line with two
candidates, or two incompatible lines claiming one reference, is ambiguous: reported, not guessed.

Hough-domain Jacobian of a reference seen from pose (x, y, θ), with β its world normal angle:
    θ_r = β − θ,   ρ_r = r − (x cos β + y sin β)   ⇒   J = [[0, 0, −1], [−cos β, −sin β, 0]];
the 2×2 blocks J P Jᵀ and the Mahalanobis distances are written out elementwise below.
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

    def without(self, index: int, reason: str) -> Matches:
        """These matches less one (an outlier found by the displacement's consistency test)."""
        keep = np.arange(len(self.line)) != index
        return Matches(self.line[keep], self.ref[keep], self.residual[keep], self.cov[keep],
                       self.d2[keep], self.ambiguous_lines, (*self.reasons, reason))


_GATES: dict[float, float] = {}


def gate_threshold(probability: float, dof: int = 2) -> float:
    key = probability + 10 * dof
    if key not in _GATES:
        _GATES[key] = float(chi2.ppf(probability, dof))
    return _GATES[key]


def associate(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
              config: HoughConfig) -> Matches:
    """Gate every (line, reference) pair, check extents, resolve one-to-one or flag ambiguity.

    S = J P Jᵀ + C per pair, written out for 2×2 blocks: with J = [[0, 0, −1], [−nᵀ, 0]],
    J P Jᵀ = [[P_θθ, nᵀP_tθ], [nᵀP_tθ, nᵀP_tt n]].
    """
    k, n_ref = len(lines), len(refs)
    if k == 0 or n_ref == 0:
        e = np.empty(0, np.intp)
        return Matches(e, e, np.empty((0, 2)), np.empty((0, 2, 2)), np.empty(0))
    cb, sb = np.cos(refs.beta), np.sin(refs.beta)
    p_tt = pose_cov[2, 2]
    p_rt = cb * pose_cov[0, 2] + sb * pose_cov[1, 2]  # L: cov(ρ, θ) from the pose
    p_rr = cb * cb * pose_cov[0, 0] + 2 * cb * sb * pose_cov[0, 1] + sb * sb * pose_cov[1, 1]
    c_tt = lines.cov[:, 0, 0][:, None]
    c_tr = lines.cov[:, 0, 1][:, None]
    c_rr = lines.cov[:, 1, 1][:, None]
    s00 = p_tt + c_tt  # K×L
    s11 = p_rr[None, :] + c_rr
    # Both representations of each observed line: (θ, ρ) and (θ + π, −ρ); the latter negates
    # cov(θ, ρ). The one closer to the reference is kept.
    d_theta = (lines.theta[:, None] - refs.theta[None, :] + np.pi) % TWO_PI - np.pi
    d_theta_flip = (d_theta + TWO_PI) % TWO_PI - np.pi  # (θ + π) − θ_ref, wrapped
    d_rho = lines.rho[:, None] - refs.rho[None, :]
    d_rho_flip = -lines.rho[:, None] - refs.rho[None, :]
    s01 = p_rt[None, :] + c_tr
    s01_flip = p_rt[None, :] - c_tr
    d2 = _quadratic(d_theta, d_rho, s00, s01, s11)
    d2_flip = _quadratic(d_theta_flip, d_rho_flip, s00, s01_flip, s11)
    flip = d2_flip < d2
    best_d2 = np.where(flip, d2_flip, d2)
    res = np.stack((np.where(flip, d_theta_flip, d_theta), np.where(flip, d_rho_flip, d_rho)), -1)
    gated = best_d2 <= gate_threshold(config.gate_probability)
    candidate = gated
    if gated.any():
        candidate = gated & _extents_overlap(lines, refs, pose, pose_cov, config)
    flip_cov = lines.cov * np.array([[1.0, -1.0], [-1.0, 1.0]])
    return _resolve(lines, candidate, best_d2, res, flip, flip_cov, config)


def _quadratic(a: NDArray, b: NDArray, s00: NDArray, s01: NDArray, s11: NDArray) -> NDArray:
    """(a, b) S⁻¹ (a, b)ᵀ for symmetric 2×2 S, elementwise."""
    det = s00 * s11 - s01 * s01
    return (s11 * a * a - 2.0 * s01 * a * b + s00 * b * b) / det


def _extents_overlap(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
                     config: HoughConfig) -> NDArray[np.bool_]:
    """K×L: does the observed piece, placed in the world at ``pose``, lie on the line's segments?

    Along the reference direction t = (−sin β, cos β) a robot-frame coordinate s maps to
    s + (x, y)·t. The fraction of the observed piece covered by the segments (each widened by a
    slack that grows with the pose uncertainty along t and with the heading uncertainty times the
    distance) must reach ``min_extent_coverage``: a wall seen through a goal mouth or a door is not
    the wall beside the opening.
    """
    tx, ty = -np.sin(refs.beta), np.cos(refs.beta)
    offset = tx * pose[0] + ty * pose[1]  # L
    var_along = tx * tx * pose_cov[0, 0] + 2 * tx * ty * pose_cov[0, 1] + ty * ty * pose_cov[1, 1]
    reach = np.maximum(np.abs(lines.s0), np.abs(lines.s1))  # K
    seg = refs.seg_ref
    sigma = np.sqrt(np.maximum(var_along[seg], 0.0)[None, :]
                    + (reach**2 * max(pose_cov[2, 2], 0.0))[:, None])  # K×S
    slack = config.extent_margin + 3.0 * sigma
    seg_lo = refs.seg_s0[None, :] - slack - offset[seg][None, :]  # segment in robot coordinates
    seg_hi = refs.seg_s1[None, :] + slack - offset[seg][None, :]
    s0, s1 = lines.s0[:, None], lines.s1[:, None]
    # the line may have been seen with the flipped normal: then its direction is reversed
    overlap = np.maximum(np.clip(np.minimum(s1, seg_hi) - np.maximum(s0, seg_lo), 0.0, None),
                         np.clip(np.minimum(-s0, seg_hi) - np.maximum(-s1, seg_lo), 0.0, None))
    onehot = np.zeros((len(seg), len(refs)))
    onehot[np.arange(len(seg)), seg] = 1.0
    covered = (overlap @ onehot) / np.maximum(lines.s1 - lines.s0, 1e-6)[:, None]
    return covered >= config.min_extent_coverage


def _resolve(lines: Lines, candidate: NDArray, d2: NDArray, res: NDArray, flip: NDArray,
             flip_cov: NDArray, config: HoughConfig) -> Matches:
    reasons: list[str] = []
    if config.nearest_neighbour_only:  # keep only each line's nearest candidate: no ambiguity
        nearest = np.where(candidate, d2, np.inf).argmin(axis=1)
        candidate = candidate & (np.arange(candidate.shape[1])[None, :] == nearest[:, None])
    n_cand = candidate.sum(axis=1)
    if config.decisive_d2_margin is not None and (n_cand >= 2).any():
        # A line whose best candidate beats every other by a clear likelihood ratio (the d²
        # already carry the pose's uncertainty) is not ambiguous: it keeps only that candidate.
        d2c = np.where(candidate, d2, np.inf)
        two = np.partition(d2c, 1, axis=1)[:, :2]
        gap = np.where(n_cand >= 2, two[:, 1] - np.where(n_cand >= 2, two[:, 0], 0.0), 0.0)
        clear = gap >= config.decisive_d2_margin
        if clear.any():
            best = d2c.argmin(axis=1)
            candidate = candidate.copy()
            candidate[clear] = False
            candidate[np.flatnonzero(clear), best[clear]] = True
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

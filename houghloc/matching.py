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
from functools import lru_cache

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
    pairs: PairTable | None = None  # the K×L tables they were chosen from (for re-gating)

    def __len__(self) -> int:
        return len(self.line)

    def without(self, index: int) -> Matches:
        """These matches less one (an outlier found by the displacement's consistency test)."""
        keep = np.arange(len(self.line)) != index
        return Matches(self.line[keep], self.ref[keep], self.residual[keep], self.cov[keep],
                       self.d2[keep], self.ambiguous_lines, self.reasons, self.pairs)


@dataclass(frozen=True)
class PairTable:
    """Every (line, reference) pair of one association: residuals, representation, and whether
    the observed piece lies on the reference's segments."""

    d_theta: NDArray[np.float64]  # K×L, wrapped
    d_rho: NDArray[np.float64]  # K×L
    sign: NDArray[np.float64]  # K×L: +1, or −1 where the flipped representation (θ + π, −ρ) fits
    on_segments: NDArray[np.bool_]  # K×L extent check (all True where it was not needed)
    cos_beta: NDArray[np.float64]  # L
    sin_beta: NDArray[np.float64]  # L


@lru_cache(maxsize=64)
def gate_threshold(probability: float, dof: int = 2) -> float:
    """The χ²(dof) quantile at ``probability``: a gate on squared Mahalanobis distances."""
    return float(chi2.ppf(probability, dof))


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
    p_rt = cb * pose_cov[0, 2] + sb * pose_cov[1, 2]  # L: cov(ρ, θ) from the pose
    p_rr = cb * (cb * pose_cov[0, 0] + 2 * sb * pose_cov[0, 1]) + sb * sb * pose_cov[1, 1]
    # Each observed line has two representations, (θ, ρ) and (θ + π, −ρ) (which negates its
    # cov(θ, ρ)); the one whose normal points the reference's way (|Δθ| ≤ π/2) is compared.
    d_theta = (lines.theta[:, None] - refs.theta + np.pi) % TWO_PI - np.pi  # K×L
    flip = np.abs(d_theta) > 0.5 * np.pi
    sign = 1.0 - 2.0 * flip
    d_theta -= np.copysign(np.pi, d_theta) * flip
    d_rho = sign * lines.rho[:, None] - refs.rho
    gated = _gate(lines, d_theta, d_rho, sign, p_rt, p_rr, pose_cov, config)
    on_segments = np.ones_like(flip)
    if gated[0].any():
        on_segments = _extents_overlap(lines, refs, cb, sb, pose, pose_cov, flip, config)
    table = PairTable(d_theta, d_rho, sign, on_segments, cb, sb)
    return _resolve(lines, gated[0] & on_segments, gated[1], table, config)


def reassociate(matches: Matches, lines: Lines, refs: References, pose: NDArray,
                offset: NDArray, pose_cov: NDArray, config: HoughConfig) -> Matches:
    """The association again at ``pose``, moved by ``offset`` = (Δx, Δy, Δθ) from where
    ``matches`` were made, with a new pose covariance (sharper: the gates shrink and lines that
    fitted two references may fit one).

    References move linearly with the pose (θ_r − Δθ, ρ_r − n·Δt), so the residuals are updated
    rather than recomputed.
    """
    table = matches.pairs
    if table is None or len(lines) == 0:
        return matches
    d_theta = table.d_theta + offset[2]
    d_rho = table.d_rho + (table.cos_beta * offset[0] + table.sin_beta * offset[1])
    cb, sb = table.cos_beta, table.sin_beta
    p_rt = cb * pose_cov[0, 2] + sb * pose_cov[1, 2]
    p_rr = cb * (cb * pose_cov[0, 0] + 2 * sb * pose_cov[0, 1]) + sb * sb * pose_cov[1, 1]
    gated, d2 = _gate(lines, d_theta, d_rho, table.sign, p_rt, p_rr, pose_cov, config)
    on_segments = table.on_segments
    if gated.any():
        on_segments = _extents_overlap(lines, refs, cb, sb, pose, pose_cov, table.sign < 0,
                                       config)
    moved = PairTable(d_theta, d_rho, table.sign, on_segments, cb, sb)
    return _resolve(lines, gated & on_segments, d2, moved, config)


def _gate(lines: Lines, d_theta: NDArray, d_rho: NDArray, sign: NDArray, p_rt: NDArray,
          p_rr: NDArray, pose_cov: NDArray, config: HoughConfig) -> tuple[NDArray, NDArray]:
    """χ²(2) gate on every pair: d² = rᵀ S⁻¹ r with S = J P Jᵀ + C written out (2×2)."""
    s00 = pose_cov[2, 2] + lines.cov[:, 0, 0][:, None]
    s01 = p_rt + sign * lines.cov[:, 0, 1][:, None]
    s11 = p_rr + lines.cov[:, 1, 1][:, None]
    d2 = (s11 * d_theta * d_theta - 2.0 * s01 * d_theta * d_rho + s00 * d_rho * d_rho) / (
        s00 * s11 - s01 * s01)
    return d2 <= gate_threshold(config.gate_probability), d2


def _extents_overlap(lines: Lines, refs: References, cos_beta: NDArray, sin_beta: NDArray,
                     pose: NDArray, pose_cov: NDArray, flip: NDArray[np.bool_],
                     config: HoughConfig) -> NDArray[np.bool_]:
    """K×L: does the observed piece, placed in the world at ``pose``, lie on the line's segments?

    Along the reference direction t = (−sin β, cos β) a robot-frame coordinate s maps to
    s + (x, y)·t (−s when the line is seen with the flipped normal). The fraction of the observed
    piece covered by the segments (each widened by a slack that grows with the pose uncertainty
    along t and with the heading uncertainty times the distance) must reach
    ``min_extent_coverage``: a wall seen through a goal mouth or a door is not the wall beside
    the opening.
    """
    tx, ty = -sin_beta, cos_beta
    seg = refs.seg_ref
    offset = (tx * pose[0] + ty * pose[1])[seg]  # S
    var_along = (tx * (tx * pose_cov[0, 0] + 2 * ty * pose_cov[0, 1]) + ty * ty * pose_cov[1, 1])
    reach_sq = np.maximum(np.abs(lines.s0), np.abs(lines.s1)) ** 2  # K
    slack = config.extent_margin + 3.0 * np.sqrt(
        np.maximum(var_along[seg], 0.0) + (reach_sq * max(pose_cov[2, 2], 0.0))[:, None])  # K×S
    seg_lo = refs.seg_s0 - offset - slack  # the segments in robot coordinates
    seg_hi = refs.seg_s1 - offset + slack
    flip_s = flip[:, seg]
    s0 = np.where(flip_s, -lines.s1[:, None], lines.s0[:, None])
    s1 = np.where(flip_s, -lines.s0[:, None], lines.s1[:, None])
    overlap = np.maximum(np.minimum(s1, seg_hi) - np.maximum(s0, seg_lo), 0.0)
    covered = overlap @ _one_hot(seg, len(refs))
    return covered >= config.min_extent_coverage * np.maximum(lines.s1 - lines.s0, 1e-6)[:, None]


def _one_hot(index: NDArray[np.intp], n: int) -> NDArray[np.float64]:
    """len(index)×n matrix with a one in each row's column ``index``: sums rows into groups."""
    return (index[:, None] == np.arange(n)).astype(np.float64)


def _resolve(lines: Lines, candidate: NDArray, d2: NDArray, table: PairTable,
             config: HoughConfig) -> Matches:
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
            r = np.column_stack((table.d_theta[idx, j], table.d_rho[idx, j]))
            spread = np.abs(r - r.mean(axis=0))
            sig = np.sqrt(np.stack((lines.cov[idx, 0, 0], lines.cov[idx, 1, 1]), -1))
            if np.any(spread > 3.0 * sig + np.array([config.theta_step / 4, config.rho_step / 4])):
                ambiguous[idx] = True
                reasons.append(f"{len(idx)} lines claim one map line")
        keep = ~ambiguous[li]
        li, rj = li[keep], rj[keep]
    cov = lines.cov[li]
    cov[:, 0, 1] *= table.sign[li, rj]  # the flipped representation negates cov(θ, ρ)
    cov[:, 1, 0] = cov[:, 0, 1]
    return Matches(li, rj, np.array((table.d_theta[li, rj], table.d_rho[li, rj])).T, cov,
                   d2[li, rj], np.flatnonzero(ambiguous), tuple(reasons), table)

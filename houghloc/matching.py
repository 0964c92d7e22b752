"""Correspondence between observed lines and the map's reference points (docs/method.md §5).

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

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from houghloc.config import HoughConfig, derived
from houghloc.geometry import TWO_PI
from houghloc.jit import njit
from houghloc.refine import Lines
from houghloc.segment_map import References


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
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
    # the K×L table they were chosen from, when it was moved from the references' prediction (for
    # re-gating); None: the lines against the references as predicted, recomputed when needed
    pairs: PairTable | None = None

    def __len__(self) -> int:
        return len(self.line)

    def without(self, index: int) -> Matches:
        """These matches less one (an outlier found by the displacement's consistency test)."""
        keep = np.arange(len(self.line)) != index
        return Matches(self.line[keep], self.ref[keep], self.residual[keep], self.cov[keep],
                       self.d2[keep], self.ambiguous_lines, self.reasons, self.pairs)


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
class PairTable:
    """Every (line, reference) pair of one association: residuals and representation."""

    d_theta: NDArray[np.float64]  # K×L, wrapped
    d_rho: NDArray[np.float64]  # K×L
    sign: NDArray[np.float64]  # K×L: +1, or −1 where the flipped representation (θ + π, −ρ) fits
    cos_beta: NDArray[np.float64]  # L
    sin_beta: NDArray[np.float64]  # L


@lru_cache(maxsize=64)
def gate_threshold(probability: float, dof: int = 2) -> float:
    """The χ²(dof) quantile at ``probability``: a gate on squared Mahalanobis distances
    (memoised: SciPy's quantile costs tens of microseconds, and a scan asks a few times)."""
    return float(chi2.ppf(probability, dof))


def associate(lines: Lines, refs: References, pose: NDArray, pose_cov: NDArray,
              config: HoughConfig) -> Matches:
    """Gate every (line, reference) pair, check extents, resolve one-to-one or flag ambiguity.

    Each observed line has two representations, (θ, ρ) and (θ + π, −ρ) (which negates its
    cov(θ, ρ)); the one whose normal points the reference's way (|Δθ| ≤ π/2) is compared.
    """
    if len(lines) == 0 or len(refs) == 0:
        e = np.empty(0, np.intp)
        return Matches(e, e, np.empty((0, 2)), np.empty((0, 2, 2)), np.empty(0))
    return matches_found(lines, None, *associate_kernel(
        lines.theta, lines.rho, np.ascontiguousarray(lines.cov), lines.s0, lines.s1, refs.theta,
        refs.rho, refs.beta, refs.seg_ref, refs.seg_s0, refs.seg_s1,
        np.ascontiguousarray(pose, dtype=float), np.ascontiguousarray(pose_cov, dtype=float),
        match_settings(config)))


def reassociate(matches: Matches, lines: Lines, refs: References, pose: NDArray,
                offset: NDArray, pose_cov: NDArray, config: HoughConfig) -> Matches:
    """The association again at ``pose``, moved by ``offset`` = (Δx, Δy, Δθ) from where
    ``matches`` were made, with a new pose covariance (sharper: the gates shrink and lines that
    fitted two references may fit one).

    References move linearly with the pose (θ_r − Δθ, ρ_r − n·Δt), so the residuals are updated
    rather than recomputed.
    """
    if len(lines) == 0 or len(refs) == 0:
        return matches
    table = matches.pairs if matches.pairs is not None else pair_table(lines, refs)
    cb, sb = table.cos_beta, table.sin_beta
    moved = PairTable(table.d_theta + offset[2], table.d_rho + (cb * offset[0] + sb * offset[1]),
                      table.sign, cb, sb)
    return _match(lines, refs, moved, pose, pose_cov, config)


def pair_table(lines: Lines, refs: References) -> PairTable:
    """Every (line, reference) pair's residuals and representation (:func:`_pairs`)."""
    d_theta, d_rho, sign = _pairs(lines.theta, lines.rho, refs.theta, refs.rho)
    return PairTable(d_theta, d_rho, sign, np.cos(refs.beta), np.sin(refs.beta))


def _match(lines: Lines, refs: References, table: PairTable, pose: NDArray, pose_cov: NDArray,
           config: HoughConfig) -> Matches:
    """Gate, extent check and resolution of one pair table (:func:`_match_kernel`), with the
    reasons for what was left out."""
    return matches_found(lines, table, *_match_kernel(
        np.ascontiguousarray(lines.cov), lines.s0, lines.s1, table.d_theta, table.d_rho,
        table.sign, table.cos_beta, table.sin_beta, refs.seg_ref, refs.seg_s0, refs.seg_s1,
        np.ascontiguousarray(pose, dtype=float), np.ascontiguousarray(pose_cov, dtype=float),
        match_settings(config)))


def match_settings(config: HoughConfig) -> tuple[float, float, float, bool, float, float, float]:
    """The association's settings, in :func:`_match_kernel`'s order (once per configuration)."""
    def build() -> tuple[float, float, float, bool, float, float, float]:
        margin = -1.0 if config.decisive_d2_margin is None else config.decisive_d2_margin
        return (gate_threshold(config.gate_probability), config.extent_margin,
                config.min_extent_coverage, config.nearest_neighbour_only, margin,
                config.theta_step, config.rho_step)
    return derived(config, "match_settings", build)


def matches_found(lines: Lines, table: PairTable | None, li: NDArray, rj: NDArray,
                  residual: NDArray, cov: NDArray, d2: NDArray, n_cand: NDArray,
                  ambiguous: NDArray, claims: NDArray) -> Matches:
    """:func:`_match_kernel`'s result as matches, with the reasons for what was left out."""
    reasons: tuple[str, ...] = ()
    if len(ambiguous):  # the reasons, only when there is something to explain
        theta, rho, count = lines.theta.tolist(), lines.rho.tolist(), n_cand.tolist()
        reasons = tuple(
            [f"line θ={math.degrees(theta[i]):.1f}° ρ={rho[i]:.2f} m fits {count[i]} map lines"
             for i in np.flatnonzero(n_cand >= 2)[:3].tolist()]
            + [f"{c} lines claim one map line" for c in claims.tolist()])
    return Matches(li, rj, residual, cov, d2, ambiguous, reasons, table)


@njit
def associate_kernel(l_theta: NDArray, l_rho: NDArray, l_cov: NDArray, l_s0: NDArray,
                     l_s1: NDArray, r_theta: NDArray, r_rho: NDArray, beta: NDArray,
                     seg_ref: NDArray, seg_s0: NDArray, seg_s1: NDArray, pose: NDArray,
                     pose_cov: NDArray, settings: tuple) -> tuple:
    """:func:`_pairs` and the references' normals (the pair table), then :func:`_match_kernel`
    on it, as one compiled call."""
    d_theta, d_rho, sign = _pairs(l_theta, l_rho, r_theta, r_rho)
    return _match_kernel(l_cov, l_s0, l_s1, d_theta, d_rho, sign, np.cos(beta), np.sin(beta),
                         seg_ref, seg_s0, seg_s1, pose, pose_cov, settings)


@njit
def _pairs(l_theta: NDArray, l_rho: NDArray, r_theta: NDArray, r_rho: NDArray
           ) -> tuple[NDArray, NDArray, NDArray]:
    """K×L residuals Δθ (wrapped), Δρ of each line against each reference, in the line's
    representation whose normal points the reference's way, and the sign of that choice."""
    k, n_ref = len(l_theta), len(r_theta)
    d_theta, d_rho, sign = np.empty((k, n_ref)), np.empty((k, n_ref)), np.empty((k, n_ref))
    for i in range(k):
        for j in range(n_ref):
            dt = (l_theta[i] - r_theta[j] + np.pi) % TWO_PI - np.pi
            sg = 1.0
            if abs(dt) > 0.5 * np.pi:
                sg = -1.0
                dt -= math.copysign(np.pi, dt)
            d_theta[i, j], sign[i, j], d_rho[i, j] = dt, sg, sg * l_rho[i] - r_rho[j]
    return d_theta, d_rho, sign


@njit
def _match_kernel(l_cov: NDArray, l_s0: NDArray, l_s1: NDArray, d_theta: NDArray,
                  d_rho: NDArray, sign: NDArray, cos_beta: NDArray, sin_beta: NDArray,
                  seg_ref: NDArray, seg_s0: NDArray, seg_s1: NDArray, pose: NDArray,
                  pose_cov: NDArray, settings: tuple) -> tuple:
    """The association's three steps on a pair table, with :func:`match_settings`.

    1. χ²(2) gate: d² = rᵀ S⁻¹ r with S = J P Jᵀ + C, written out for 2×2 blocks: with
       J = [[0, 0, −1], [−nᵀ, 0]], J P Jᵀ = [[P_θθ, nᵀP_tθ], [nᵀP_tθ, nᵀP_tt n]].
    2. Extents, for gated pairs: does the observed piece, placed in the world at ``pose``, lie on
       the line's segments? Along the reference direction t = (−sin β, cos β) a robot-frame
       coordinate s maps to s + (x, y)·t (−s when the line is seen with the flipped normal).
       The fraction of the piece covered by the segments (each widened by a slack that grows
       with the pose uncertainty along t and with the heading uncertainty times the distance)
       must reach ``min_coverage``: a wall seen through a goal mouth or a door is not the wall
       beside the opening.
    3. Resolution: a line whose best candidate beats every other by ``decisive_margin`` in d²
       (a clear likelihood ratio: the d² already carry the pose's uncertainty) keeps only that
       one; a line left with two candidates is ambiguous. Two lines claiming one reference are
       fine when they agree with each other (the same wall seen twice); otherwise neither can be
       trusted.

    Returns the accepted pairs (line, reference), their residuals (Δθ, Δρ) and the lines'
    covariances in the representation that fits (the flipped one negates cov(θ, ρ)), their d²,
    each line's candidate count, the lines left ambiguous, and the number of lines in each
    conflicting claim.
    """
    gate, extent_margin, min_coverage, nearest_only, decisive_margin, theta_step, rho_step = (
        settings)
    k, n_ref = d_theta.shape
    cb, sb = cos_beta, sin_beta
    candidate = np.zeros((k, n_ref), np.bool_)
    d2 = np.empty((k, n_ref))
    any_gated = False
    for j in range(n_ref):
        p_rt = cb[j] * pose_cov[0, 2] + sb[j] * pose_cov[1, 2]  # cov(ρ, θ) from the pose
        p_rr = cb[j] * (cb[j] * pose_cov[0, 0] + 2 * sb[j] * pose_cov[0, 1]) + (
            sb[j] * sb[j] * pose_cov[1, 1])
        for i in range(k):
            s00 = pose_cov[2, 2] + l_cov[i, 0, 0]
            s01 = p_rt + sign[i, j] * l_cov[i, 0, 1]
            s11 = p_rr + l_cov[i, 1, 1]
            dt, dr = d_theta[i, j], d_rho[i, j]
            d2[i, j] = (s11 * dt * dt - 2.0 * s01 * dt * dr + s00 * dr * dr) / (
                s00 * s11 - s01 * s01)
            candidate[i, j] = d2[i, j] <= gate
            any_gated |= candidate[i, j]
    if any_gated:
        covered = np.zeros((k, n_ref))
        heading_var = max(pose_cov[2, 2], 0.0)
        for s in range(len(seg_ref)):
            j = seg_ref[s]
            tx, ty = -sb[j], cb[j]
            offset = tx * pose[0] + ty * pose[1]
            var_along = tx * (tx * pose_cov[0, 0] + 2 * ty * pose_cov[0, 1]) + (
                ty * ty * pose_cov[1, 1])
            for i in range(k):
                if not candidate[i, j]:
                    continue
                reach_sq = max(abs(l_s0[i]), abs(l_s1[i])) ** 2
                slack = extent_margin + 3.0 * math.sqrt(max(var_along, 0.0)
                                                         + reach_sq * heading_var)
                lo = seg_s0[s] - offset - slack  # the segment in robot coordinates
                hi = seg_s1[s] - offset + slack
                s0, s1 = (-l_s1[i], -l_s0[i]) if sign[i, j] < 0 else (l_s0[i], l_s1[i])
                covered[i, j] += max(min(s1, hi) - max(s0, lo), 0.0)
        for i in range(k):
            need = min_coverage * max(l_s1[i] - l_s0[i], 1e-6)
            for j in range(n_ref):
                candidate[i, j] &= covered[i, j] >= need
    n_cand = np.zeros(k, np.intp)
    for i in range(k):
        best, second, best_j = np.inf, np.inf, -1
        for j in range(n_ref):
            if candidate[i, j]:
                n_cand[i] += 1
                if d2[i, j] < best:
                    best, second, best_j = d2[i, j], best, j
                elif d2[i, j] < second:
                    second = d2[i, j]
        if n_cand[i] >= 2 and (nearest_only or (
                decisive_margin >= 0 and second - best >= decisive_margin)):
            candidate[i] = False  # the nearest (or the decisive) candidate only
            candidate[i, best_j] = True
            if not nearest_only:
                n_cand[i] = 1
        if nearest_only:
            n_cand[i] = min(n_cand[i], 1)
    ambiguous = n_cand >= 2
    li, rj = [], []
    claims = np.zeros(n_ref, np.intp)
    for i in range(k):
        if n_cand[i] == 1:
            for j in range(n_ref):
                if candidate[i, j]:
                    li.append(i)
                    rj.append(j)
                    claims[j] += 1
    conflicts = []
    for j in range(n_ref):
        if claims[j] < 2:
            continue
        idx = [li[m] for m in range(len(li)) if rj[m] == j]
        mean_t = mean_r = 0.0
        for i in idx:
            mean_t += d_theta[i, j]
            mean_r += d_rho[i, j]
        mean_t /= len(idx)
        mean_r /= len(idx)
        for i in idx:
            if (abs(d_theta[i, j] - mean_t) > 3.0 * math.sqrt(l_cov[i, 0, 0]) + theta_step / 4
                    or abs(d_rho[i, j] - mean_r) > 3.0 * math.sqrt(l_cov[i, 1, 1])
                    + rho_step / 4):
                for i2 in idx:
                    ambiguous[i2] = True
                conflicts.append(len(idx))
                break
    keep = [m for m in range(len(li)) if not ambiguous[li[m]]]
    n_out = len(keep)
    out_l, out_r = np.empty(n_out, np.intp), np.empty(n_out, np.intp)
    out_res, out_cov, out_d2 = np.empty((n_out, 2)), np.empty((n_out, 2, 2)), np.empty(n_out)
    for q in range(n_out):
        i, j = li[keep[q]], rj[keep[q]]
        out_l[q], out_r[q], out_d2[q] = i, j, d2[i, j]
        out_res[q, 0], out_res[q, 1] = d_theta[i, j], d_rho[i, j]
        out_cov[q, 0, 0], out_cov[q, 1, 1] = l_cov[i, 0, 0], l_cov[i, 1, 1]
        out_cov[q, 0, 1] = out_cov[q, 1, 0] = l_cov[i, 0, 1] * sign[i, j]
    return (out_l, out_r, out_res, out_cov, out_d2, n_cand, np.flatnonzero(ambiguous),
            np.array(conflicts, np.intp))

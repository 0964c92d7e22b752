"""Refinement of Hough peaks to continuous lines (DESIGN §3.3).

The grid bounds the paper's precision (3°, 10 cm). Each peak's inlier points — those within a band
of its line — are fitted by total least squares, the band is narrowed to the fit's own scatter, and
the points are split into contiguous pieces along the line; pieces too small or too short are
dropped (a robot's arc, a lone return). All peaks are processed together: N×K matrices for the
first fit, then one line label per point.

Covariance of a fitted line (normal angle θ, offset ρ), with σ² the residual variance, N inliers,
sᵢ their coordinates along the line and s̄ their mean:
    var θ = σ² / Σ(sᵢ − s̄)²,    var(offset at the centroid) = σ² / N,
    ρ = c·n(θ)  ⇒  ∂ρ/∂θ = c·t = s̄,  so  C = [[vθ, s̄ vθ], [s̄ vθ, σ²/N + s̄² vθ]],
plus a small floor on each diagonal term (``line_theta_floor_deg``, ``line_rho_floor``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig
from houghloc.geometry import TWO_PI


@dataclass(frozen=True)
class Lines:
    """Observed lines in the robot frame (ρ ≥ 0 except within noise of 0), one row each.

    ``cov`` is K×2×2 over (θ, ρ). ``s0``/``s1`` bound the observed points along the direction
    (−sin θ, cos θ). ``members`` is the N×K inlier mask (for colouring points by line).
    """

    theta: NDArray[np.float64]
    rho: NDArray[np.float64]
    cov: NDArray[np.float64]
    n: NDArray[np.int64]
    sigma: NDArray[np.float64]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]
    members: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.theta)

    def subset(self, keep: NDArray) -> Lines:
        return Lines(
            self.theta[keep],
            self.rho[keep],
            self.cov[keep],
            self.n[keep],
            self.sigma[keep],
            self.s0[keep],
            self.s1[keep],
            self.members[:, keep],
        )


def _moments(points: NDArray, weights: NDArray | None = None) -> NDArray:
    """Per-point monomials w·[1, x, y, x², xy, y²]: one product with a mask gives all line sums
    (weighted sums when the points have weights)."""
    mono = np.empty((len(points), 6))
    mono[:, 0] = 1.0
    mono[:, 1:3] = points
    np.multiply(points[:, :1], points, out=mono[:, 3:5])  # x·x, x·y
    np.multiply(points[:, 1], points[:, 1], out=mono[:, 5])  # y·y
    return mono if weights is None else mono * weights[:, None]


def _tls(monomials: NDArray, mask: NDArray) -> tuple[NDArray, ...]:
    """Total-least-squares lines through the masked points of each column.

    The scatter matrix comes from the masked sums (Mᵀ·[1, x, y, x², xy, y²]); the normal is the
    eigenvector of its smallest eigenvalue. Returns normal angle θ (ρ ≥ 0), ρ, the mean square
    residual Σwr²/W, the weight W = Σw (the count N for unit weights), the centroid c (2×K) and
    the variance along the line (the spread of the points).
    """
    sums = monomials.T @ mask.astype(np.float64)  # 6×K
    n = sums[0]
    moments = sums[1:] / np.maximum(n, 1.0)
    cx, cy = moments[0], moments[1]
    sxx = moments[2] - cx * cx
    sxy = moments[3] - cx * cy
    syy = moments[4] - cy * cy
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + 0.5 * np.pi  # normal ⊥ principal axis
    half_sum, root = 0.5 * (sxx + syy), np.hypot(0.5 * (sxx - syy), sxy)
    rho = cx * np.cos(theta) + cy * np.sin(theta)
    theta[rho < 0] += np.pi
    return (theta % TWO_PI, np.abs(rho), np.maximum(half_sum - root, 0.0), n, moments[:2],
            half_sum + root)


def _split_pieces(points: NDArray, label: NDArray[np.intp], cos_t: NDArray, sin_t: NDArray,
                  config: HoughConfig) -> NDArray[np.intp]:
    """Keep only points in contiguous pieces of at least ``min_piece_points`` (all lines at once).

    ``label`` gives each point's line (−1: none), ``cos_t``/``sin_t`` the lines' normals. The
    labelled points are sorted by (line, coordinate along the line); a step wider than
    ``piece_gap`` or a change of line starts a new piece. Returns the labels with the points of
    small pieces set to −1.
    """
    idx = np.flatnonzero(label >= 0)
    if len(idx) == 0:
        return label
    lab = label[idx]
    along = points[idx, 1] * cos_t[lab] - points[idx, 0] * sin_t[lab]
    # lines are at most a few hundred metres long: the line index dominates the sort key
    order = np.argsort(lab * 1.0e4 + along)
    lab, along = lab[order], along[order]
    starts = np.empty(len(lab), dtype=np.intp)
    starts[0] = 0
    np.logical_or(along[1:] - along[:-1] > config.piece_gap, lab[1:] != lab[:-1], out=starts[1:])
    piece = np.cumsum(starts, out=starts)  # pieces numbered from 0
    small = np.bincount(piece)[piece] < config.min_piece_points
    out = label.copy()
    out[idx[order[small]]] = -1
    return out


def refine_lines(points: NDArray[np.float64], theta0: NDArray, rho0: NDArray,
                 config: HoughConfig, weights: NDArray | None = None) -> Lines:
    """Refine peaks (θ₀, ρ₀) to TLS lines with covariances; drop those that are not lines.

    ``weights`` (relative, mean 1) make it a weighted TLS: var θ = σ²/Σwᵢ(sᵢ − s̄)², var = σ²/Σwᵢ.
    """
    monomials = _moments(points, weights)
    max_band = config.refine_max_band or config.rho_step
    theta, rho = np.asarray(theta0, float), np.asarray(rho0, float)
    band = np.full(len(theta), max_band)  # first pass: one cell (or the widest band) each side
    mask = _inliers(points, theta, rho, band)
    n = mask.sum(axis=0) if config.refine_iterations == 1 else None
    for it in range(config.refine_iterations - 1):  # re-centre the band on a first fit
        if it:
            mask = _inliers(points, theta, rho, band)
        theta, rho, mean_sq, n, _, _ = _tls(monomials, mask)
        band = np.minimum(np.maximum(config.refine_band_sigmas * np.sqrt(mean_sq),
                                     config.refine_min_band), max_band)
    keep = _distinct(mask, n, theta, rho, config)
    theta, rho, band = theta[keep], rho[keep], band[keep]
    k = len(theta)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    # Each point now belongs to the nearest line whose band holds it: a point near a corner
    # biases only the wall it is on, and twin peaks cannot share their points.
    if k:
        dist = np.abs(points @ np.array((cos_t, sin_t)) - rho) / band
        nearest = np.argmin(dist, axis=1)
        label = np.where(dist[np.arange(len(points)), nearest] <= 1.0, nearest, -1)
        label = _split_pieces(points, label, cos_t, sin_t, config)
    else:
        label = np.full(len(points), -1, dtype=np.intp)
    mask = label[:, None] == np.arange(k)
    theta, rho, mean_sq, weight, c, spread_var = _tls(monomials, mask)
    n = np.bincount(label + 1, minlength=k + 1)[1:] if weights is not None else weight
    var = mean_sq * weight / np.maximum(n - 2.0, 1.0)  # σ² = Σwr² / (N − 2), unbiased

    sigma = np.sqrt(var)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    s_bar = cos_t * c[1] - sin_t * c[0]  # centroid along t = (−sin θ, cos θ)
    # extent of each line's points along it (±inf for a line left without points)
    on_line = np.flatnonzero(label >= 0)
    line_of = label[on_line]
    along = (points @ np.array((-sin_t, cos_t)))[on_line, line_of]
    s0, s1 = np.full(k, np.inf), np.full(k, -np.inf)
    np.minimum.at(s0, line_of, along)
    np.maximum.at(s1, line_of, along)
    ok = (n >= config.min_piece_points) & (sigma <= config.max_line_sigma) & (
        s1 - s0 >= config.min_line_length)
    var_eff = np.maximum(var, config.point_sigma_floor**2)
    v_theta = var_eff / np.maximum(spread_var * weight, 1e-12)  # σ² / Σwᵢ(sᵢ − s̄)²
    v_off = var_eff / np.maximum(weight, 1e-12)  # σ² / Σwᵢ
    cov = np.empty((k, 2, 2))
    # Real walls are not perfect lines and sensors have small biases: a floor keeps thousands of
    # points from claiming sub-millimetre certainty.
    cov[:, 0, 0] = v_theta + config.line_theta_floor**2
    cov[:, 0, 1] = cov[:, 1, 0] = s_bar * v_theta
    cov[:, 1, 1] = v_off + s_bar**2 * v_theta + config.line_rho_floor**2
    lines = Lines(theta, rho, cov, n.astype(np.int64), sigma, s0, s1, mask)
    return lines if ok.all() else lines.subset(ok)


def _inliers(points: NDArray, theta: NDArray, rho: NDArray, band: NDArray | float) -> NDArray:
    """N×K mask of |p·n − ρ| ≤ band."""
    return np.abs(points @ np.array((np.cos(theta), np.sin(theta))) - rho) <= band


def _distinct(mask: NDArray[np.bool_], n: NDArray, theta: NDArray, rho: NDArray,
              config: HoughConfig) -> NDArray[np.bool_]:
    """Drop peaks that are one line with a stronger peak: they found mostly the same points
    (plateaus, a noisy line's spread of peaks, the θ ↔ θ+π twins of a line through the sensor),
    or they refined to within half a cell of it (a short line near the sensor, whose peaks at
    neighbouring θ catch different parts of it). Lines meeting at a corner share a few points
    only and differ by far more than half a cell."""
    m = mask.astype(np.float32)
    shared = m.T @ m  # K×K counts of common inliers
    same = shared > 0.5 * np.minimum(n[:, None], n)
    # |θᵢ − θⱼ| < δθ/2 (wrapped) as cos(θᵢ − θⱼ) = cos θᵢ cos θⱼ + sin θᵢ sin θⱼ > cos(δθ/2)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    near = np.multiply.outer(cos_t, cos_t) + np.multiply.outer(sin_t, sin_t)
    same |= (near > math.cos(0.5 * config.theta_step)) & (np.abs(rho[:, None] - rho[None, :])
                                                          < 0.5 * config.rho_step)
    # stronger[i, j]: line j outranks line i (more inliers; on a tie, the earlier, stronger peak)
    stronger = (n > n[:, None]) | ((n == n[:, None]) & _earlier(len(n)))
    return (n > 0) & ~(same & stronger).any(axis=1)


@lru_cache(maxsize=64)
def _earlier(k: int) -> NDArray[np.bool_]:
    """K×K: column j comes before row i."""
    return np.tri(k, k, -1, dtype=bool)

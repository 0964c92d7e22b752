"""Refinement of Hough peaks to continuous lines (DESIGN §3.3).

The grid bounds the paper's precision (3°, 10 cm). Each peak's inlier points — those within a band
of its line — are fitted by total least squares, the band is narrowed to the fit's own scatter, and
the points are split into contiguous pieces along the line; pieces too small or too short are
dropped (a robot's arc, a lone return). All peaks are processed together as N×K matrices.

Covariance of a fitted line (normal angle θ, offset ρ), with σ² the residual variance, N inliers,
sᵢ their coordinates along the line and s̄ their mean:
    var θ = σ² / Σ(sᵢ − s̄)²,    var(offset at the centroid) = σ² / N,
    ρ = c·n(θ)  ⇒  ∂ρ/∂θ = c·t = s̄,  so  C = [[vθ, s̄ vθ], [s̄ vθ, σ²/N + s̄² vθ]],
plus a small floor on each diagonal term (``line_theta_floor_deg``, ``line_rho_floor``).
"""

from __future__ import annotations

from dataclasses import dataclass

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
    x, y = points[:, 0], points[:, 1]
    mono = np.column_stack((np.ones(len(points)), x, y, x * x, x * y, y * y))
    return mono if weights is None else mono * weights[:, None]


def _tls(monomials: NDArray, mask: NDArray) -> tuple[NDArray, ...]:
    """Total-least-squares lines through the masked points of each column.

    The scatter matrix comes from the masked sums (Mᵀ·[1, x, y, x², xy, y²]); the normal is the
    eigenvector of its smallest eigenvalue. Returns normal angle θ (ρ ≥ 0), ρ, the mean square
    residual Σwr²/W, the weight W = Σw (the count N for unit weights), the centroid c (K×2) and
    the variance along the line (the spread of the points).
    """
    sums = mask.T.astype(np.float64) @ monomials  # K×6
    n = sums[:, 0]
    safe = np.maximum(n, 1.0)
    cx, cy = sums[:, 1] / safe, sums[:, 2] / safe
    sxx = sums[:, 3] / safe - cx * cx
    sxy = sums[:, 4] / safe - cx * cy
    syy = sums[:, 5] / safe - cy * cy
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + 0.5 * np.pi  # normal ⊥ principal axis
    root = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    lam_min = np.maximum(0.5 * (sxx + syy) - root, 0.0)
    lam_max = 0.5 * (sxx + syy) + root
    rho = cx * np.cos(theta) + cy * np.sin(theta)
    theta = np.where(rho < 0, theta + np.pi, theta) % TWO_PI
    return theta, np.abs(rho), lam_min, n, np.column_stack((cx, cy)), lam_max


def _split_pieces(s: NDArray, mask: NDArray, config: HoughConfig) -> NDArray[np.bool_]:
    """Keep only points in contiguous pieces with at least ``min_piece_points`` (all lines at once).

    Each line's inliers are binned along the line in cells of half ``piece_gap``; a run of
    occupied cells is a piece. A gap wider than ``piece_gap`` always leaves an empty cell, so it
    always splits (a gap between half and one ``piece_gap`` may). One bincount over (line, cell)
    does all lines together, without sorting the points.
    """
    k = s.shape[1]
    if k == 0 or not mask.any():
        return mask
    half = 0.5 * config.piece_gap
    s_in = np.where(mask, s, np.inf)
    lo = s_in.min(axis=0)
    lo = np.where(np.isfinite(lo), lo, 0.0)
    cell = ((s - lo) * (1.0 / half)).astype(np.int64)
    n_cells = int(cell[mask].max()) + 2
    np.clip(cell, 0, n_cells - 1, out=cell)
    flat = cell + np.arange(k) * n_cells  # N×K global cell ids
    counts = np.bincount(flat[mask], minlength=k * n_cells)
    occupied = counts > 0
    start = occupied.copy()
    start[1:] &= ~occupied[:-1]
    start[::n_cells] = occupied[::n_cells]  # a row's first cell starts a piece if occupied
    piece = np.cumsum(start) - 1
    size = np.bincount(piece[occupied], weights=counts[occupied],
                       minlength=int(start.sum()))
    good_cell = occupied & (size[np.maximum(piece, 0)] >= config.min_piece_points)
    return mask & good_cell[flat]


def refine_lines(points: NDArray[np.float64], theta0: NDArray, rho0: NDArray,
                 config: HoughConfig, weights: NDArray | None = None) -> Lines:
    """Refine peaks (θ₀, ρ₀) to TLS lines with covariances; drop those that are not lines.

    ``weights`` (relative, mean 1) make it a weighted TLS: var θ = σ²/Σwᵢ(sᵢ − s̄)², var = σ²/Σwᵢ.
    """
    monomials = _moments(points, weights)
    max_band = config.refine_max_band or config.rho_step
    band = max_band  # first pass: one cell (or the widest band) either side of the peak
    theta, rho = np.asarray(theta0, float), np.asarray(rho0, float)
    mask = _inliers(points, theta, rho, band)
    n = mask.sum(axis=0)
    for it in range(config.refine_iterations - 1):  # re-centre the band on a first fit
        if it:
            mask = _inliers(points, theta, rho, band)
        theta, rho, mean_sq, n, _, _ = _tls(monomials, mask)
        band = np.clip(config.refine_band_sigmas * np.sqrt(mean_sq), config.refine_min_band,
                       max_band)
    keep = _distinct(mask, n, theta, rho, config)
    theta, rho, band = theta[keep], rho[keep], np.broadcast_to(band, keep.shape)[keep]
    # Each point now belongs to the nearest line whose band holds it: a point near a corner
    # biases only the wall it is on, and twin peaks cannot share their points.
    dist = np.abs(points @ np.vstack((np.cos(theta), np.sin(theta))) - rho) / band
    mask = np.zeros(dist.shape, dtype=bool)
    if dist.shape[1]:
        nearest = np.argmin(dist, axis=1)
        rows = np.arange(len(points))
        mask[rows, nearest] = dist[rows, nearest] <= 1.0
    normal = np.vstack((np.cos(theta), np.sin(theta)))
    mask = _split_pieces(points @ np.vstack((-normal[1], normal[0])), mask, config)
    theta, rho, mean_sq, weight, c, spread_var = _tls(monomials, mask)
    n = mask.sum(axis=0) if weights is not None else weight
    var = mean_sq * weight / np.maximum(n - 2.0, 1.0)  # σ² = Σwr² / (N − 2), unbiased

    sigma = np.sqrt(var)
    t = np.vstack((-np.sin(theta), np.cos(theta)))
    along = points @ t  # N×K
    s_bar = c[:, 0] * t[0] + c[:, 1] * t[1]
    s0 = np.where(mask, along, np.inf).min(axis=0)
    s1 = np.where(mask, along, -np.inf).max(axis=0)
    ok = (
        (n >= config.min_piece_points)
        & (sigma <= config.max_line_sigma)
        & (s1 - s0 >= config.min_line_length)
    )
    var_eff = np.maximum(var, config.point_sigma_floor**2)
    v_theta = var_eff / np.maximum(spread_var * weight, 1e-12)  # σ² / Σwᵢ(sᵢ − s̄)²
    v_off = var_eff / np.maximum(weight, 1e-12)  # σ² / Σwᵢ
    cov = np.empty((len(theta), 2, 2))
    cov[:, 0, 0] = v_theta
    cov[:, 0, 1] = cov[:, 1, 0] = s_bar * v_theta
    cov[:, 1, 1] = v_off + s_bar**2 * v_theta
    # Real walls are not perfect lines and sensors have small biases: a floor keeps thousands of
    # points from claiming sub-millimetre certainty.
    cov[:, 0, 0] += config.line_theta_floor**2
    cov[:, 1, 1] += config.line_rho_floor**2
    lines = Lines(theta, rho, cov, n.astype(np.int64), sigma, s0, s1, mask)
    return lines if ok.all() else lines.subset(ok)


def _inliers(points: NDArray, theta: NDArray, rho: NDArray, band: NDArray | float) -> NDArray:
    """N×K mask of |p·n − ρ| ≤ band."""
    return np.abs(points @ np.vstack((np.cos(theta), np.sin(theta))) - rho) <= band


def _distinct(mask: NDArray[np.bool_], n: NDArray, theta: NDArray, rho: NDArray,
              config: HoughConfig) -> NDArray[np.bool_]:
    """Drop peaks that are one line with a stronger peak: they found mostly the same points
    (plateaus, a noisy line's spread of peaks, the θ ↔ θ+π twins of a line through the sensor),
    or they refined to within half a cell of it (a short line near the sensor, whose peaks at
    neighbouring θ catch different parts of it). Lines meeting at a corner share a few points
    only and differ by far more than half a cell."""
    m = mask.astype(np.float32)
    shared = m.T @ m  # K×K counts of common inliers
    k = len(n)
    idx = np.arange(k)
    same = shared > 0.5 * np.minimum(n[:, None], n[None, :])
    dth = np.abs((theta[:, None] - theta[None, :] + np.pi) % TWO_PI - np.pi)
    same |= (dth < 0.5 * config.theta_step) & (np.abs(rho[:, None] - rho[None, :])
                                               < 0.5 * config.rho_step)
    stronger = (n[None, :] > n[:, None]) | (
        (n[None, :] == n[:, None]) & (idx[None, :] < idx[:, None]))
    return (n > 0) & ~(same & stronger).any(axis=1)

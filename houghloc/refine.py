"""Refinement of Hough peaks to continuous lines (docs/method.md §3).

The grid bounds the paper's precision (3°, 10 cm). Each peak's inlier points — those within a band
of its line — are fitted by total least squares, the band is narrowed to the fit's own scatter, and
the points are split into contiguous pieces along the line; pieces too small or too short are
dropped (a robot's arc, a lone return). All peaks are processed together: a K×N inlier mask for the
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

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig
from houghloc.geometry import TWO_PI
from houghloc.jit import fma, njit


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
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


def refine_lines(points: NDArray[np.float64], theta0: NDArray, rho0: NDArray,
                 config: HoughConfig, weights: NDArray | None = None) -> Lines:
    """Refine peaks (θ₀, ρ₀) to TLS lines with covariances; drop those that are not lines.

    ``weights`` (relative, mean 1) make it a weighted TLS: var θ = σ²/Σwᵢ(sᵢ − s̄)², var = σ²/Σwᵢ.
    The steps, compiled as one kernel: (1) the inliers of each peak within one ρ cell (or
    ``refine_max_band``) are fitted (`tls_fit`) and the band narrowed to
    ``refine_band_sigmas`` times the fit's scatter, ``refine_iterations − 1`` times; (2) peaks
    that are one line with a stronger one are dropped (:func:`_distinct`); (3) each point joins
    the nearest line whose band holds it, and only contiguous pieces are kept
    (:func:`_split_pieces`); (4) each line is fitted to its points, with the covariance above,
    and kept if it has ``min_piece_points``, a scatter ≤ ``max_line_sigma`` and a length ≥
    ``min_line_length``.
    """
    theta0 = np.ascontiguousarray(theta0, dtype=float)
    rho0 = np.ascontiguousarray(rho0, dtype=float)
    unit = weights is None
    w = np.ones(len(points)) if weights is None else np.ascontiguousarray(weights, dtype=float)
    theta, rho, cov, n, sigma, s0, s1, members = _refine_kernel(
        np.ascontiguousarray(points, dtype=float), w, unit, theta0, rho0,
        config.refine_max_band or config.rho_step, config.refine_iterations,
        config.refine_band_sigmas, config.refine_min_band, config.theta_step, config.rho_step,
        config.piece_gap, config.min_piece_points, config.min_line_length,
        config.max_line_sigma, config.point_sigma_floor, config.line_theta_floor,
        config.line_rho_floor)
    return Lines(theta, rho, cov, n, sigma, s0, s1, members)


@njit
def _refine_kernel(points: NDArray, w: NDArray, unit: bool, theta: NDArray, rho: NDArray,
                   max_band: float, iterations: int, band_sigmas: float, min_band: float,
                   theta_step: float, rho_step: float, piece_gap: float, min_piece_points: int,
                   min_line_length: float, max_line_sigma: float, point_sigma_floor: float,
                   theta_floor: float, rho_floor: float) -> tuple:
    n_points, k = points.shape[0], theta.shape[0]
    mono = _moments(points, w)
    band = np.full(k, max_band)
    label = np.empty(n_points, np.intp)
    # (1) fit each peak's inliers, narrow the band; peaks may share points here
    inliers = _inliers(points, theta, rho, band)
    if iterations < 2:  # no fit below: the peaks' weights are their inlier counts
        weight = np.zeros(k)
        for j in range(k):
            for i in range(n_points):
                weight[j] += inliers[j, i]
    for it in range(iterations - 1):
        if it:
            inliers = _inliers(points, theta, rho, band)
        sums = _masked_sums(mono, inliers)
        theta, rho, mean_sq, weight, _, _, _ = tls_fit(sums)
        for j in range(k):
            band[j] = min(max(band_sigmas * math.sqrt(mean_sq[j]), min_band), max_band)
    # (2) one line per wall
    keep = np.flatnonzero(_distinct(inliers, weight, theta, rho, theta_step, rho_step))
    theta, rho, band = theta[keep], rho[keep], band[keep]
    k = len(keep)
    # (3) each point to the nearest line whose band holds it: a point near a corner biases only
    # the wall it is on, and twin peaks cannot share their points
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    for i in range(n_points):
        label[i] = -1
        best = np.inf
        for j in range(k):
            d = abs(fma(points[i, 1], sin_t[j], points[i, 0] * cos_t[j]) - rho[j]) / band[j]
            if d < best:
                best, label[i] = d, j
        if best > 1.0:
            label[i] = -1
    _split_pieces(points, label, cos_t, sin_t, piece_gap, min_piece_points)
    # (4) the final fits, their extents and covariances
    on_line = np.zeros((n_points, k), np.bool_)
    count = np.zeros(k)
    sums = np.zeros((6, k))
    for i in range(n_points):
        j = label[i]
        if j >= 0:
            on_line[i, j] = True
            count[j] += 1.0
            for m in range(6):
                sums[m, j] += mono[i, m]
    theta, rho, mean_sq, weight, centroid, spread_var, _ = tls_fit(sums)
    if unit:
        count = weight
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    s0, s1 = np.full(k, np.inf), np.full(k, -np.inf)
    for i in range(n_points):
        j = label[i]
        if j >= 0:
            along = fma(points[i, 1], cos_t[j], points[i, 0] * -sin_t[j])
            s0[j], s1[j] = min(s0[j], along), max(s1[j], along)
    good = np.empty(k, np.bool_)
    cov = np.empty((k, 2, 2))
    sigma = np.empty(k)
    for j in range(k):
        var = mean_sq[j] * weight[j] / max(count[j] - 2.0, 1.0)  # σ² = Σwr² / (N − 2), unbiased
        sigma[j] = math.sqrt(var)
        good[j] = (count[j] >= min_piece_points and sigma[j] <= max_line_sigma
                   and s1[j] - s0[j] >= min_line_length)
        s_bar = cos_t[j] * centroid[1, j] - sin_t[j] * centroid[0, j]  # along t = (−sin, cos)
        var_eff = max(var, point_sigma_floor**2)
        v_theta = var_eff / max(spread_var[j] * weight[j], 1e-12)  # σ² / Σwᵢ(sᵢ − s̄)²
        v_off = var_eff / max(weight[j], 1e-12)  # σ² / Σwᵢ
        # Real walls are not perfect lines and sensors have small biases: a floor keeps
        # thousands of points from claiming sub-millimetre certainty.
        cov[j, 0, 0] = v_theta + theta_floor**2
        cov[j, 0, 1] = cov[j, 1, 0] = s_bar * v_theta
        cov[j, 1, 1] = v_off + s_bar**2 * v_theta + rho_floor**2
    ok = np.flatnonzero(good)
    return (theta[ok], rho[ok], cov[ok], count[ok].astype(np.int64), sigma[ok], s0[ok], s1[ok],
            np.ascontiguousarray(on_line[:, ok]))


@njit
def _moments(points: NDArray, weights: NDArray) -> NDArray:
    """Per-point monomials w·[1, x, y, x², xy, y²]: one product with a mask gives all line sums
    (weighted sums when the points have weights)."""
    mono = np.empty((len(points), 6))
    for i in range(len(points)):
        x, y, wi = points[i, 0], points[i, 1], weights[i]
        mono[i, 0], mono[i, 1], mono[i, 2] = wi, x * wi, y * wi
        mono[i, 3], mono[i, 4], mono[i, 5] = x * x * wi, x * y * wi, y * y * wi
    return mono


@njit
def _masked_sums(mono: NDArray, inliers: NDArray[np.bool_]) -> NDArray:
    """6×K: Σ over each peak's inliers (K×N) of the monomials."""
    k = inliers.shape[0]
    sums = np.zeros((6, k))
    for j in range(k):
        s0 = s1 = s2 = s3 = s4 = s5 = 0.0
        mask = inliers[j]
        for i in range(len(mask)):
            if mask[i]:
                s0 += mono[i, 0]
                s1 += mono[i, 1]
                s2 += mono[i, 2]
                s3 += mono[i, 3]
                s4 += mono[i, 4]
                s5 += mono[i, 5]
        sums[0, j], sums[1, j], sums[2, j] = s0, s1, s2
        sums[3, j], sums[4, j], sums[5, j] = s3, s4, s5
    return sums


@njit
def tls_fit(sums: NDArray) -> tuple:
    """Total-least-squares lines from each column's sums of [1, x, y, x², xy, y²] (weighted or
    not: :func:`_masked_sums`; the map builder's moments use it too).

    The scatter matrix comes from the sums; the normal is the eigenvector of its smallest
    eigenvalue. Returns normal angle θ (ρ ≥ 0), ρ, the mean square residual Σwr²/W, the weight
    W = Σw (the count N for unit weights), the centroid c (2×K), the variance along the line (the
    spread of the points), and the principal axis's angle in (−π/2, π/2] (the line's direction).
    """
    k = sums.shape[1]
    theta, rho, mean_sq, spread = np.empty(k), np.empty(k), np.empty(k), np.empty(k)
    axis = np.empty(k)
    centroid = np.empty((2, k))
    for j in range(k):
        n = max(sums[0, j], 1.0)
        cx, cy = sums[1, j] / n, sums[2, j] / n
        sxx = sums[3, j] / n - cx * cx
        sxy = sums[4, j] / n - cx * cy
        syy = sums[5, j] / n - cy * cy
        axis[j] = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
        t = axis[j] + 0.5 * np.pi  # normal ⊥ principal axis
        half_sum, root = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
        r = cx * math.cos(t) + cy * math.sin(t)
        if r < 0:
            t += np.pi
        theta[j], rho[j] = t % TWO_PI, abs(r)
        mean_sq[j], spread[j] = max(half_sum - root, 0.0), half_sum + root
        centroid[0, j], centroid[1, j] = cx, cy
    return theta, rho, mean_sq, sums[0].copy(), centroid, spread, axis


@njit
def _split_pieces(points: NDArray, label: NDArray[np.intp], cos_t: NDArray, sin_t: NDArray,
                  piece_gap: float, min_piece_points: int) -> None:
    """Keep only points in contiguous pieces of at least ``min_piece_points`` (all lines at once).

    ``label`` gives each point's line (−1: none), ``cos_t``/``sin_t`` the lines' normals. The
    labelled points are sorted by (line, coordinate along the line); a step wider than
    ``piece_gap`` or a change of line starts a new piece. The points of small pieces are set to
    −1 in ``label``.
    """
    idx = np.flatnonzero(label >= 0)
    if len(idx) == 0:
        return
    lab = label[idx]
    along = np.empty(len(idx))
    for m in range(len(idx)):
        along[m] = points[idx[m], 1] * cos_t[lab[m]] - points[idx[m], 0] * sin_t[lab[m]]
    order = _by_line_then_along(lab, along, len(cos_t))
    start = 0
    for m in range(1, len(order) + 1):
        if (m == len(order) or lab[order[m]] != lab[order[m - 1]]
                or along[order[m]] - along[order[m - 1]] > piece_gap):
            if m - start < min_piece_points:
                for q in range(start, m):
                    label[idx[order[q]]] = -1
            start = m


@njit
def _by_line_then_along(lab: NDArray[np.intp], along: NDArray, k: int) -> NDArray[np.intp]:
    """The order that sorts points by line (``lab``, 0…k−1), then by coordinate along it.

    Grouped by line first (a counting sort), then each group by ``along``: a scan's points on a
    wall come in order or in reverse, give or take the noise, so an insertion sort of the group
    (reversed first if it runs backwards) is linear in the usual case; a group far from sorted
    is handed to a general sort. Points with equal keys may come in any order: the pieces do not
    depend on it.
    """
    start = np.zeros(k + 1, np.intp)
    for m in range(len(lab)):
        start[lab[m] + 1] += 1
    for j in range(k):
        start[j + 1] += start[j]
    fill = start[:-1].copy()
    order = np.empty(len(lab), np.intp)
    for m in range(len(lab)):
        order[fill[lab[m]]] = m
        fill[lab[m]] += 1
    for j in range(k):
        group = order[start[j]:start[j + 1]]
        if len(group) > 1 and along[group[0]] > along[group[-1]]:
            group[:] = group[::-1].copy()
        budget = 8 * len(group)  # element moves allowed before the general sort takes over
        for q in range(1, len(group)):
            item = group[q]
            key = along[item]
            p = q
            while p > 0 and along[group[p - 1]] > key and budget > 0:
                group[p] = group[p - 1]
                p -= 1
                budget -= 1
            group[p] = item
            if budget == 0:
                group[:] = group[np.argsort(along[group])]
                break
    return order


@njit
def _inliers(points: NDArray, theta: NDArray, rho: NDArray, band: NDArray) -> NDArray:
    """K×N mask of |p·n − ρ| ≤ band: one row per line."""
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    mask = np.empty((len(theta), len(points)), np.bool_)
    for j in range(len(theta)):
        row = mask[j]
        for i in range(len(points)):
            p_n = fma(points[i, 1], sin_t[j], points[i, 0] * cos_t[j])
            row[i] = abs(p_n - rho[j]) <= band[j]
    return mask


@njit
def _distinct(inliers: NDArray[np.bool_], n: NDArray, theta: NDArray, rho: NDArray,
              theta_step: float, rho_step: float) -> NDArray[np.bool_]:
    """Drop peaks that are one line with a stronger peak: they found mostly the same points
    (plateaus, a noisy line's spread of peaks, the θ ↔ θ+π twins of a line through the sensor),
    or they refined to within half a cell of it (a short line near the sensor, whose peaks at
    neighbouring θ catch different parts of it). Lines meeting at a corner share a few points
    only and differ by far more than half a cell."""
    k = len(n)  # inliers: K×N, one row per peak
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    near_cos = math.cos(0.5 * theta_step)
    keep = n > 0
    for i in range(k):
        for j in range(k):
            # line j outranks line i: more inliers; on a tie, the earlier, stronger peak
            if not (n[j] > n[i] or (n[j] == n[i] and j < i)):
                continue
            # |θᵢ − θⱼ| < δθ/2 (wrapped) as cos(θᵢ − θⱼ) > cos(δθ/2)
            near = (cos_t[i] * cos_t[j] + sin_t[i] * sin_t[j] > near_cos
                    and abs(rho[i] - rho[j]) < 0.5 * rho_step)
            # the common inliers are counted only for the pairs compared: a plateau of peaks on
            # one wall would make a table of all pairs cost N × K²
            if near or _common(inliers[i], inliers[j]) > 0.5 * min(n[i], n[j]):
                keep[i] = False
                break
    return keep


@njit
def _common(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> int:
    """How many points two peaks' inlier masks share."""
    count = 0
    for i in range(len(a)):
        count += a[i] & b[i]
    return count

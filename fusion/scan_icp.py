"""Point-to-line ICP between two consecutive laser scans, compiled: each scan's normals from its
neighbouring beams, correspondences by a grid of cells, Gauss-Newton on the point-to-line
distances. Scan odometry (:mod:`fusion.scan_odometry`) uses it to correct the wheels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.settings.scan_odometry import ScanOdometryConfig
from houghloc.geometry import within_radius, wrap_scalar
from houghloc.jit import fma, njit

_DAMPING = 1e-6  # of the ICP's normal equations, against a thousand points' ~1e3 per axis


@dataclass(frozen=True, slots=True)
class IcpResult:
    """The increment that maps the current scan onto the previous one, and its covariance."""

    delta: NDArray[np.float64]
    cov: NDArray[np.float64]
    overlap: float  # fraction of the current scan's points paired at the last iteration
    weakest: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    """the unit direction of translation the match observes least (the information matrix's
    weakest translation axis)"""
    support: float = 0.0
    """how many points' worth of evidence the scene gives along ``weakest`` without the one
    movable object that gives most: Σ wᵢ (nᵢ·u)² over the paired points, in units of a point
    whose wall faces u squarely, less the largest sum of one object's points, an object being a
    run of beams without a jump of ``max_neighbour_gap`` whose surface facing u is at most
    :data:`MOVABLE_EXTENT` across (:func:`_largest_movable`). A person walking beside the
    robot can carry a match along a corridor alone; a direction the rest of the scene does not
    observe may be that person's motion."""
    disagreement: tuple[float, int] = (0.0, 0)
    """(Q, dof): how far the scene's objects disagree on the motion along ``weakest``, a χ²
    statistic with dof degrees of freedom on a rigid scene (:func:`_object_disagreement`).
    Several people walking, or people and the furniture, make it large."""


def scan_normals(points: NDArray[np.float64], max_gap: float, radius: float,
                 half_window: int = 8) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Unit normals of a scan in beam order, and which are usable.

    Each normal is the minor axis of the covariance of the point's neighbours within
    ``radius`` (among the ``half_window`` beams either side, not across a jump of more than
    ``max_gap``, where the scan passes from one object to another). A normal from the two
    adjacent points alone turns by tens of degrees with a centimetre of range noise when the
    beams are a centimetre or two apart: along a corridor's walls those tilts add up to
    information along the corridor that the walls do not give. Usable: at least three
    points in the neighbourhood."""
    return _scan_normals(np.ascontiguousarray(points, dtype=float), max_gap, radius,
                         half_window)


@njit
def _scan_normals(points: NDArray, max_gap: float, radius: float, half_window: int
                  ) -> tuple[NDArray, NDArray]:
    n = len(points)
    jump = np.zeros(n, np.intp)  # the object each point belongs to
    for i in range(1, n):
        gap = math.hypot(points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1])
        jump[i] = jump[i - 1] + (gap > max_gap)
    normals = np.empty((n, 2))
    usable = np.empty(n, np.bool_)
    for i in range(n):
        count = sx = sy = sxx = sxy = syy = 0.0
        for j in range(max(0, i - half_window), min(n, i + half_window + 1)):
            dx, dy = points[j, 0] - points[i, 0], points[j, 1] - points[i, 1]
            if jump[j] == jump[i] and within_radius(dx, dy, radius):
                count += 1.0
                sx, sy = sx + dx, sy + dy
                sxx, sxy, syy = sxx + dx * dx, sxy + dx * dy, syy + dy * dy
        safe = max(count, 1.0)
        cxx = sxx / safe - (sx / safe) ** 2
        cxy = sxy / safe - (sx / safe) * (sy / safe)
        cyy = syy / safe - (sy / safe) ** 2
        along = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)  # the major axis: the surface's direction
        normals[i, 0], normals[i, 1] = -math.sin(along), math.cos(along)
        usable[i] = count >= 3
    return normals, usable


def point_to_line_icp(previous: NDArray[np.float64], current: NDArray[np.float64],
                      guess: NDArray[np.float64], config: ScanOdometryConfig) -> IcpResult | None:
    """Align ``current`` (robot frame at k) onto ``previous`` (robot frame at k − 1), started at
    the increment ``guess``: Gauss–Newton on Σ w ρ(nᵢ·(R qᵢ + t − pᵢ)) with Huber weights, pairs
    by nearest neighbour within a distance that shrinks over the iterations. None when too few
    points pair. Cov = σ̂² (JᵀWJ)⁻¹, the Gauss–Newton covariance at the optimum."""
    if len(previous) < config.min_points or len(current) < config.min_points:
        return None
    previous = np.ascontiguousarray(previous, dtype=float)
    normals, usable = scan_normals(previous, config.max_neighbour_gap, config.normal_radius)
    found, x, hessian, sigma2, overlap, paired_normals, weights, residuals = _icp(
        previous, normals, usable, np.ascontiguousarray(current, dtype=float),
        np.array(guess, dtype=float), config.iterations, config.max_pair_distance,
        config.final_pair_distance, config.huber, config.min_points)
    if not found:
        return None
    x[2] = wrap_scalar(x[2])
    weakest = np.linalg.eigh(hessian[:2, :2])[1][:, 0]
    facing = paired_normals @ weakest
    evidence = weights * facing**2
    starts = _objects(current, config.max_neighbour_gap)
    support = float(evidence.sum() - _largest_movable(current, evidence, facing, starts))
    disagreement = _object_disagreement(evidence, weights * facing * residuals, starts,
                                        sigma2 * config.noise_scale)
    return IcpResult(x, sigma2 * np.linalg.inv(hessian), overlap, weakest, support,
                     disagreement)


MOVABLE_EXTENT = 1.0
"""m: the largest object that may move between two scans (a person, a cart); a longer run of
beams is a wall or furniture too large to carry."""


def _objects(points: NDArray[np.float64], max_gap: float) -> NDArray[np.intp]:
    """The first beam of each object: objects are runs of beams without a jump of ``max_gap``."""
    points = np.asarray(points, dtype=float)
    if len(points) == 0:
        return np.zeros(0, np.intp)
    jumps = np.flatnonzero(np.hypot(*np.diff(points, axis=0).T) > max_gap) + 1
    return np.concatenate(([0], jumps))


def _largest_movable(points: NDArray[np.float64], evidence: NDArray[np.float64],
                     facing: NDArray[np.float64], starts: NDArray[np.intp]) -> float:
    """The most evidence one movable object gives: of the objects (``starts``, see
    :func:`_objects`), those whose surface facing the weakest direction u spans at most
    MOVABLE_EXTENT count. That surface is the object's points whose normals lie within 45° of
    ±u (``facing`` = n·u, facing² ≥ ½), the points that carry its evidence along u: a person
    standing by a wall is one run of beams with the wall, and only the person faces along the
    corridor."""
    if len(starts) == 0:
        return 0.0
    points = np.asarray(points, dtype=float)
    faces = (np.asarray(facing, dtype=float) ** 2 >= 0.5)[:, None]
    low = np.minimum.reduceat(np.where(faces, points, np.inf), starts, axis=0)
    high = np.maximum.reduceat(np.where(faces, points, -np.inf), starts, axis=0)
    with np.errstate(invalid="ignore"):  # an object with no facing point spans nothing
        span = np.nan_to_num(np.hypot(*(high - low).T), nan=0.0, posinf=0.0)
    movable = span <= MOVABLE_EXTENT
    per_object = np.add.reduceat(evidence, starts)
    return float(per_object[movable].max()) if movable.any() else 0.0


def _object_disagreement(evidence: NDArray[np.float64], moment: NDArray[np.float64],
                         starts: NDArray[np.intp], sigma2: float) -> tuple[float, int]:
    """How far the objects disagree on the motion along the weakest direction u: (Q, dof).

    Object j alone would shift the scan along u by δⱼ = −Σ wᵢ aᵢ rᵢ / Eⱼ (least squares on
    its residuals rᵢ, aᵢ = nᵢ·u, Eⱼ = Σ wᵢ aᵢ², its evidence), with variance σ²/Eⱼ. On a rigid
    scene every δⱼ is the same up to that noise, and Q = Σ Eⱼ (δⱼ − δ̄)²/σ² (δ̄ the
    evidence-weighted mean) is χ² with (objects − 1) degrees of freedom; objects that moved
    between the scans (people walking) make it large. Objects with less than one point's
    worth of evidence along u are left out: they do not observe it."""
    if len(starts) == 0:
        return 0.0, 0
    e = np.add.reduceat(evidence, starts)
    m = np.add.reduceat(moment, starts)
    seen = e >= 1.0
    if seen.sum() < 2:
        return 0.0, 0
    e, shift = e[seen], -m[seen] / e[seen]
    mean = float(e @ shift / e.sum())
    return float(e @ (shift - mean) ** 2 / sigma2), int(seen.sum()) - 1


@njit
def _icp(previous: NDArray, normals: NDArray, usable: NDArray, current: NDArray,
         x: NDArray, iterations: int, max_pair: float, final_pair: float, huber: float,
         min_points: int
         ) -> tuple[bool, NDArray, NDArray, float, float, NDArray, NDArray, NDArray]:
    """The Gauss–Newton iterations of :func:`point_to_line_icp`: (found, x, JᵀWJ + damping,
    σ̂², overlap, each current point's paired normal, Huber weight and residual at the last
    iteration, zero where unpaired). Nearest neighbours come from a grid of the previous scan
    (:func:`_nearest`)."""
    index = _cell_index(previous, _grid_cell(previous, final_pair))
    n = len(current)
    residual, weight = np.zeros(n), np.zeros(n)
    paired_normals = np.zeros((n, 2))
    hessian = np.eye(3)
    shrink = max(1.0, 0.6 * iterations)
    paired = 0
    for iteration in range(iterations):
        progress = min(1.0, iteration / shrink)
        reach = max_pair + (final_pair - max_pair) * progress
        c, s = math.cos(x[2]), math.sin(x[2])
        hessian = np.zeros((3, 3))
        gradient = np.zeros(3)
        paired = 0
        for i in range(n):  # q = R(θ) cᵢ + t, as the matrix product [cᵢ]·[[c, s], [−s, c]]
            qx = fma(current[i, 1], -s, current[i, 0] * c) + x[0]
            qy = fma(current[i, 1], c, current[i, 0] * s) + x[1]
            j = _nearest(previous, index, qx, qy, reach)
            if j < 0 or not usable[j]:
                residual[i] = weight[i] = 0.0
                paired_normals[i, 0] = paired_normals[i, 1] = 0.0
                continue
            paired += 1
            nx, ny = normals[j, 0], normals[j, 1]
            paired_normals[i, 0], paired_normals[i, 1] = nx, ny
            r = nx * (qx - previous[j, 0]) + ny * (qy - previous[j, 1])
            ax, ay = qx - x[0], qy - x[1]  # ∂(R q)/∂θ = (−(Rq)_y, (Rq)_x)
            jac = (nx, ny, ny * ax - nx * ay)
            w = 1.0 / max(1.0, abs(r) / huber)
            residual[i], weight[i] = r, w
            for a in range(3):
                gradient[a] += jac[a] * w * r
                for b in range(3):
                    hessian[a, b] += jac[a] * jac[b] * w
        if paired < min_points:
            return False, x, hessian, 0.0, 0.0, paired_normals, weight, residual
        hessian += _DAMPING * np.eye(3)
        # damped: along a featureless corridor one direction has no information; the step
        # leaves it alone and the covariance calls it unknown (σ² ~ σ̂²/damping)
        step = -np.linalg.solve(hessian, gradient)
        x += step
        if np.abs(step).max() < 1e-5:
            break
    dof = max(1, paired - 3)
    sigma2 = max((weight * residual**2).sum() / dof, 1e-6)
    return True, x, hessian, sigma2, paired / n, paired_normals, weight, residual


GRID_CELLS = 262_144
"""Cells of the previous scan's grid at most (2 MB of counts): a scan spread over a hall has
coarser cells rather than a grid as large as the hall."""


@njit
def _grid_cell(points: NDArray, final_pair: float) -> float:
    """The side of the grid's cells: the last pairing distance, so that the nearest wall point
    is mostly in the 3 × 3 cells around a point; coarser only beyond ``GRID_CELLS``."""
    width = points[:, 0].max() - points[:, 0].min()
    height = points[:, 1].max() - points[:, 1].min()
    return max(final_pair, math.sqrt(width * height / GRID_CELLS), 1e-3)


@njit
def _cell_index(points: NDArray, cell: float) -> tuple:
    """Points bucketed in square cells of side ``cell`` (a counting sort): the grid's origin,
    1/cell, its width and height in cells, and ``start``, ``order`` such that
    ``order[start[c]:start[c + 1]]`` are the points of cell c (row-major)."""
    ox, oy = points[:, 0].min(), points[:, 1].min()
    inv_cell = 1.0 / cell
    nx = int((points[:, 0].max() - ox) * inv_cell) + 1
    ny = int((points[:, 1].max() - oy) * inv_cell) + 1
    of = np.empty(len(points), np.intp)
    counts = np.zeros(nx * ny + 1, np.intp)
    for k in range(len(points)):
        of[k] = int((points[k, 1] - oy) * inv_cell) * nx + int((points[k, 0] - ox) * inv_cell)
        counts[of[k] + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    order = np.empty(len(points), np.intp)
    for k in range(len(points)):
        order[fill[of[k]]] = k
        fill[of[k]] += 1
    return ox, oy, inv_cell, nx, ny, start, order


@njit
def _nearest(points: NDArray, index: tuple, x: float, y: float, reach: float) -> int:
    """The point of :func:`_cell_index` nearest (x, y) and closer than ``reach``, or −1 (ties:
    the lowest index).

    Cells are searched in square rings around the one holding (x, y), the nearest first; the
    search stops when the next ring lies farther than the best point found (or than ``reach``):
    a point beyond the rings searched is at least as far as their outer edge. Along a wall the
    nearest point is centimetres away, so one or two rings are searched, not all of ``reach``.
    """
    ox, oy, inv_cell, nx, ny, start, order = index
    cell = 1.0 / inv_cell
    cx, cy = math.floor((x - ox) * inv_cell), math.floor((y - oy) * inv_cell)
    best, best_d2 = -1, reach * reach
    rings = int(reach * inv_cell) + 2
    for ring in range(rings):
        if ring > 0:
            # the distance from (x, y) to the outside of the rings searched so far; a point's
            # cell is rounded from its coordinates, so the bound is loosened by a micrometre
            edge = min(x - (ox + (cx - ring + 1) * cell), ox + (cx + ring) * cell - x,
                       y - (oy + (cy - ring + 1) * cell), oy + (cy + ring) * cell - y) - 1e-6
            if edge > 0.0 and edge * edge > best_d2:
                break
        for gy in range(max(cy - ring, 0), min(cy + ring + 1, ny)):
            on_edge_row = gy == cy - ring or gy == cy + ring
            step = 1 if on_edge_row else 2 * ring  # else only its two ends (ring ≥ 1)
            gx = cx - ring
            while gx <= cx + ring:
                if 0 <= gx < nx:
                    c = gy * nx + gx
                    for m in range(start[c], start[c + 1]):
                        k = order[m]
                        d2 = (points[k, 0] - x) ** 2 + (points[k, 1] - y) ** 2
                        if d2 < best_d2 or (d2 == best_d2 and 0 <= k < best):
                            best, best_d2 = k, d2
                gx += step
    return best

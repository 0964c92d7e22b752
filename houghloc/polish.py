"""The fix polished on the scan's points (docs/method.md §5).

The Hough fix reads the pose off the lines whose peaks the scan voted for: walls long enough and
dense enough to be lines. The scan's other points lie on the map's walls too — door frames,
short pieces, the ends of corridors, corners — and the lines' own points weigh by their number.
So the fix is polished: each point within ``polish_gate`` of a wall of the map is paired with
the nearest such segment, and the pose that brings the points onto their walls' lines is found
by Gauss–Newton, starting at the fix. With q = R(θ)p the point p turned into the map frame, a
the segment's start and n its unit normal:

    rᵢ = nᵢ·(qᵢ + t − aᵢ),    ∂rᵢ/∂(x, y, θ) = Jᵢ = [nᵢₓ, nᵢᵧ, nᵢ·(−qᵢᵧ, qᵢₓ)].

A wall of the map is off the real one by the map's model error (``line_rho_floor``,
``line_theta_floor``), the same for every point on it, so the points of one map line g are not
independent: their residuals have the covariance

    Σ_g = σ_g² W_g⁻¹ + U F Uᵀ,   U = [1, sᵢ − s̄],   F = diag(ρ_floor², θ_floor²),

sᵢ the point's place along the line (s̄ their weighted mean), W_g the points' relative weights,
σ_g² the weighted scatter of the residuals (at least ``point_sigma_floor``²). The normal equations
sum Jᵀ Σ_g⁻¹ J over the lines; by the Woodbury identity, with a = Σ wᵢJᵢ, b = Σ wᵢJᵢ(sᵢ − s̄),

    Jᵀ Σ_g⁻¹ J = (Jᵀ W J − m₀ a aᵀ − m₁ b bᵀ) / σ_g²,
    m₀ = ρ_floor² / (σ_g² + ρ_floor² Σwᵢ),   m₁ = θ_floor² / (σ_g² + θ_floor² Σwᵢ(sᵢ − s̄)²),

and likewise for Jᵀ Σ_g⁻¹ r. Without floors (an exact map) this is plain least squares. The step
is taken only in the directions the fix observed (a corridor fix stays where it was along the
corridor), and its covariance is (Bᵀ H B)⁻¹ in those directions, B their basis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig, derived
from houghloc.jit import njit
from houghloc.segment_map import SegmentMap, check_grid_size
from houghloc.subspace import expand, project, project_vector, solve_spd, well_conditioned

MAX_STEPS = 5
"""Gauss–Newton steps at most. The residuals are linear in the translation and nearly so in a
small turn: from a fix, three or four steps converge (Intel: 90 % within five). Beyond, the
pairings of points at the gate's edge flip back and forth, and what they move is below the
laser's noise."""
CONVERGED = 1e-4
"""m (and rad): a step smaller than this (a tenth of a millimetre) ends the iterations."""


@dataclass(frozen=True)
class WallCells:
    """For each square cell of side ``cell`` (one ``polish_gate``), the segments of the map's
    kinds that come within that distance of some point of it: ``candidates[first[c]:first[c +
    1]]`` for the cell c = row·width + column, rows along y from ``origin``."""

    origin: NDArray[np.float64]
    cell: float
    width: int
    height: int
    first: NDArray[np.int64]
    candidates: NDArray[np.int64]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    normal: NDArray[np.float64]
    """each segment's unit normal, its map line's: the same for every segment of a line"""
    line: NDArray[np.int64]

    @cached_property
    def kernel_args(self) -> tuple:
        """The cells as :func:`_polish_kernel` takes them (built once)."""
        return (float(self.origin[0]), float(self.origin[1]), 1.0 / self.cell, self.width,
                self.height, self.first, self.candidates,
                _candidate_rows(self.candidates, self.starts, self.ends), self.starts,
                self.normal, self.line, int(self.line.max()) + 1 if len(self.line) else 0)


@njit
def _candidate_rows(candidates: NDArray, starts: NDArray, ends: NDArray) -> NDArray:
    """Per entry of ``candidates``, its segment's start a, direction e = end − a and
    max(|e|², 10⁻³⁰⁰), in the candidates' order: :func:`_pair` reads a cell's segments as one
    run of memory."""
    rows = np.empty((len(candidates), 5))
    for k in range(len(candidates)):
        j = candidates[k]
        ax, ay = starts[j, 0], starts[j, 1]
        ex, ey = ends[j, 0] - ax, ends[j, 1] - ay
        rows[k, 0], rows[k, 1], rows[k, 2], rows[k, 3] = ax, ay, ex, ey
        rows[k, 4] = max(ex * ex + ey * ey, 1e-300)
    return rows


def build_wall_cells(map: SegmentMap, kinds: tuple[str, ...], gate: float) -> WallCells:
    """Each segment is sampled every half cell; a point within ``gate`` of it is within
    gate + cell/4 of a sample, hence at most two cells from the sample's cell in each axis, so
    the 5 × 5 cells around every sample list it."""
    segs = np.flatnonzero(map.kind_mask(kinds))
    starts, ends = map.starts[segs], map.ends[segs]
    cell = float(gate)
    reach = math.ceil((gate + 0.25 * cell) / cell)
    if len(segs) == 0:
        return WallCells(np.zeros(2), cell, 1, 1, np.zeros(2, np.int64), np.empty(0, np.int64),
                         starts, ends, np.empty((0, 2)), np.empty(0, np.int64))
    both = np.concatenate((starts, ends))
    origin = both.min(axis=0) - (reach + 1) * cell
    width, height = (np.ceil((both.max(axis=0) - origin) / cell).astype(int) + reach + 2)
    check_grid_size((int(height), int(width)), cell, f"map {map.source}")
    lengths = np.linalg.norm(ends - starts, axis=1)
    count = np.ceil(lengths / (0.5 * cell)).astype(np.int64) + 1
    sample_of = np.repeat(np.arange(len(segs)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    frac = k / np.maximum(count[sample_of] - 1, 1)
    samples = starts[sample_of] + frac[:, None] * (ends - starts)[sample_of]
    col = np.floor((samples[:, 0] - origin[0]) / cell).astype(np.int64)
    row = np.floor((samples[:, 1] - origin[1]) / cell).astype(np.int64)
    shifts = np.arange(-reach, reach + 1)
    dr, dc = (v.ravel() for v in np.meshgrid(shifts, shifts, indexing="ij"))
    cells = ((row[:, None] + dr) * width + (col[:, None] + dc)).ravel()
    pairs = np.unique(cells * len(segs) + np.repeat(sample_of, len(dr)))
    cell_of, seg_of = np.divmod(pairs, len(segs))
    first = np.searchsorted(cell_of, np.arange(int(width) * int(height) + 1))
    line = map.line_of_segment[segs]
    alpha = map.line_alpha[line]
    return WallCells(origin, cell, int(width), int(height), first.astype(np.int64),
                     seg_of.astype(np.int64), np.ascontiguousarray(starts),
                     np.ascontiguousarray(ends), np.column_stack((np.cos(alpha), np.sin(alpha))),
                     line.astype(np.int64))


def polish_pose(points: NDArray[np.float64], weights: NDArray[np.float64] | None,
                cells: WallCells, pose: NDArray[np.float64], basis: NDArray[np.float64],
                config: HoughConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The pose that brings ``points`` (robot frame; relative ``weights``, mean 1, or None for
    equal ones) onto the map's walls, moved from ``pose`` only along the columns of ``basis``
    (3×k, orthonormal), and the k×k covariance of that move (module docstring); None when the
    points do not pin it (fewer than two map lines with ``min_piece_points`` points each, or
    too weak a system)."""
    polished, information, ok = _polish_kernel(*_kernel_args(points, weights, cells, pose,
                                                             basis, config))
    return (polished, np.linalg.inv(information)) if ok else None


def polish_fix(points: NDArray[np.float64], weights: NDArray[np.float64] | None,
               cells: WallCells, pose: NDArray[np.float64], cov: NDArray[np.float64],
               observable: NDArray[np.float64], unobservable: NDArray[np.float64],
               gate: float, unobserved_variance: float, config: HoughConfig
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """A fix (``pose``, ``cov``, its ``observable`` and ``unobservable`` bases) polished: its
    pose, 3×3 covariance (``unobserved_variance`` along the unobservable directions) and
    information; None where :func:`polish_pose` finds nothing, or where the polished pose lies
    beyond the χ² ``gate`` of the fix's own covariance (the points then disagree with the lines
    that were matched, and the lines are kept). One compiled call."""
    args = _kernel_args(points, weights, cells, pose, observable, config)
    polished, new_cov, information, ok = _polish_fix_kernel(
        args, np.ascontiguousarray(cov, dtype=float),
        np.ascontiguousarray(unobservable, dtype=float), gate, unobserved_variance)
    return (polished, new_cov, information) if ok else None


def _kernel_args(points: NDArray, weights: NDArray | None, cells: WallCells, pose: NDArray,
                 basis: NDArray, config: HoughConfig) -> tuple:
    unit = weights is None
    return (np.ascontiguousarray(points, dtype=float),
            _ONE if unit else np.ascontiguousarray(weights, dtype=float), unit,
            np.array(pose, dtype=float), np.ascontiguousarray(basis, dtype=float),
            *cells.kernel_args, *derived(config, "polish", lambda: _config_args(config)))


def _config_args(config: HoughConfig) -> tuple[float, float, float, float, int]:
    return (float(config.polish_gate or 0.0), config.line_rho_floor**2,
            config.line_theta_floor**2, config.point_sigma_floor**2, config.min_piece_points)


_ONE = np.ones(1)


@njit
def _polish_fix_kernel(args: tuple, cov: NDArray, unobservable: NDArray, gate: float,
                       unobserved_variance: float) -> tuple:
    pose = args[3].copy()
    basis = args[4]
    polished, information, ok = _polish_kernel(*args)
    if not ok:
        return polished, cov, information, False
    k = basis.shape[1]
    step = project_vector(basis, polished - pose)  # θ unwrapped: the polish turns from the fix's
    spread = np.empty((k, k))
    project(basis, cov, spread)
    if not step @ solve_spd(spread, step) <= gate:  # NaN too: a spread not positive definite
        return polished, cov, information, False
    reduced_cov = np.empty((k, k))
    unit = np.zeros(k)
    for j in range(k):  # (BᵀHB)⁻¹ column by column
        unit[:] = 0.0
        unit[j] = 1.0
        reduced_cov[:, j] = solve_spd(information, unit)
    new_cov = expand(basis, reduced_cov)
    for i in range(3):
        for j in range(3):
            for c in range(unobservable.shape[1]):
                new_cov[i, j] += unobserved_variance * unobservable[i, c] * unobservable[j, c]
    return polished, new_cov, expand(basis, information), True


@njit
def _pair(points: NDArray, pose: NDArray, ox: float, oy: float, inv_cell: float, width: int,
          height: int, first: NDArray, candidates: NDArray, rows: NDArray, gate: float,
          out: NDArray) -> None:
    """Each point's nearest segment within ``gate`` at ``pose`` (−1: none), into ``out``
    (``rows``: :func:`_candidate_rows`)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    gate_sq = gate * gate
    for i in range(points.shape[0]):
        out[i] = -1
        wx = pose[0] + c * points[i, 0] - s * points[i, 1]
        wy = pose[1] + s * points[i, 0] + c * points[i, 1]
        fx, fy = (wx - ox) * inv_cell, (wy - oy) * inv_cell
        if not (0.0 <= fx < width and 0.0 <= fy < height):  # off the grid: no wall near
            continue
        cell = int(fy) * width + int(fx)
        best = gate_sq
        for k in range(first[cell], first[cell + 1]):
            ax, ay, ex, ey = rows[k, 0], rows[k, 1], rows[k, 2], rows[k, 3]
            along = ((wx - ax) * ex + (wy - ay) * ey) / rows[k, 4]
            along = min(max(along, 0.0), 1.0)
            dx, dy = wx - ax - along * ex, wy - ay - along * ey
            d_sq = dx * dx + dy * dy
            if d_sq <= best:
                best = d_sq
                out[i] = candidates[k]


_SUMS = 21
"""Per map line: Σw, Σws, Σws², Σwr, Σwr², Σwsr, Σw J (3), Σw J s (3), Σw J r (3), Σw JJᵀ (6)."""


@njit
def _normal_equations(points: NDArray, w: NDArray, unit: bool, pose: NDArray, paired: NDArray,
                      starts: NDArray, normal: NDArray, line: NDArray, rho_floor_sq: float,
                      theta_floor_sq: float, sigma_floor_sq: float, min_points: int,
                      slot: NDArray, keys: NDArray, counts: NDArray, sums: NDArray, H: NDArray,
                      g: NDArray) -> int:
    """H = Σ_g Jᵀ Σ_g⁻¹ J and g = Σ_g Jᵀ Σ_g⁻¹ r over the map lines with ``min_points`` paired
    points (module docstring), into ``H`` and ``g``; returns how many lines there were. One pass
    over the points adds each one's terms to its line's sums, in the order the lines are first met
    (``slot``: each map line's row of the sums, −1 for none; all −1 on entry and on return).
    ``keys``, ``counts`` and ``sums`` are work space of a row per point."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    n_keys = 0
    for i in range(points.shape[0]):
        j = paired[i]
        if j < 0:
            continue
        key = line[j]
        u = slot[key]
        if u < 0:
            u = n_keys
            slot[key] = u
            keys[u] = key
            counts[u] = 0
            sums[u, :] = 0.0
            n_keys += 1
        counts[u] += 1
        qx = c * points[i, 0] - s * points[i, 1]
        qy = s * points[i, 0] + c * points[i, 1]
        nx, ny = normal[j, 0], normal[j, 1]
        rx, ry = pose[0] + qx - starts[j, 0], pose[1] + qy - starts[j, 1]
        r = nx * rx + ny * ry
        # the place along the map line, measured the same way on all its segments
        along = -ny * (starts[j, 0] + rx) + nx * (starts[j, 1] + ry)
        jac = (nx, ny, -qy * nx + qx * ny)
        wi = 1.0 if unit else w[i]
        row = sums[u]
        row[0] += wi
        row[1] += wi * along
        row[2] += wi * along * along
        row[3] += wi * r
        row[4] += wi * r * r
        row[5] += wi * along * r
        col = 15
        for k in range(3):
            wj = wi * jac[k]
            row[6 + k] += wj
            row[9 + k] += wj * along
            row[12 + k] += wj * r
            for m in range(k, 3):
                row[col] += wj * jac[m]
                col += 1
    H[:, :] = 0.0
    g[:] = 0.0
    groups = 0
    for u in range(n_keys):
        slot[keys[u]] = -1
        if counts[u] >= min_points:
            groups += 1
            _add_line(sums[u], rho_floor_sq, theta_floor_sq, sigma_floor_sq, H, g)
    return groups


@njit
def _add_line(row: NDArray, rho_floor_sq: float, theta_floor_sq: float, sigma_floor_sq: float,
              H: NDArray, g: NDArray) -> None:
    """One map line's Jᵀ Σ⁻¹ J and Jᵀ Σ⁻¹ r, added to H and g, from its sums (module
    docstring: Woodbury; the sums centred on the points' mean place along the line)."""
    total, sum_s, sum_ss, sum_r, sum_rr, sum_sr = row[0], row[1], row[2], row[3], row[4], row[5]
    s_mean = sum_s / total
    r_mean = sum_r / total
    sigma_sq = max(sum_rr / total - r_mean * r_mean, sigma_floor_sq)
    spread = max(sum_ss - total * s_mean * s_mean, 0.0)  # Σw(s − s̄)²
    m0 = rho_floor_sq / (sigma_sq + rho_floor_sq * total)
    m1 = theta_floor_sq / (sigma_sq + theta_floor_sq * spread)
    b_r = sum_sr - s_mean * sum_r  # Σw(s − s̄)r
    col = 15
    for k in range(3):
        a_k = row[6 + k]
        b_k = row[9 + k] - s_mean * a_k  # Σ wJ(s − s̄)
        g[k] += (row[12 + k] - m0 * a_k * sum_r - m1 * b_k * b_r) / sigma_sq
        for m in range(k, 3):
            a_m = row[6 + m]
            b_m = row[9 + m] - s_mean * a_m
            value = (row[col] - m0 * a_k * a_m - m1 * b_k * b_m) / sigma_sq
            col += 1
            H[k, m] += value
            if m != k:
                H[m, k] += value


@njit
def _polish_kernel(points: NDArray, w: NDArray, unit: bool, pose: NDArray, basis: NDArray,
                   ox: float,
                   oy: float, inv_cell: float, width: int, height: int, first: NDArray,
                   candidates: NDArray, rows: NDArray, starts: NDArray, normal: NDArray,
                   line: NDArray, n_lines: int, gate: float, rho_floor_sq: float,
                   theta_floor_sq: float, sigma_floor_sq: float, min_points: int) -> tuple:
    """Gauss–Newton from ``pose`` in the span of ``basis``: (pose, BᵀHB at it, ok)."""
    k = basis.shape[1]
    reduced = np.zeros((k, k))
    n = points.shape[0]
    paired = np.empty(n, np.int64)
    slot = np.full(n_lines, -1, np.int64)
    keys = np.empty(n, np.int64)
    counts = np.empty(n, np.int64)
    sums = np.empty((n, _SUMS))
    H = np.empty((3, 3))
    g = np.empty(3)
    for step in range(MAX_STEPS + 1):
        _pair(points, pose, ox, oy, inv_cell, width, height, first, candidates, rows, gate,
              paired)
        groups = _normal_equations(points, w, unit, pose, paired, starts, normal, line,
                                   rho_floor_sq, theta_floor_sq, sigma_floor_sq, min_points,
                                   slot, keys, counts, sums, H, g)
        project(basis, H, reduced)
        if groups < 2 or not well_conditioned(reduced):
            return pose, reduced, False
        if step == MAX_STEPS:
            break
        # the step Δ = −B (BᵀHB)⁻¹ Bᵀg, the Gauss–Newton step confined to the span of B
        converged = True
        solution = solve_spd(reduced, project_vector(basis, g))
        for i in range(3):
            move = 0.0
            for j in range(k):
                move -= basis[i, j] * solution[j]
            pose[i] += move
            converged = converged and abs(move) < CONVERGED
        if converged:
            break
    return pose, reduced, True

"""The Hough grid and its voting (docs/method.md §1–2).

Normal form ρ = x cos θ + y sin θ with θ ∈ [0, 2π) and ρ ≥ 0: in the robot frame every line has
one point and θ is cyclic. A few cells below ρ = 0 (``rho_margin_cells``) catch lines through the
sensor.

With ρ ≥ 0 a point votes in only half of the θ rows (the other half sees it at ρ < 0). The votes
are therefore cast over θ ∈ [0, π) with signed ρ, half the work, and unfolded: the row θ + π at ρ
is the row θ at −ρ, since (θ + π, ρ) ≡ (θ, −ρ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig
from houghloc.geometry import TWO_PI
from houghloc.jit import fma, njit


@dataclass(frozen=True)
class HoughGrid:
    """Cell layout: ``n_theta`` angles from 0 (cyclic) and ``n_rho`` distances from ``rho_min``."""

    theta_step: float
    rho_step: float
    rho_min: float
    n_theta: int
    n_rho: int
    # cos/sin of the cell centres, 2×T, for one matrix product per scan
    trig: NDArray[np.float64]
    # cos/sin of the first half-circle's cell centres over δρ (float32), 2×(T/2): ρ in cells
    half_trig32: NDArray[np.float32]
    signed_cells: int  # n_rho − margin: cells on each side of ρ = 0 in a signed row
    margin_cells: int

    @property
    def thetas(self) -> NDArray[np.float64]:
        return np.arange(self.n_theta, dtype=np.float64) * self.theta_step

    @property
    def rhos(self) -> NDArray[np.float64]:
        return self.rho_min + (np.arange(self.n_rho, dtype=np.float64) + 0.5) * self.rho_step

    def cell_center(self, i_theta: NDArray, i_rho: NDArray) -> tuple[NDArray, NDArray]:
        return i_theta * self.theta_step, self.rho_min + (i_rho + 0.5) * self.rho_step


@lru_cache(maxsize=16)
def _grid(theta_step: float, rho_step: float, rho_max: float, margin_cells: int) -> HoughGrid:
    # a whole, even number of cells around the circle keeps θ cyclic and makes θ + π a row
    n_theta = 2 * max(2, round(np.pi / theta_step))
    theta_step = TWO_PI / n_theta
    thetas = np.arange(n_theta) * theta_step
    rho_min = -margin_cells * rho_step
    n_rho = int(np.ceil((rho_max - rho_min) / rho_step))
    trig = np.vstack((np.cos(thetas), np.sin(thetas)))
    signed = n_rho - margin_cells
    half = n_theta // 2
    return HoughGrid(theta_step, rho_step, rho_min, n_theta, n_rho, trig,
                     (trig[:, :half] / rho_step).astype(np.float32), signed, margin_cells)


def make_grid(config: HoughConfig) -> HoughGrid:
    """The grid for a configuration (cached: building it once per configuration is enough)."""
    return _grid(config.theta_step, config.rho_step, config.rho_max, config.rho_margin_cells)


def vote(points: NDArray[np.float64], grid: HoughGrid) -> NDArray[np.int32]:
    """Accumulate HT(θ, ρ): each point votes once per θ row, in the cell where its ρ falls.

    The signed ρ of every (point, θ < π) is computed in float32 (it resolves ρ to a micrometre
    at 20 m; the grid is centimetres) as ρ/δρ = (x cos θ + y sin θ)/δρ, one fused multiply-add.
    The cell coordinate is shifted so that truncation is floor; votes beyond ±``rho_max`` clip
    into a guard cell at each end of the signed row, which no cell reads; so do the votes of a
    point that is not finite (NaN or ±inf cast none). Each signed vote lands
    in two rows of the unfolded accumulator (θ ∈ [0, 2π), ρ ≥ ρ_min): row θ at ρ, and row θ + π
    at −ρ, since (θ + π, ρ) ≡ (θ, −ρ); a vote within the margin of ρ = 0 counts in both.
    Returns the accumulator, ``n_theta × n_rho``.
    """
    acc = np.empty((grid.n_theta, grid.n_rho), dtype=np.int32)
    _vote_kernel(np.ascontiguousarray(points, dtype=float), grid.half_trig32, grid.signed_cells,
                 grid.margin_cells, acc)
    return acc


@njit
def _vote_kernel(points: NDArray[np.float64], half_trig32: NDArray[np.float32], u: int, m: int,
                 acc: NDArray[np.int32]) -> None:
    half, n_rho, n = half_trig32.shape[1], acc.shape[1], points.shape[0]
    shift = np.float32(u + 1)  # signed cell c − (u + 1) holds ρ/δρ
    cos_, sin_ = half_trig32[0].copy(), half_trig32[1].copy()
    # point by point, all rows at once: consecutive points of a wall fall in the same cell of a
    # row, and counting them one after the other would wait on each increment; across rows the
    # increments are independent. Unsigned cells need no wrap-around check.
    xs, ys = points[:, 0].astype(np.float32), points[:, 1].astype(np.float32)
    # |ρ| ≤ |p|: when the farthest point reaches r < u cells, the signed rows hold only the full
    # row's cells u − r − 1 to u + r + 2: the cells read below (u − r to u + r + 1) and a guard
    # at each end. The full row's other cells get no vote.
    r = _reach_cells(xs, ys, cos_, sin_, u)
    skip, size = (u - r - 1, 2 * r + 4) if r < u else (0, 2 * u + 2)
    low, high = np.float32(skip), np.float32(skip + size - 1)  # the guards, in full-row cells
    signed = np.zeros((half, size), np.int32)
    cells = np.empty(half, np.uint32)
    for k in range(n):
        x, y = xs[k], ys[k]
        for i in range(half):  # the cells first (vectorised), then the counts
            q = fma(y, sin_[i], x * cos_[i]) + shift
            q = q if q >= low else low  # NaN too: a non-finite point votes in a guard cell
            q = q if q <= high else high
            cells[i] = np.uint32(q) - np.uint32(skip)
        for i in range(half):
            signed[i, cells[i]] += 1
    # cell j of row θ holds ρ ∈ [(j − m)δ, (j − m + 1)δ): the full row's signed cell j − m; in
    # row θ + π the mirrored signed cell −(j − m + 1); both shifted by u + 1 for the guard, and
    # by −skip where they are stored. Cells [first, last) of a row can hold votes.
    first, last = max(m - 1 - r, 0), min(r + 1 + m, n_rho)
    for i in range(half):
        row = acc[i]  # separate loops: each is then a vectorised fill or copy
        mirrored = acc[i + half]
        for j in range(first):
            row[j] = 0
            mirrored[j] = 0
        for j in range(last, n_rho):
            row[j] = 0
            mirrored[j] = 0
        forward = signed[i, u + 1 - m + first - skip: u + 1 - m + last - skip]
        for j in range(last - first):
            row[first + j] = forward[j]
        backward = signed[i, u + m + 1 - last - skip: u + m + 1 - first - skip]  # from its end
        for j in range(last - first):
            mirrored[first + j] = backward[last - first - 1 - j]


@njit
def _reach_cells(xs: NDArray[np.float32], ys: NDArray[np.float32], cos_: NDArray[np.float32],
                 sin_: NDArray[np.float32], u: int) -> int:
    """A bound on |ρ|/δρ over the finite points and the rows, plus two cells, at most ``u``:
    |ρ| ≤ |p|·|(cos θ, sin θ)|, the rows' trig already over δρ; the float32 cells are exact to
    far less than a cell."""
    far = 0.0
    for k in range(xs.shape[0]):
        d = float(xs[k]) * float(xs[k]) + float(ys[k]) * float(ys[k])
        if d > far and d < math.inf:
            far = d
    scale = 0.0
    for i in range(cos_.shape[0]):
        scale = max(scale, float(cos_[i]) * float(cos_[i]) + float(sin_[i]) * float(sin_[i]))
    bound = math.sqrt(far * scale)
    return u if not bound + 2.0 < u else int(bound) + 2

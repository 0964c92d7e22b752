"""The Hough grid and its voting (DESIGN §3.1–3.2).

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
    # first flat index of each half-circle row in the voting buffer: signed-ρ rows of
    # 2·(n_rho − margin) cells with a guard cell at each end, so that out-of-range votes are
    # clipped there instead of filtered out
    half_offsets: NDArray[np.intp]
    signed_cells: int  # n_rho − margin: cells on each side of ρ = 0 in a signed row
    margin_cells: int

    @property
    def thetas(self) -> NDArray[np.float64]:
        return np.arange(self.n_theta) * self.theta_step

    @property
    def rhos(self) -> NDArray[np.float64]:
        return self.rho_min + (np.arange(self.n_rho) + 0.5) * self.rho_step

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
    offsets = (np.arange(half, dtype=np.intp) * (2 * signed + 2))[None, :]
    return HoughGrid(theta_step, rho_step, rho_min, n_theta, n_rho, trig,
                     (trig[:, :half] / rho_step).astype(np.float32), offsets, signed, margin_cells)


def make_grid(config: HoughConfig) -> HoughGrid:
    """The grid for a configuration (cached: building it once per configuration is enough)."""
    return _grid(config.theta_step, config.rho_step, config.rho_max, config.rho_margin_cells)


def vote(points: NDArray[np.float64], grid: HoughGrid) -> NDArray[np.int64]:
    """Accumulate HT(θ, ρ): each point votes once per θ row, in the cell where its ρ falls.

    One float32 matrix product gives the signed ρ for every (point, θ < π) (float32 resolves ρ to
    a micrometre at 20 m; the grid is centimetres). The cell coordinate is shifted so that
    truncation is floor and out-of-range votes clip into a guard cell at each end of the row
    (cheaper than filtering); ``np.bincount`` sums the flat indices. The signed rows are then
    unfolded into θ ∈ [0, 2π), ρ ≥ ρ_min. Returns the accumulator, ``n_theta × n_rho``.
    """
    u, m, n_rho = grid.signed_cells, grid.margin_cells, grid.n_rho
    q = points.astype(np.float32) @ grid.half_trig32  # N×(T/2): ρ/δρ = (x cos θ + y sin θ)/δρ
    q += np.float32(u + 1)  # signed cell index + guard
    if np.abs(points).max(initial=0.0) * math.sqrt(2.0) >= u * grid.rho_step:  # |ρ| ≤ |x| + |y|
        np.clip(q, 0.0, 2 * u + 1, out=q)  # only points out of range need the guards
    flat = q.astype(np.intp)
    flat += grid.half_offsets
    width = 2 * u + 2
    signed = np.bincount(flat.ravel(), minlength=(grid.n_theta // 2) * width).reshape(-1, width)
    # cell c of row θ holds ρ ∈ [(c − m)δ, (c − m + 1)δ): the signed cell c − m of row θ, and for
    # row θ + π the signed cell −(c − m + 1) (mirrored), both shifted by u + 1 for the guard
    return np.concatenate((signed[:, u + 1 - m: u + 1 - m + n_rho],
                           signed[:, u + m: u + m - n_rho: -1]))

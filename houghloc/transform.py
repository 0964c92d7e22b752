"""The Hough grid and its voting (DESIGN §3.1–3.2).

Normal form ρ = x cos θ + y sin θ with θ ∈ [0, 2π) and ρ ≥ 0: in the robot frame every line has
one point and θ is cyclic. A few cells below ρ = 0 (``rho_margin_cells``) catch lines through the
sensor.
"""

from __future__ import annotations

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
    # first flat index of each θ row in the voting buffer, whose rows carry a guard cell at each
    # end (n_rho + 2 wide) so out-of-range votes are clipped there instead of filtered out
    row_offsets: NDArray[np.int32]
    trig32: NDArray[np.float32]

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
    n_theta = max(4, round(TWO_PI / theta_step))
    theta_step = TWO_PI / n_theta  # a whole number of cells around the circle keeps θ cyclic
    thetas = np.arange(n_theta) * theta_step
    rho_min = -margin_cells * rho_step
    n_rho = int(np.ceil((rho_max - rho_min) / rho_step))
    trig = np.vstack((np.cos(thetas), np.sin(thetas)))
    offsets = (np.arange(n_theta, dtype=np.int32) * (n_rho + 2))[None, :]
    return HoughGrid(theta_step, rho_step, rho_min, n_theta, n_rho, trig, offsets,
                     trig.astype(np.float32))


def make_grid(config: HoughConfig) -> HoughGrid:
    """The grid for a configuration (cached: building it once per configuration is enough)."""
    return _grid(config.theta_step, config.rho_step, config.rho_max, config.rho_margin_cells)


def vote(points: NDArray[np.float64], grid: HoughGrid) -> NDArray[np.int64]:
    """Accumulate HT(θ, ρ): each point votes once per θ column, in the cell where its ρ falls.

    One float32 matrix product gives ρ for every (point, θ) (float32 resolves ρ to a micrometre at
    20 m; the grid is centimetres). The cell coordinate is shifted by one so that truncation is
    floor and out-of-range votes clip into a guard cell at each end of the row (cheaper than
    filtering); ``np.bincount`` sums the flat indices and the guards are cut off.
    Returns the accumulator, ``n_theta × n_rho``.
    """
    q = points.astype(np.float32) @ grid.trig32  # N×T: ρ = x cos θ + y sin θ
    q *= np.float32(1.0 / grid.rho_step)
    q += np.float32(1.0 - grid.rho_min / grid.rho_step)  # cell index + 1
    np.clip(q, 0.0, grid.n_rho + 1, out=q)
    flat = q.astype(np.int32)
    flat += grid.row_offsets
    counts = np.bincount(flat.ravel(), minlength=grid.n_theta * (grid.n_rho + 2))
    return counts.reshape(grid.n_theta, grid.n_rho + 2)[:, 1:-1]

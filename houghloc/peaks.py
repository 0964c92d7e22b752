"""Local maxima of the accumulator (docs/method.md §2): a vote threshold relative to the number of
points and non-maximum suppression in a window that wraps around θ."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig
from houghloc.jit import njit


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
class Peaks:
    """Peak cells, strongest first."""

    i_theta: NDArray[np.intp]
    i_rho: NDArray[np.intp]
    votes: NDArray[np.integer]

    def __len__(self) -> int:
        return len(self.votes)


def find_peaks(acc: NDArray[np.integer], n_points: int, config: HoughConfig,
               limit: int | None = None) -> Peaks:
    """Cells with ≥ max(peak_min_votes, peak_fraction·N) votes, maximal in their window.

    The window spans ±``nms_theta_cells`` rows, wrapping around θ (a line at θ ≈ 0 and one at
    θ ≈ 2π are neighbours), and ±``nms_rho_cells`` columns, cut at the grid's ends. Equal
    neighbours on a plateau both survive; the refinement merges them, since they are the same
    line. Strongest first; among equals, the first in the accumulator's row order.
    """
    threshold = max(config.peak_min_votes, int(np.ceil(config.peak_fraction * n_points)))
    i_theta, i_rho, votes = _peaks_kernel(acc, threshold, config.nms_theta_cells,
                                          config.nms_rho_cells, limit or config.max_peaks)
    return Peaks(i_theta, i_rho, votes)


@njit
def _peaks_kernel(acc: NDArray[np.integer], threshold: int, w: int, h: int, limit: int
                  ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.int64]]:
    n_theta, n_rho = acc.shape
    i_theta = np.empty(64, np.intp)
    i_rho = np.empty(64, np.intp)
    count = 0
    # Only columns [lo, hi] hold a cell at or above the threshold (a scan's votes reach as far
    # as its farthest point): the cells outside can neither be a peak nor suppress one, which
    # must be at least as high. One vectorised pass finds them.
    column_top = acc[0].copy()
    for i in range(1, n_theta):
        for j in range(n_rho):
            column_top[j] = max(column_top[j], acc[i, j])
    lo, hi = 0, n_rho - 1
    while lo <= hi and column_top[lo] < threshold:
        lo += 1
    while hi >= lo and column_top[hi] < threshold:
        hi -= 1
    for i in range(n_theta if lo <= hi else 0):
        if acc[i, lo:hi + 1].max() < threshold:  # a row without a candidate: one vectorised pass
            continue
        for j in range(lo, hi + 1):
            v = acc[i, j]
            if v < threshold:
                continue
            # the cells beside it first: they reject most cells on a peak's slopes
            if (j > 0 and acc[i, j - 1] > v) or (j + 1 < n_rho and acc[i, j + 1] > v):
                continue
            peak = True
            for di in range(-w, w + 1):
                ii = i + di  # wrapped around θ
                if ii < 0:
                    ii += n_theta
                elif ii >= n_theta:
                    ii -= n_theta
                for jj in range(max(j - h, 0), min(j + h + 1, n_rho)):
                    if acc[ii, jj] > v:
                        peak = False
                        break
                if not peak:
                    break
            if peak:
                if count == len(i_theta):  # grow the (rarely full) lists
                    i_theta = np.concatenate((i_theta, np.empty_like(i_theta)))
                    i_rho = np.concatenate((i_rho, np.empty_like(i_rho)))
                i_theta[count], i_rho[count] = i, j
                count += 1
    votes = np.empty(count, np.int64)
    for k in range(count):
        votes[k] = acc[i_theta[k], i_rho[k]]
    order = np.argsort(-votes, kind="mergesort")[:limit]  # stable: row order among equals
    return i_theta[order], i_rho[order], votes[order]

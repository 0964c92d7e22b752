"""Local maxima of the accumulator (DESIGN §3.2): a vote threshold relative to the number of points
and non-maximum suppression in a window that wraps around θ."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from houghloc.config import HoughConfig


@dataclass(frozen=True)
class Peaks:
    """Peak cells, strongest first."""

    i_theta: NDArray[np.intp]
    i_rho: NDArray[np.intp]
    votes: NDArray[np.integer]

    def __len__(self) -> int:
        return len(self.votes)


@lru_cache(maxsize=8)
def _kernel(w: int, h: int) -> NDArray[np.uint8]:
    return np.ones((2 * w + 1, 2 * h + 1), np.uint8)


def find_peaks(acc: NDArray[np.integer], n_points: int, config: HoughConfig,
               limit: int | None = None) -> Peaks:
    """Cells with ≥ max(peak_min_votes, peak_fraction·N) votes, maximal in their window.

    The window maximum is a grey dilation (OpenCV) of the accumulator padded by wrapping θ, so a
    line at θ ≈ 0 and one at θ ≈ 2π are neighbours. Equal neighbours on a plateau both survive;
    the refinement merges them, since they are the same line.
    """
    threshold = max(config.peak_min_votes, int(np.ceil(config.peak_fraction * n_points)))
    flat = acc.ravel()
    cand = np.flatnonzero(flat >= threshold)  # few cells: compare only these with the window
    if len(cand) == 0:
        e = np.empty(0, np.intp)
        return Peaks(e, e, np.empty(0, acc.dtype))
    w, h = config.nms_theta_cells, config.nms_rho_cells
    dtype = np.uint16 if n_points < 65535 else np.float32  # types OpenCV dilates
    # only the columns up to the last candidate (and a window beyond) can matter: near scans
    # leave the far columns empty
    i_theta, i_rho = np.divmod(cand, acc.shape[1])
    used = acc[:, : int(i_rho.max()) + 1 + h]
    padded = np.concatenate((used[-w:], used, used[:w]), dtype=dtype, casting="unsafe")
    window_max = cv2.dilate(padded, _kernel(w, h))[w:-w]
    v = flat[cand]
    peak = v >= window_max[i_theta, i_rho]
    v, i_theta, i_rho = v[peak], i_theta[peak], i_rho[peak]
    order = np.argsort(-v, kind="stable")[: limit or config.max_peaks]
    return Peaks(i_theta[order], i_rho[order], v[order])

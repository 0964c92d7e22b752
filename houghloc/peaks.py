"""Local maxima of the accumulator (DESIGN §3.2): a vote threshold relative to the number of points
and non-maximum suppression in a window that wraps around θ."""

from __future__ import annotations

from dataclasses import dataclass

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
    padded = np.concatenate((acc[-w:], acc, acc[:w])).astype(dtype)
    kernel = np.ones((2 * w + 1, 2 * h + 1), np.uint8)
    window_max = cv2.dilate(padded, kernel)[w:-w].ravel()
    cand = cand[flat[cand] >= window_max[cand]]
    v = flat[cand]
    order = np.argsort(-v, kind="stable")[: limit or config.max_peaks]
    it, ir = np.divmod(cand[order], acc.shape[1])
    return Peaks(it, ir, v[order])

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
    votes: NDArray[np.int32]

    def __len__(self) -> int:
        return len(self.votes)


def find_peaks(acc: NDArray[np.int32], n_points: int, config: HoughConfig,
               limit: int | None = None) -> Peaks:
    """Cells with ≥ max(peak_min_votes, peak_fraction·N) votes, maximal in their window.

    The window maximum is a grey dilation (OpenCV) of the accumulator padded by wrapping θ, so a
    line at θ ≈ 0 and one at θ ≈ 2π are neighbours. Equal neighbours on a plateau both survive;
    the refinement merges them, since they are the same line.
    """
    threshold = max(config.peak_min_votes, int(np.ceil(config.peak_fraction * n_points)))
    w, h = config.nms_theta_cells, config.nms_rho_cells
    padded = np.concatenate((acc[-w:], acc, acc[:w])).astype(np.float32)
    kernel = np.ones((2 * w + 1, 2 * h + 1), np.uint8)
    window_max = cv2.dilate(padded, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)[w:-w]
    it, ir = np.nonzero((acc >= threshold) & (acc >= window_max))
    v = acc[it, ir]
    order = np.argsort(-v, kind="stable")[: limit or config.max_peaks]
    return Peaks(it[order], ir[order], v[order])

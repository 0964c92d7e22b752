"""The guess polished on the scan's points: a measurement where the lines give no usable fix.

A scan's Hough fix is not used when too few lines match (no fix), when its lines fit two places
(ambiguous) or when it moves the scan off the walls (misfit). The scan's points still lie on the
map's walls near the guess: door frames, short pieces, corners and the walls whose lines were
left out. So the guess itself is polished on them (``houghloc.polish.polish_pose``: Gauss–Newton
of the points against the walls within ``polish_gate``, in all three directions, each wall's
points sharing its model error) and offered to the filter as a full measurement, when

* the points pin every direction: the polished covariance's largest σ is below
  ``max_observable_sigma`` (the displacement's own bound for an observed direction);
* the move is plausible: Δᵀ (P + C)⁻¹ Δ within the χ² gate of ``gate_probability`` on 3 dof, P
  the guess's covariance and C the polish's (the filter runs the same test on its innovation);
* the scan fits the walls at least as well there as at the guess (the share of its points on
  walls, the manager's measure of fit): a polish that slid the points off the walls is no fix.

The polish starts at the guess, or at a misfit fix that puts more of the scan on walls than the
guess does (its lines matched; it was refused for its fit against recent fixes, which a fast
turn through clutter lowers for every pose): from a guess 20 cm and several degrees off, too few
points lie within the gate to bring it back.

No number of its own: the thresholds are the Hough settings' and the manager's measure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from houghloc import HoughConfig
from houghloc.geometry import inverse_3x3, wrap_scalar
from houghloc.localize import polish_weights
from houghloc.map_lookup import wall_cells
from houghloc.matching import gate_threshold
from houghloc.polish import polish_pose
from houghloc.segment_map import SegmentMap

_ALL_DIRECTIONS = np.eye(3)


@dataclass(frozen=True, slots=True)
class PointsMeasurement:
    """The guess polished on the scan's points: a full pose measurement."""

    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    guess_fit: float
    """share of the scan's points on walls at the guess"""
    fit: float
    """the same share at the polished pose"""


@dataclass
class PointsFix:
    """Polishes the guess on the scan's points where the lines gave no usable fix (module
    docstring)."""

    map: SegmentMap
    fit: ScanFit

    def measure(self, guess: NDArray, guess_cov: NDArray, points: NDArray, hough: HoughConfig,
                guess_fit: float | None = None, start: NDArray | None = None
                ) -> PointsMeasurement | None:
        """The measurement the scan's ``points`` (robot frame) give near ``guess`` (covariance
        ``guess_cov``), or None where they do not give one (module docstring). ``guess_fit``:
        the share of the points on walls at the guess, when the caller knows it. ``start``:
        where the polish starts (default the guess); the gates are the guess's still."""
        if hough.polish_gate is None or len(points) == 0:
            return None
        cells = wall_cells(self.map, hough.reference_kinds, hough.polish_gate)
        found = polish_pose(points, polish_weights(points, hough), cells,
                            guess if start is None else start, _ALL_DIRECTIONS, hough)
        if found is None:
            return None
        pose, cov = found
        if not np.linalg.eigvalsh(cov).max() < hough.max_observable_sigma**2:
            return None
        step = np.array([pose[0] - guess[0], pose[1] - guess[1],
                         wrap_scalar(pose[2] - guess[2])])
        if not step @ inverse_3x3(guess_cov + cov) @ step <= gate_threshold(
                hough.gate_probability, 3):
            return None
        kinds = hough.reference_kinds
        if guess_fit is None:
            guess_fit = float(self.fit.fractions(guess[None], points, kinds)[0])
        fit = float(self.fit.fractions(pose[None], points, kinds)[0])
        if fit < guess_fit:
            return None
        pose[2] = wrap_scalar(pose[2])
        return PointsMeasurement(pose, cov, guess_fit, fit)

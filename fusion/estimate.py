"""What the localizer returns for each measurement: the pose at its time, its covariance, what
became of the measurement, and the probability that the pose is right (:class:`Estimate`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.corridor import CorridorMeasurement
from fusion.ekf import UpdateOutcome
from fusion.integrity import localized_probability
from fusion.points_fix import PointsMeasurement
from fusion.status import ScanStatus
from houghloc.localize import ScanCorrection


@dataclass(frozen=True, slots=True)
class Estimate:
    """The pose at a measurement's time after using it, and what happened to the measurement."""

    t: float
    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    status: ScanStatus
    correction: ScanCorrection | None = None
    outcome: UpdateOutcome | None = None
    along: CorridorMeasurement | None = None
    """the corridor fix placed along its corridor by the scan's points, when it was"""
    by_points: PointsMeasurement | None = None
    """the guess polished on the scan's points, offered where the lines' fix was refused"""
    mode: float = 1.0
    """the probability that the filter is around the right place at all (fusion.integrity)"""

    @property
    def localized_probability(self) -> float:
        """The probability that ``pose`` is within 0.3 m and 5° of the truth
        (:func:`fusion.integrity.localized_probability`)."""
        return localized_probability(self.cov, self.mode)

"""What the localizer returns for each measurement: the pose at its time, its covariance, what
became of the measurement, and the probability that the pose is right (:class:`Estimate`); and
what became of all of them so far (:class:`LocalizerStats`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from time import perf_counter
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.corridor import CorridorMeasurement
from fusion.ekf import UpdateOutcome
from fusion.integrity import localized_probability
from fusion.points_fix import PointsMeasurement
from fusion.pose_history import TrackerCounts
from fusion.status import ScanStatus, State
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


@dataclass
class LocalizerStats:
    """Counts for ``metrics.json``: what became of every measurement.

    ``statuses`` counts every status a scan ended with (:class:`Estimate`); the named counts
    read it."""

    scans: int = 0
    partial_rank: int = 0
    placed_along: int = 0
    points_fixes: int = 0
    """scans whose refused fix was replaced by the guess polished on their points (offered to
    the filter, whose counts say what it made of them)"""
    late: int = 0
    """measurements (fixes and polished guesses) offered to the filter for a time before its
    newest reading: applied at their own time, the odometry since re-propagated"""
    stray_timestamps: int = 0
    invalid_odometry: int = 0
    statuses: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=lambda: {"hough": 0.0, "update": 0.0})
    """wall time spent in each stage of the scans (metrics.json's ``seconds``)"""

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        """Adds the wall time of the ``with`` block to ``seconds[stage]``."""
        start = perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + perf_counter() - start

    def summary(self, counts: TrackerCounts) -> dict[str, Any]:
        """What became of the measurements, with the filter's ``counts`` of its updates and
        refusals (``metrics.json``, :meth:`fusion.localizer.Localizer.summary`)."""
        return {
            "updates": counts.updates,
            "rejections": counts.rejected,
            "delayed_measurements": counts.delayed,
            "dropped_measurements": counts.dropped + self.dropped,
            "odometry_jumps": counts.odometry_jumps,
            "odometry_backwards": counts.odometry_backwards,
            "invalid_inputs": counts.invalid,
            "invalid_odometry": self.invalid_odometry,
            "stray_timestamps": self.stray_timestamps,
            "fixes": {"accepted": self.accepted, "rejected": self.rejected,
                      "ambiguous": self.ambiguous, "no_fix": self.no_fix,
                      "partial_rank": self.partial_rank,
                      "placed_along_corridor": self.placed_along,
                      "polished_guesses": self.points_fixes, "late": self.late},
            "statuses": dict(self.statuses),
            "tracked_fraction": round(self.tracked_fraction, 6),
        }

    @property
    def tracked_fraction(self) -> float:
        """The share of scans that ended while tracking (a fix used or not, the pose trusted);
        the rest ended collecting views, relocalizing or lost."""
        untracked = {s.value for s in State if s is not State.TRACKING} | {ScanStatus.RELOCALIZED}
        total = sum(self.statuses.values())
        lost = sum(v for k, v in self.statuses.items() if k in untracked)
        return 1.0 - lost / total if total else 0.0

    @property
    def accepted(self) -> int:
        return self.statuses.get(ScanStatus.ACCEPTED, 0)

    @property
    def rejected(self) -> int:
        return self.statuses.get(ScanStatus.REJECTED, 0)

    @property
    def ambiguous(self) -> int:
        return self.statuses.get(ScanStatus.AMBIGUOUS, 0)

    @property
    def no_fix(self) -> int:
        return self.statuses.get(ScanStatus.NO_FIX, 0)

    @property
    def dropped(self) -> int:
        return self.statuses.get(ScanStatus.DROPPED, 0)

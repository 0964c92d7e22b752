"""The decision stage: does a tracking scan's fix become a measurement, and which one?

    TrackingScan (the scan's points, its sensor, the guess at its time) + the lines' fix
        ─▶ FixDecider.decide ─▶ FixDecision (the verdict, and the measurement offered or none)

1. **The verdict** (:meth:`FixDecider.judge`): a fix the matcher vouches for (not ambiguous, of
   rank > 0, at least the sensor's ``min_fix_lines`` lines matched) may be used, and one it
   cannot vouch for may be when the scan itself does (:meth:`ScanFit.fix_gains`: the odometry
   slipped in a turn); either only if it keeps the scan on the walls about as well as recent
   fixes did (:meth:`ScanFit.fix_fits`).
2. **The measurement**: a used fix, placed along its corridor by the scan's points where they
   can (:mod:`fusion.corridor`); a refused one (no fix, ambiguous, misfit) gives way to the
   guess polished on the scan's points where they pin it (:mod:`fusion.points_fix`); else
   nothing is offered.

What follows is not decided here: the filter's gate may still refuse the measurement
(:meth:`fusion.tracker.PoseTracker.apply`), and the manager then decides whether the pose is
searched for nearby (:meth:`~fusion.ambiguity.manager.AmbiguityManager.re_search`) and whether
tracking goes on (:meth:`~fusion.ambiguity.manager.AmbiguityManager.tracking_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.corridor import CorridorMeasurement, CorridorPlacement
from fusion.points_fix import PointsFix, PointsMeasurement
from fusion.settings.hypotheses import HypothesisConfig
from fusion.status import ScanStatus
from houghloc import HoughConfig, ScanCorrection, SegmentMap


@dataclass(frozen=True, slots=True)
class TrackingScan:
    """One scan while tracking, as every stage after the prediction sees it: its time, its
    points in the robot frame, its sensor, and the filter's guess at its time."""

    t: float
    points: NDArray[np.float64]
    sensor: str
    hough: HoughConfig
    """the sensor's Hough settings"""
    min_fix_lines: int
    """the sensor's fewest matched lines for a fix the matcher vouches for"""
    guess: NDArray[np.float64]
    guess_cov: NDArray[np.float64]
    scans_broke: bool = False
    """this scan fitted its predecessor nowhere near the wheels' increment (scan odometry)"""

    @property
    def kinds(self) -> tuple[str, ...]:
        """the map's segment kinds this sensor sees"""
        return self.hough.reference_kinds


@dataclass(frozen=True, slots=True)
class Verdict:
    """The word on a tracking fix, before the filter sees it: ``use`` it, or not and why
    (``status``). ``guess_fit``/``fix_fit``: the fractions of the scan's points on walls at the
    guess and at the fix (``fix_fit`` None for a fix of rank 0: it has no pose of its own)."""

    use: bool
    status: ScanStatus | None = None
    guess_fit: float | None = None
    fix_fit: float | None = None


@dataclass(frozen=True, slots=True)
class Measurement:
    """A pose measurement for the filter; ``basis``: the observed directions of a partial one
    (None: the whole pose, H = I)."""

    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    basis: NDArray[np.float64] | None = None


@dataclass(frozen=True, slots=True)
class FixDecision:
    """What a tracking scan offers the filter: the ``verdict`` on the lines' fix and the
    ``measurement`` (None: nothing), which is the fix itself, the fix placed ``along`` its
    corridor, or the guess polished on the points (``by_points``) where the fix was refused."""

    verdict: Verdict
    measurement: Measurement | None = None
    along: CorridorMeasurement | None = None
    by_points: PointsMeasurement | None = None
    partial: bool = False
    """a used fix of rank < 3 (offered as it is, or completed along its corridor)"""


class FixDecider:
    """Decides what each tracking scan's fix gives the filter (module docstring)."""

    def __init__(self, map: SegmentMap, fit: ScanFit, likelihood: HypothesisConfig) -> None:
        self.fit = fit
        self.corridor = CorridorPlacement(fit, likelihood)
        self.points_fix = PointsFix(map, fit)

    def decide(self, scan: TrackingScan, fix: ScanCorrection) -> FixDecision:
        """The verdict on ``fix``, then the measurement it leads to."""
        verdict = self.judge(scan, fix)
        if not verdict.use:
            return self._by_points(scan, fix, verdict)
        along = self.corridor.complete(fix, scan.guess_cov, scan.points, scan.hough)
        if along is not None:
            measurement = Measurement(along.pose, along.cov)
        else:  # a full fix measures the whole pose (H = I), whatever its basis's column order
            measurement = Measurement(fix.pose, fix.cov, fix.observable if fix.rank < 3 else None)
        return FixDecision(verdict, measurement, along=along, partial=fix.rank < 3)

    def judge(self, scan: TrackingScan, fix: ScanCorrection) -> Verdict:
        """Should the filter be offered this tracking fix (step 1 of the module docstring)? A
        few more points on walls than a guess that has none does not vouch for a fix that
        leaves the scan off them: the robot is elsewhere, or the lines were matched to the
        wrong walls, however small the innovation."""
        fit, points, kinds = self.fit, scan.points, scan.kinds
        # the fractions of the scan on walls at the guess and at the fix (when there is one),
        # in one pass, for every check that wants them
        wanted = [scan.guess, fix.pose] if fix.rank > 0 else [scan.guess]
        fits = fit.fractions(np.array(wanted), points, kinds).tolist()
        guess_fit = fits[0]
        fix_fit = fits[1] if fix.rank > 0 else None
        matched = 0 if fix.matches is None else len(fix.matches)
        vouched = not fix.ambiguous and fix.rank > 0 and matched >= scan.min_fix_lines
        by_fit = (not vouched and fix.rank > 0
                  and fit.fix_gains(fix.pose, points, kinds, guess_fit, fix_fit))
        if not (vouched or by_fit):
            status = ScanStatus.AMBIGUOUS if fix.ambiguous else ScanStatus.NO_FIX
            return Verdict(False, status, guess_fit, fix_fit)
        if not fit.fix_fits(fix.pose, points, kinds, guess_fit, fix_fit):
            return Verdict(False, ScanStatus.MISFIT, guess_fit, fix_fit)
        return Verdict(True, None, guess_fit, fix_fit)

    def _by_points(self, scan: TrackingScan, fix: ScanCorrection, verdict: Verdict
                   ) -> FixDecision:
        """Where the lines' fix was refused (no fix, ambiguous, misfit), the guess polished on
        the scan's points (:mod:`fusion.points_fix`) where they pin it."""
        # a misfit's lines matched; it was refused for where it puts the scan against recent
        # fits. Where it still puts more of the scan on walls than the guess does, the polish
        # starts there (a guess far off in a fast turn pairs too few points to come back).
        # A fix refused for its lines (too few, or fitting two places) is no place to start.
        better = (verdict.status is ScanStatus.MISFIT and verdict.fix_fit is not None
                  and verdict.guess_fit is not None and verdict.fix_fit > verdict.guess_fit)
        found = self.points_fix.measure(fix.guess, scan.guess_cov, scan.points, scan.hough,
                                        verdict.guess_fit, fix.pose if better else None)
        if found is None:
            return FixDecision(verdict)
        # The points refine the pose near the guess; they cannot vouch that the guess is the
        # right place: the scan keeps the verdict's status, and the manager still counts it as
        # a scan without a usable fix (a wrong pose polished onto nearby walls must still be
        # given up).
        return FixDecision(verdict, Measurement(found.pose, found.cov), by_points=found)

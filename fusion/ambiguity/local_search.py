"""The local re-search: when tracking fails and the prediction no longer fits the scan, the
scan's own lines are matched to the map within a neighbourhood of the dead-reckoned pose before
tracking is given up (a wheel slip, a motion the odometry did not report).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.hypotheses import scan_log_likelihood
from fusion.integrity import LOCALIZED_HEADING_DEG, LOCALIZED_POSITION
from fusion.settings.ambiguity import AmbiguityConfig
from houghloc import (
    GlobalResult,
    HoughConfig,
    ScanCorrection,
    SegmentMap,
    global_match,
    localize_scan,
)
from houghloc.displacement import UNOBSERVED_VARIANCE
from houghloc.geometry import wrap_angle, wrap_scalar
from houghloc.matching import gate_threshold
from houghloc.neighbourhood import Neighbourhood

MATCHED_STARTS = 3
"""the local match's best poses that tracking is run from"""
SWEPT_STARTS = 6
"""the swept poses (below) that put most of the scan on walls, run from as well"""
START_SIGMA_XY = 0.1
"""m: the covariance each start is tracked from, in position ..."""
START_SIGMA_DEG = 2.0
"""°: ... and in heading"""
SIGMA_ALONG = 0.3
"""m: the σ of a candidate's position along a corridor where it keeps the guess's (the fix did
not observe it)"""
SWEEP_STEP_XY = 0.25
"""m: the sweep's starts move the guess along its heading in steps of this"""
SWEEP_STEP_DEG = 2.0
"""°: and turn it in steps of this"""
SAME_POSE_XY = LOCALIZED_POSITION
"""m: candidates closer than this (and than SAME_POSE_DEG) are one pose, not rivals: the bounds
within which the integrity output calls a pose right"""
SAME_POSE_DEG = LOCALIZED_HEADING_DEG


@dataclass(frozen=True, slots=True)
class Found:
    """A pose the local re-search found (with its covariance and fit), or only the match."""

    result: GlobalResult | None = None
    pose: NDArray[np.float64] | None = None
    cov: NDArray[np.float64] | None = None
    fit: float = 0.0
    along_kept: bool = False
    """the pose's position along a corridor is the guess's: the scan did not observe it"""


@dataclass
class LocalSearch:
    """Matches one scan's lines to the map near the guess (``local_search_xy``,
    ``local_search_theta_deg``) and judges the pose found by the scan's fit (:class:`ScanFit`)."""

    map: SegmentMap
    config: AmbiguityConfig
    fit: ScanFit
    counts: Counter

    def find(self, guess: NDArray, points: NDArray, fix: ScanCorrection,
             kinds: tuple[str, ...], guess_fit: float, hough: HoughConfig,
             moved_since_fix: float | None, guess_cov: NDArray | None = None) -> Found:
        """Match the lines of the tracking ``fix`` (from the same ``points``) to the map near
        ``guess`` (within ``local_search_xy``, and within ``local_search_theta_deg`` of its
        heading or, when ``guess_cov`` says the heading is less certain, as far as the matcher's
        ``gate_probability`` reaches: :func:`_heading_reach`). The pose found is returned
        when it clearly fits the scan better than the guess and about as well as tracking did,
        no other pose in the neighbourhood scores as well (a corridor leaves the position along
        it open), it is within reach of the odometry's motion since the last accepted fix
        (``moved_since_fix``, m; None: no bound) (``local_reach_per_metre``), and the scan
        makes it clearly likelier than the guess (:meth:`_likelier`: not by seeing through
        walls)."""
        lines, radius = fix.lines, self.config.local_search_xy
        if (lines is None or len(lines) < 2 or lines.members.shape[0] != len(points)
                or fix.grid is None or fix.accumulator is None or radius is None):
            return Found()
        turn = _heading_reach(math.radians(self.config.local_search_theta_deg), guess_cov,
                              hough.gate_probability)
        near = Neighbourhood(np.asarray(guess, float), radius, turn)
        # only the best are polished below: refining more would be wasted
        local = self.config.global_match.model_copy(update={"max_refined": MATCHED_STARTS})
        result = global_match(lines, points, self.map, local, kinds, near)
        self.counts["local_searches"] += 1
        typical = self.fit.typical_fix()
        if typical is None:
            return Found(result)
        # Candidates: the matcher's poses (clustered by 5°, so each is polished by tracking from
        # it) and the guess turned and moved along its heading step by step (a slip in a turn,
        # an unreported reversal), each corrected by tracking from there.
        sweep = _sweep(np.asarray(guess, float), radius, turn)
        raw = self.fit.fractions(sweep, points, kinds)  # polish the promising ones only
        starts = [np.asarray(h.pose, float) for h in result.hypotheses[:MATCHED_STARTS]]
        starts += list(sweep[np.argsort(-raw, kind="stable")[:SWEPT_STARTS]])
        prior = np.diag([START_SIGMA_XY**2, START_SIGMA_XY**2,
                         math.radians(START_SIGMA_DEG) ** 2])
        observed = (fix.grid, fix.accumulator, lines)  # one scan, matched from every start
        found = []
        for start in starts:
            polished = _polished(localize_scan(points, self.map, start, hough, pose_cov=prior,
                                               observed=observed), np.asarray(guess, float))
            if polished is not None:
                found.append((self.fit.fraction(polished[0], points, kinds), *polished))
        if not found:
            return Found(result)
        found.sort(key=lambda f: -f[0])
        fit, pose, cov, along_kept = found[0]
        rivals = [f for f in found[1:] if f[0] > fit - self.config.local_rival_margin
                  and not _same_pose(f[1], pose)]
        if (fit < guess_fit + self.config.local_fit_gain
                or fit < self.config.local_min_fit * typical or rivals
                or not self._within_reach(pose, guess, moved_since_fix)
                or not self._likelier(pose, guess, points, kinds)):
            return Found(result)
        self.counts["local_fixes"] += 1
        return Found(result, np.asarray(pose, float), np.array(cov, dtype=float), fit,
                     along_kept)

    def _likelier(self, pose: NDArray, guess: NDArray, points: NDArray,
                  kinds: tuple[str, ...]) -> bool:
        """Does the scan make ``pose`` likelier than the ``guess`` by the odds at which a followed
        hypothesis is taken (``hypotheses.accept_probability``, 19 to 1), under the likelihood
        that weighs them (:func:`scan_log_likelihood`: the guess is the filter's belief, which
        may be where the map has nothing)? Two poses, one scan, no prior between them. A pose
        that puts more of the scan on walls by seeing through others is not, nor one that
        only explains what the map lacks around the guess (with ``hypotheses`` None there is
        no likelihood: every pose is)."""
        model = self.config.hypotheses
        if model is None:
            return True
        shares = self.fit.shares(np.array([pose, guess], float), points, kinds)
        found = scan_log_likelihood(shares[:1], model)[0]
        believed = scan_log_likelihood(shares[1:], model, belief=True)[0]
        odds = model.accept_probability / (1.0 - model.accept_probability)
        if found - believed >= math.log(odds):
            return True
        self.counts["local_less_likely"] += 1
        return False

    def _within_reach(self, pose: NDArray, guess: NDArray, moved: float | None) -> bool:
        """Is ``pose`` within ``local_reach_base`` + ``local_reach_per_metre`` × ``moved`` (the
        odometry's displacement since the last accepted fix) of the ``guess``? Without it
        (None) there is no motion to bound it by."""
        per_metre = self.config.local_reach_per_metre
        if per_metre is None or moved is None:
            return True
        shift = math.hypot(*(np.asarray(pose, float)[:2] - np.asarray(guess, float)[:2]))
        if shift <= self.config.local_reach_base + per_metre * moved:
            return True
        self.counts["local_out_of_reach"] += 1
        return False


def _heading_reach(least: float, guess_cov: NDArray | None, probability: float) -> float:
    """How far (rad) from the guess's heading the re-search looks: ``least``, or the
    heading's own uncertainty where it is wider, the half-width that holds the true heading with
    ``probability`` under the guess's covariance (√χ²₁(p) σθ; 3.9 σθ at 0.9999), at most π.
    A fast turn the odometry missed leaves the heading tens of degrees out, and the filter's
    covariance, grown by the motion model, says so."""
    if guess_cov is None:
        return least
    sigma = math.sqrt(max(float(guess_cov[2, 2]), 0.0))
    return min(max(least, math.sqrt(gate_threshold(probability, 1)) * sigma), math.pi)


def _polished(fix: ScanCorrection, guess: NDArray, sigma_along: float = SIGMA_ALONG
              ) -> tuple[NDArray, NDArray, bool] | None:
    """A local re-search candidate from a fix tracked from it: a full fix as it is; one that
    observes the heading and the position across the walls in view only (a corridor, or one
    wall of a cluttered room) keeps the guess's position along them, ``sigma_along`` uncertain
    (the fix cannot say where along the corridor the start was, so every start along it gives
    the same candidate and none of them is a rival). None when ambiguous or without heading;
    the flag says whether the position along was kept."""
    if fix.ambiguous or fix.rank < 2:
        return None
    if fix.rank == 3:
        return fix.pose, fix.cov, False
    v = fix.unobservable  # 3×1, in x, y
    along = v @ v.T
    pose = fix.pose - along @ (fix.pose - guess)
    return pose, fix.cov + (sigma_along**2 - UNOBSERVED_VARIANCE) * along, True


def _sweep(guess: NDArray, radius_xy: float, radius_theta: float,
           step_xy: float = SWEEP_STEP_XY, step_theta: float = math.radians(SWEEP_STEP_DEG)
           ) -> NDArray[np.float64]:
    """The guess turned by every ``step_theta`` within ``radius_theta``, and moved along its
    heading by every ``step_xy`` within ``radius_xy`` (forwards and backwards)."""
    turns = np.arange(step_theta, radius_theta + 1e-9, step_theta)
    turns = np.concatenate(([0.0], turns, -turns))
    moves = np.arange(step_xy, radius_xy + 1e-9, step_xy)
    moves = np.concatenate((moves, -moves))
    turned = np.tile(guess, (len(turns), 1))
    turned[:, 2] = wrap_angle(turned[:, 2] + turns)
    moved = np.tile(guess, (len(moves), 1))
    moved[:, :2] += moves[:, None] * np.array([math.cos(guess[2]), math.sin(guess[2])])
    return np.concatenate((turned, moved))


def _same_pose(a: NDArray, b: NDArray, xy: float = SAME_POSE_XY,
               theta: float = math.radians(SAME_POSE_DEG)) -> bool:
    return bool(math.hypot(a[0] - b[0], a[1] - b[1]) <= xy
                and abs(wrap_scalar(a[2] - b[2])) <= theta)

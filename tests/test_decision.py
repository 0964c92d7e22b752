"""The decision stage (fusion/decision.py): what a tracking scan's fix offers the filter.

Ground truth comes from exact scans cast in known worlds: the office map, and a room with boxes
whose points pin every direction of the pose.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from fusion.ambiguity.fit import ScanFit
from fusion.decision import FixDecider, TrackingScan
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.settings.hypotheses import HypothesisConfig
from fusion.status import ScanStatus
from houghloc import HoughConfig, SegmentMap, localize_scan
from tests.test_scan_odometry import ROOM, scan_points

HOUGH = HoughConfig()
GUESS_COV = np.diag([0.2**2, 0.2**2, math.radians(2.0) ** 2])


def decider(map: SegmentMap) -> tuple[FixDecider, Counter]:
    counts: Counter = Counter()
    return FixDecider(map, ScanFit(map, AmbiguityConfig(), counts), HypothesisConfig()), counts


def tracking_scan(points: np.ndarray, guess: np.ndarray, min_fix_lines: int = 2) -> TrackingScan:
    return TrackingScan(1.0, points, "laser", HOUGH, min_fix_lines, guess, GUESS_COV)


@pytest.mark.parametrize("clutter, used", [(0, True), (300, False)])
def test_a_fix_the_scan_vouches_for_must_still_fit_like_recent_ones(office, clutter, used):
    """One wall in view (the y = 7 wall, 1 m to the left): the matcher cannot vouch for a
    one-line fix, and the guess, 0.3 m off that wall, has no point on it. The fix puts the
    wall's points on it: with nothing else in view that is the whole scan, and it is used; among
    300 points that lie on no wall it is a sixth of the scan, against 0.9 for recent fixes, and
    it is a misfit like any other fix that leaves the scan off the walls."""
    rng = np.random.default_rng(4)
    truth = np.array([5.0, 6.0, 0.0])
    wall = np.column_stack((np.linspace(-3.0, 0.8, 60), np.full(60, 1.0)))  # short of a door
    room = rng.uniform(-1.0, 1.0, (clutter, 2)) * [3.0, 0.35] + [0.0, 0.05]  # off its walls
    points = np.concatenate((wall, room))
    stage, counts = decider(office)
    stage.fit.used.extend([0.9] * 5)  # recent fixes put nine tenths of their scans on walls
    guess = truth + [0.0, -0.3, 0.0]
    fix = localize_scan(points, office, guess, HOUGH, pose_cov=GUESS_COV)
    assert fix.rank == 2 and len(fix.matches) == 1 and abs(fix.pose[1] - truth[1]) < 0.05
    verdict = stage.judge(tracking_scan(points, guess), fix)
    assert verdict.guess_fit == 0.0 and verdict.fix_fit is not None
    assert verdict.fix_fit >= 0.03 and counts["fixes_by_fit"] == 1
    assert verdict.use is used
    assert verdict.status is (None if used else ScanStatus.MISFIT)


def test_a_full_fix_the_matcher_vouches_for_is_offered_as_it_is():
    """A guess 10 cm and 1.5° off in a room whose walls and boxes pin the pose: the lines' fix
    lands within 2 cm and 0.5° of the truth, and the decision offers exactly that fix as a
    measurement of the whole pose (no basis), with nothing placed along a corridor or polished."""
    room = SegmentMap(ROOM[:, :2], ROOM[:, 2:], name="room")
    truth = np.array([4.0, 2.5, 0.3])
    guess = truth + np.array([0.08, -0.06, math.radians(1.5)])
    points = scan_points(ROOM, truth)
    fix = localize_scan(points, room, guess, HOUGH, pose_cov=GUESS_COV)
    assert fix.rank == 3
    decision = decider(room)[0].decide(tracking_scan(points, guess), fix)
    assert decision.verdict.use and decision.verdict.status is None
    m = decision.measurement
    assert m is not None and m.basis is None and not decision.partial
    assert np.array_equal(m.pose, fix.pose) and np.array_equal(m.cov, fix.cov)
    assert decision.along is None and decision.by_points is None
    error = m.pose - truth
    assert math.hypot(error[0], error[1]) < 0.02 and abs(math.degrees(error[2])) < 0.5


def test_a_refused_fix_gives_way_to_the_guess_polished_on_the_points():
    """The same scan, but the sensor asks for more lines than the room has: the matcher cannot
    vouch for the fix, the guess already fits the scan as well as the fix (no gain by fit), so
    the fix is refused as no fix. The points pin the pose: the decision offers the guess polished
    onto them, within 5 mm and 0.1° of the truth, and keeps the refusal's status."""
    room = SegmentMap(ROOM[:, :2], ROOM[:, 2:], name="room")
    truth = np.array([4.0, 2.5, 0.3])
    guess = truth + np.array([0.03, -0.02, math.radians(0.5)])
    points = scan_points(ROOM, truth)
    fix = localize_scan(points, room, guess, HOUGH, pose_cov=GUESS_COV)
    decision = decider(room)[0].decide(tracking_scan(points, guess, min_fix_lines=99), fix)
    assert not decision.verdict.use and decision.verdict.status is ScanStatus.NO_FIX
    found, m = decision.by_points, decision.measurement
    assert found is not None and m is not None and m.basis is None and decision.along is None
    assert np.array_equal(m.pose, found.pose)
    error = m.pose - truth
    assert math.hypot(error[0], error[1]) < 0.005 and abs(math.degrees(error[2])) < 0.1


def test_a_refused_fix_without_points_offers_nothing():
    """No points at all: no fix to use and nothing to polish, so nothing is offered."""
    room = SegmentMap(ROOM[:, :2], ROOM[:, 2:], name="room")
    guess = np.array([4.0, 2.5, 0.3])
    points = np.empty((0, 2))
    fix = localize_scan(points, room, guess, HOUGH, pose_cov=GUESS_COV)
    decision = decider(room)[0].decide(tracking_scan(points, guess), fix)
    assert not decision.verdict.use and decision.measurement is None
    assert decision.by_points is None and decision.along is None

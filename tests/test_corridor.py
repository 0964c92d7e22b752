"""A corridor fix placed along its corridor by the scan's points (fusion/corridor.py).

Ground truth comes from scans cast in known corridors: one whose doorways place the robot along
it, and one with nothing along it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.ambiguity.fit import ScanFit
from fusion.corridor import CorridorPlacement
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.settings.hypotheses import HypothesisConfig
from houghloc import HoughConfig, SegmentMap, localize_scan
from tests.test_scan_odometry import CORRIDOR, scan_points

# A corridor 2 m wide between rooms: its left wall opens on two doorways, 1 m and 0.8 m wide,
# into a room whose far wall runs parallel to the corridor; two pillars 25 cm square stand
# against its right wall. Every line long enough to be a Hough line is parallel: a Hough fix
# measures the heading and the position across, never along.
DOORWAYS = np.array([
    [-15, -1, 15, -1],
    [-15, 1, 1, 1], [2, 1, 5, 1], [5.8, 1, 15, 1],
    [-15, 4, 15, 4],
    *(side for x in (0.5, 4.0) for side in (
        [x, -1, x, -0.75], [x, -0.75, x + 0.25, -0.75], [x + 0.25, -0.75, x + 0.25, -1])),
], dtype=float)
HOUGH = HoughConfig()
TRUTH = np.array([2.5, 0.0, 0.2])


def segment_map(walls: np.ndarray) -> SegmentMap:
    return SegmentMap(walls[:, :2], walls[:, 2:], name="corridor")


def placement(m: SegmentMap) -> CorridorPlacement:
    return CorridorPlacement(ScanFit(m, AmbiguityConfig()), HypothesisConfig())


def corridor_fix(m: SegmentMap, walls: np.ndarray, along_error: float, cov: np.ndarray):
    """The Hough fix of the scan at TRUTH from a guess ``along_error`` m off along x."""
    points = scan_points(walls, TRUTH)
    guess = TRUTH + np.array([along_error, 0.05, math.radians(2.0)])
    fix = localize_scan(points, m, guess, HOUGH, pose_cov=cov)
    assert fix.rank == 2 and not fix.ambiguous, fix.reason
    return fix, points


@pytest.mark.parametrize(("sigma", "most"), [(0.1, 0.9), (0.3, 0.6), (0.6, 0.8)])
def test_doorways_and_pillars_place_a_corridor_fix_along_the_corridor(sigma: float, most: float
                                                                       ) -> None:
    """Guesses off along the corridor by up to 1.5 σ of their prior: the Hough fix keeps each
    guess's error. Where the scan places the fix, the measurement is within 2 of its σ of the
    truth; fused with the guess (the filter's update along the corridor), it leaves the
    guesses at most ``most`` of their RMS error (within the 12 cm that a point counts as on a
    wall, 10 cm priors gain little). Across the corridor and in heading it is the Hough fix,
    with its covariance."""
    m = segment_map(DOORWAYS)
    cov = np.diag([sigma**2, 0.05**2, math.radians(3.0) ** 2])
    errors = np.linspace(-1.5, 1.5, 7) * sigma
    fused = []
    for error in errors:
        fix, points = corridor_fix(m, DOORWAYS, error, cov)
        assert abs(fix.pose[0] - TRUTH[0]) > abs(error) - 0.01
        placed = placement(m).complete(fix, cov, points, HOUGH)
        if placed is None:  # the doorways' pattern repeats within the prior: not placed
            fused.append(fix.pose[0] - TRUTH[0])
            continue
        assert abs(placed.pose[0] - TRUTH[0]) < 2 * placed.sigma
        assert np.allclose(placed.pose[1:], fix.pose[1:])
        v = fix.unobservable[:, 0]
        assert np.isclose(v @ placed.cov @ v, placed.sigma**2)
        assert np.allclose(placed.cov @ fix.observable, fix.cov @ fix.observable)
        info_guess, info_placed = 1 / sigma**2, 1 / placed.sigma**2
        fused.append((info_guess * (fix.pose[0] - TRUTH[0]) + info_placed * (
            placed.pose[0] - TRUTH[0])) / (info_guess + info_placed))
    assert np.sqrt(np.mean(np.square(fused))) < most * np.sqrt(np.mean(errors**2))


def test_a_corridor_with_nothing_along_it_leaves_the_fix_a_corridor_fix() -> None:
    m = segment_map(CORRIDOR)
    cov = np.diag([0.3**2, 0.05**2, math.radians(3.0) ** 2])
    fix, points = corridor_fix(m, CORRIDOR, 0.2, cov)
    assert placement(m).complete(fix, cov, points, HOUGH) is None


def test_a_guess_known_better_than_the_doorways_place_it_is_left_alone() -> None:
    """A guess known to 2 mm along the corridor: the scan's points, on walls or not within
    12 cm, cannot add to it."""
    m = segment_map(DOORWAYS)
    cov = np.diag([0.002**2, 0.05**2, math.radians(3.0) ** 2])
    fix, points = corridor_fix(m, DOORWAYS, 0.0, cov)
    assert placement(m).complete(fix, cov, points, HOUGH) is None


def test_a_full_fix_is_not_touched() -> None:
    room = np.vstack((DOORWAYS, [[8, -1, 8, 1]]))  # the corridor's end: a full fix
    m = segment_map(room)
    cov = np.diag([0.3**2, 0.05**2, math.radians(3.0) ** 2])
    points = scan_points(room, TRUTH)
    fix = localize_scan(points, m, TRUTH + np.array([0.1, 0.05, 0.02]), HOUGH, pose_cov=cov)
    assert fix.rank == 3
    assert placement(m).complete(fix, cov, points, HOUGH) is None

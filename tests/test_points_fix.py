"""The guess polished on the scan's points where the lines' fix was refused (fusion/points_fix.py).

Ground truth comes from exact scans cast in known worlds: a room with boxes, which pins every
direction, and a corridor with nothing along it, which does not.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from fusion.ambiguity.fit import ScanFit
from fusion.config import LocalizerConfig
from fusion.localizer import Localizer
from fusion.points_fix import PointsFix
from fusion.settings.ambiguity import AmbiguityConfig
from houghloc import HoughConfig, SegmentMap
from tests.test_scan_odometry import CORRIDOR, ROOM, scan_points

HOUGH = HoughConfig()
TRUTH = np.array([4.0, 2.5, 0.3])
GUESS_COV = np.diag([0.15**2, 0.15**2, math.radians(5.0) ** 2])


def points_fix(walls: np.ndarray) -> PointsFix:
    m = SegmentMap(walls[:, :2], walls[:, 2:], name="test")
    return PointsFix(m, ScanFit(m, AmbiguityConfig()))


@pytest.mark.parametrize("offset", [(0.06, -0.04, 1.5), (-0.08, 0.05, -2.0), (0.0, 0.09, 0.5)])
def test_a_guess_near_the_truth_is_polished_onto_it(offset: tuple[float, float, float]) -> None:
    """From guesses 5–10 cm and up to 2° off, the scan's points bring the pose to the truth
    within 5 mm and 0.1°, the truth inside the measurement's own χ² gate, and every point of
    the scan on a wall there."""
    guess = TRUTH + np.array([offset[0], offset[1], math.radians(offset[2])])
    points = scan_points(ROOM, TRUTH)
    found = points_fix(ROOM).measure(guess, GUESS_COV, points, HOUGH)
    assert found is not None
    error = found.pose - TRUTH
    assert np.hypot(error[0], error[1]) < 0.005
    assert abs(math.degrees(error[2])) < 0.1
    assert error @ np.linalg.solve(found.cov, error) < chi2.ppf(HOUGH.gate_probability, 3)
    assert found.fit == 1.0 >= found.guess_fit


def test_a_corridor_with_nothing_along_it_gives_no_measurement() -> None:
    """Parallel walls pin the heading and the position across, never along: no full
    measurement (the lines' corridor fix is the tool there)."""
    pose = np.array([0.0, 0.0, 0.2])
    points = scan_points(CORRIDOR, pose)
    guess = pose + np.array([0.05, 0.03, math.radians(1.0)])
    assert points_fix(CORRIDOR).measure(guess, GUESS_COV, points, HOUGH) is None


def test_a_move_the_guess_cannot_have_made_is_refused() -> None:
    """A guess known to a millimetre, 8 cm off: the points would move it far outside its own
    uncertainty, and the measurement is refused rather than offered to the filter."""
    guess = TRUTH + np.array([0.08, 0.0, 0.0])
    tight = np.diag([0.001**2, 0.001**2, math.radians(0.05) ** 2])
    points = scan_points(ROOM, TRUTH)
    assert points_fix(ROOM).measure(guess, tight, points, HOUGH) is None


def test_points_off_every_wall_give_no_measurement() -> None:
    """A scan of what the map does not hold (points in the room's free space): nothing to
    pair, nothing measured."""
    rng = np.random.default_rng(3)
    points = rng.uniform([0.5, -0.8], [2.0, 0.8], size=(150, 2))
    assert points_fix(ROOM).measure(TRUTH, GUESS_COV, points, HOUGH) is None


def test_without_a_polish_gate_nothing_is_measured() -> None:
    points = scan_points(ROOM, TRUTH)
    off = HOUGH.model_copy(update={"polish_gate": None})
    assert points_fix(ROOM).measure(TRUTH, GUESS_COV, points, off) is None


def test_a_polish_started_elsewhere_is_still_judged_against_the_guess() -> None:
    """Started near the truth (a misfit fix that fits better than the guess), the polish lands
    on the truth; the move from the guess, 32 cm and 6°, is offered only when the guess's own
    uncertainty allows it."""
    guess = TRUTH + np.array([0.25, -0.2, math.radians(6.0)])
    start = TRUTH + np.array([0.03, 0.02, math.radians(0.5)])
    points = scan_points(ROOM, TRUTH)
    wide = np.diag([0.3**2, 0.3**2, math.radians(10.0) ** 2])
    found = points_fix(ROOM).measure(guess, wide, points, HOUGH, start=start)
    assert found is not None
    assert np.hypot(*(found.pose[:2] - TRUTH[:2])) < 0.005
    assert found.fit == 1.0 > found.guess_fit
    tight = np.diag([0.02**2, 0.02**2, math.radians(1.0) ** 2])
    assert points_fix(ROOM).measure(guess, tight, points, HOUGH, start=start) is None


@pytest.mark.parametrize("scan_time", [0.15, 0.2])
def test_a_polished_guess_for_an_earlier_time_counts_as_late(scan_time: float) -> None:
    """A scan whose lines' fix is refused (too few lines for ``min_fix_lines``) is polished on
    its points instead; taken before the filter's newest odometry reading, that measurement is
    late like a late fix (metrics.json's ``late``), and one at the newest reading is not."""
    config = LocalizerConfig()
    laser = config.sensors["laser"].model_copy(update={"min_fix_lines": 100})
    config = config.model_copy(update={"sensors": {**config.sensors, "laser": laser}})
    localizer = Localizer(SegmentMap(ROOM[:, :2], ROOM[:, 2:], name="test"), config, TRUTH)
    for t in (0.0, 0.1, 0.2):
        localizer.on_odometry(t, 0.0, 0.0, 0.0)
    localizer.on_points(scan_time, scan_points(ROOM, TRUTH), "laser")
    assert localizer.stats.points_fixes == 1
    assert localizer.stats.late == (1 if scan_time < 0.2 else 0)

"""The wheels' distance scale learned from pairs of full fixes (fusion.wheel_scale)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.settings.wheel_scale import WheelScaleConfig
from fusion.wheel_scale import WheelScaleLearner

FIX_SIGMA = 0.01
FIX_COV = np.diag([FIX_SIGMA**2, FIX_SIGMA**2, 1e-5])
CONFIG = WheelScaleConfig()


def drive(learner: WheelScaleLearner, true_scale: float, rng: np.random.Generator,
          heading: float = 0.3, metres: float = 40.0, turn_per_metre: float = 0.0,
          wheels_turn_per_metre: float = 0.0, fix_every: float = 0.5,
          jitter: float = 0.0) -> None:
    """Drive ``metres`` from the map's origin at ``heading``, turning ``turn_per_metre``; the
    wheels at 50 Hz report 1/``true_scale`` of each step, in their own frame (turned by 1 rad
    from the map's) and turning ``wheels_turn_per_metre`` more than the robot does (wheels of
    different radii), each reading off by ``jitter`` (σ, m) in x and y; a full fix with
    ``FIX_SIGMA`` noise every ``fix_every`` m."""
    speed, rate = 0.5, 50.0
    t, x, y, th = 0.0, 0.0, 0.0, heading
    wx, wy, wth = 0.0, 0.0, heading + 1.0
    driven, next_fix = 0.0, 0.0
    for _ in range(round(metres / speed * rate)):
        step = speed / rate
        x, y = x + step * math.cos(th), y + step * math.sin(th)
        th += turn_per_metre * step
        reported = step / true_scale
        wx, wy = wx + reported * math.cos(wth), wy + reported * math.sin(wth)
        wth += (turn_per_metre + wheels_turn_per_metre) * step
        t += 1.0 / rate
        driven += step
        shake = rng.normal(0.0, jitter, 2) if jitter else (0.0, 0.0)
        learner.on_wheels(t, wx + shake[0], wy + shake[1], wth, broken=False)
        if driven >= next_fix:
            noise = rng.normal(0.0, FIX_SIGMA, 2)
            learner.on_fix(t - 0.01, np.array((x + noise[0], y + noise[1], th)), FIX_COV)
            next_fix += fix_every


@settings(max_examples=25, deadline=None)
@given(true_scale=st.floats(0.93, 1.07), seed=st.integers(0, 10_000))
def test_full_fixes_along_a_straight_path_find_the_wheels_scale(true_scale, seed) -> None:
    """40 m with a full fix every half metre: about twenty chords of 2 m, each good to about
    1 %: the estimate is within 1 % of the truth and its σ below the prior's fifth."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    drive(learner, true_scale, np.random.default_rng(seed))
    assert learner.updates >= 12
    assert abs(learner.value - true_scale) < 0.01
    assert learner.sigma < 0.2 * (CONFIG.sigma or 0.0)


def test_wheels_that_report_a_straight_path_as_an_arc_still_find_it() -> None:
    """Wheels whose radii differ by 8 % (on a 0.4 m base: 12° per metre) report a straight
    corridor as an arc; its length, not its chord (0.7 % shorter over 2 m), is the distance
    they report."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    drive(learner, 1.03, np.random.default_rng(3), wheels_turn_per_metre=math.radians(12.0))
    assert learner.updates >= 15
    assert abs(learner.value - 1.03) < 0.005


def test_the_readings_jitter_does_not_lengthen_the_path() -> None:
    """Readings 1 cm apart, each off by 2 mm: summed reading by reading, their path would be
    4 % longer than the wheels drove; measured in longer chords, the scale is still right."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    drive(learner, 0.98, np.random.default_rng(4), jitter=0.002)
    assert learner.updates >= 15
    assert abs(learner.value - 0.98) < 0.005


def test_a_curved_path_teaches_nothing() -> None:
    """Turning 30° per metre, no two fixes 2 m apart lie on a straight path: the prior stays."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    drive(learner, 1.05, np.random.default_rng(1), turn_per_metre=math.radians(30.0))
    assert learner.updates == 0 and learner.value == 1.0


def test_motion_the_wheels_missed_breaks_the_chord() -> None:
    """A fix, then a reading after an odometry gap (the wheels' path across it is unknown),
    then a fix 3 m on: no chord joins them."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    learner.on_wheels(0.0, 0.0, 0.0, 0.0, broken=False)
    learner.on_fix(0.0, np.zeros(3), FIX_COV)
    learner.on_wheels(0.1, 0.05, 0.0, 0.0, broken=False)
    learner.on_wheels(6.0, 2.9, 0.0, 0.0, broken=True)
    learner.on_fix(6.1, np.array((3.15, 0.0, 0.0)), FIX_COV)
    learner.on_wheels(6.2, 3.0, 0.0, 0.0, broken=False)
    assert learner.updates == 0
    learner.forget()
    assert learner.value == 1.0


def test_a_fix_waits_for_the_wheels_after_it() -> None:
    """A fix newer than the newest reading is used when the next reading brackets it: the
    wheels are interpolated at its time, not taken from the reading before. (Two chords that
    agree: a chord is used once the next one corroborates it.)"""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    learner.on_wheels(0.0, 0.0, 0.0, 0.0, broken=False)
    learner.on_fix(0.0, np.zeros(3), FIX_COV)
    learner.on_wheels(4.0, 2.0, 0.0, 0.0, broken=False)
    learner.on_fix(5.0, np.array((2.5, 0.0, 0.0)), FIX_COV)  # the wheels: 2.5 m at 5 s
    learner.on_wheels(6.0, 3.0, 0.0, 0.0, broken=False)
    learner.on_fix(10.0, np.array((5.0, 0.0, 0.0)), FIX_COV)
    assert learner.updates == 0  # waiting for the wheels after 10 s
    learner.on_wheels(11.0, 5.5, 0.0, 0.0, broken=False)
    assert learner.updates == 2
    assert learner.value == pytest.approx(1.0, abs=1e-6)  # 2.5 m measured for 2.5 m driven


def test_a_chord_between_wrong_fixes_is_not_believed() -> None:
    """The first chord's fix is 0.25 m off (a room the map lacks, the filter too unsure to
    refuse it): 10 % too long, within the prior's 2σ. No chord agrees with it, and the estimate
    is the right chords'."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    learner.on_wheels(0.0, 0.0, 0.0, 0.0, broken=False)
    learner.on_fix(0.0, np.zeros(3), FIX_COV)
    for k in range(1, 16):
        learner.on_wheels(4.0 * k, 2.0 * k, 0.0, 0.0, broken=False)
        wrong = 0.25 if k == 1 else 0.0
        learner.on_fix(4.0 * k, np.array((0.97 * 2.0 * k + wrong, 0.0, 0.0)), FIX_COV)
    learner.on_wheels(70.0, 35.0, 0.0, 0.0, broken=False)
    assert learner.updates == 6  # the six chords from 12 m on, each 4 m
    assert learner.value == pytest.approx(0.97, abs=0.002)


def test_a_run_of_chords_wrong_the_same_way_is_outvoted() -> None:
    """The first two chords agree on 7 % too long (a stretch where the map is stretched): they
    decide the estimate until the right chords after them are more (a Kalman filter's gate,
    centred on the wrong estimate, refused those for the rest of the run)."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    learner.on_wheels(0.0, 0.0, 0.0, 0.0, broken=False)
    learner.on_fix(0.0, np.zeros(3), FIX_COV)
    x = 0.0
    for k in range(1, 14):
        learner.on_wheels(4.0 * k, 2.0 * k, 0.0, 0.0, broken=False)
        x += 2.0 * (1.07 if k <= 2 else 0.99)
        learner.on_fix(4.0 * k, np.array((x, 0.0, 0.0)), FIX_COV)
    learner.on_wheels(60.0, 30.0, 0.0, 0.0, broken=False)
    assert learner.updates == 6  # two wrong, four right
    assert learner.value == pytest.approx(0.99, abs=0.002)


def test_one_pair_of_chords_does_not_move_the_scale() -> None:
    """Two chords agreeing on 7 % too long could lie in one distorted stretch of the map: the
    scale stays at the prior until a second pair agrees."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    drive(learner, 1.07, np.random.default_rng(5), metres=9.0)
    assert learner.updates == 2 and learner.value == 1.0
    assert learner.sigma == CONFIG.sigma  # the prior's, as the estimate is the prior
    drive_on = WheelScaleLearner(CONFIG, prior=1.0)
    drive(drive_on, 1.07, np.random.default_rng(5), metres=12.0)
    assert drive_on.updates == 4 and drive_on.value == pytest.approx(1.07, abs=0.01)
    assert drive_on.sigma < 0.2 * (CONFIG.sigma or 0.0)


def test_a_pair_wrong_the_same_way_is_outvoted_by_the_next() -> None:
    """ACES's held-out map: one pair of chords 5 and 8 % long (a stretched stretch of the map),
    then a pair of right ones (0.99): the median of the four and the prior lies between, the
    wrong pair is left out of the mean."""
    learner = WheelScaleLearner(CONFIG, prior=1.0)
    learner.on_wheels(0.0, 0.0, 0.0, 0.0, broken=False)
    learner.on_fix(0.0, np.zeros(3), FIX_COV)
    x = 0.0
    for k, ratio in enumerate((1.05, 1.08, 0.995, 0.985), start=1):
        learner.on_wheels(4.0 * k, 2.2 * k, 0.0, 0.0, broken=False)
        x += 2.2 * ratio
        learner.on_fix(4.0 * k, np.array((x, 0.0, 0.0)), FIX_COV)
        if k == 2:
            learner.on_wheels(4.0 * k + 0.1, 2.2 * k + 0.05, 0.0, 0.0, broken=False)
            assert learner.updates == 2 and learner.value == 1.0  # one pair: not used
    learner.on_wheels(20.0, 11.0, 0.0, 0.0, broken=False)
    assert learner.updates == 4
    assert learner.value == pytest.approx(0.99, abs=0.006)


def test_a_swerve_to_one_side_is_no_straight_path() -> None:
    """Heading 20° off the chord for half a metre, then back along a long gentle return: the
    path leaves its chord on one side by more than ``max_turn_deg`` and is refused, whichever
    side."""
    for side in (1.0, -1.0):
        learner = WheelScaleLearner(CONFIG, prior=1.0)
        t, x, y, path = 0.0, 0.0, 0.0, 0.0
        learner.on_wheels(t, path, 0.0, 0.0, broken=False)
        learner.on_fix(t, np.zeros(3), FIX_COV)
        legs = [(math.radians(20.0) * side, 0.5)] + [(-math.radians(4.0) * side, 0.5)] * 6
        for heading, length in legs * 3:
            x, y = x + length * math.cos(heading), y + length * math.sin(heading)
            path += length
            t += 1.0
            learner.on_wheels(t, path / 1.05, 0.0, 0.0, broken=False)
            learner.on_fix(t, np.array((x, y, heading)), FIX_COV)
        learner.on_wheels(t + 1.0, path / 1.05 + 0.01, 0.0, 0.0, broken=False)
        assert learner.updates == 0, side

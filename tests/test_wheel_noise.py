"""The wheels' random noise learned from the gaps between good scan matches and the wheels."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.motion import OdometryMotionModel
from fusion.settings.motion import OdometryMotionConfig
from fusion.settings.wheel_noise import WheelNoiseConfig
from fusion.settings.wheel_scale import WheelScaleConfig
from fusion.wheel_noise import WheelNoiseLearner

MOTION = OdometryMotionConfig()
CONFIG = WheelNoiseConfig()
ROLLING = WheelScaleConfig().wheel_noise  # m per √m: the least the wheels are credited with
LEAST = ROLLING**2 / (MOTION.alpha3**2 + MOTION.floor_xy**2)


def learned(share: float, seed: int, outliers: float = 0.0,
            config: WheelNoiseConfig = CONFIG) -> WheelNoiseLearner:
    """A learner told ``config.matches`` gaps of 5 cm steps whose variance is ``share`` of the
    default model's, a fraction ``outliers`` of them a person's 10 cm instead."""
    rng = np.random.default_rng(seed)
    learner = WheelNoiseLearner(config, MOTION, ROLLING)
    variance = 0.05 * (MOTION.alpha3**2 + MOTION.floor_xy**2)
    for _ in range(config.matches):
        gap = 0.1 if rng.random() < outliers else rng.normal(0.0, np.sqrt(share * variance))
        learner.observe(gap, variance)
    return learner


@settings(max_examples=30, deadline=None)
@given(share=st.floats(0.1, 0.9), seed=st.integers(0, 2**32 - 1))
def test_the_wheels_noise_is_found(share: float, seed: int) -> None:
    """Over 2,000 matches the median's relative standard error is about 5 %: within 25 % is
    five of them. (Over the default 200 it is 16 %, which the tests below allow for.)"""
    many = WheelNoiseConfig(matches=2000)
    assert learned(share, seed, config=many).factor == pytest.approx(share, rel=0.25)


def test_a_few_people_walking_past_do_not_make_the_wheels_noisy() -> None:
    assert learned(0.2, 1, outliers=0.1).factor < 0.3


def test_it_is_never_above_the_configured_nor_below_a_rolling_wheels() -> None:
    assert learned(4.0, 2).factor == 1.0
    assert learned(0.0, 3).factor == pytest.approx(LEAST)


def test_the_configured_noise_stands_until_enough_matches_were_seen() -> None:
    learner = WheelNoiseLearner(CONFIG, MOTION, ROLLING)
    for _ in range(CONFIG.matches // 4 - 1):
        learner.observe(0.0, 1e-4)
    assert learner.factor == 1.0
    learner.observe(0.0, 1e-4)
    assert learner.factor == pytest.approx(LEAST)


def test_the_factor_scales_the_noise_along_the_direction_of_travel_only() -> None:
    model = OdometryMotionModel()
    straight, turning = np.array([0.05, 0.0, 0.0]), np.array([0.05, 0.0, 0.02])
    default = model.noise(straight), model.noise(turning)
    model.translation_factor = 0.25
    assert model.noise(straight)[0, 0] == pytest.approx(0.25 * default[0][0, 0], rel=1e-12)
    assert model.noise(straight)[1, 1] == default[0][1, 1]  # across: not what matches measure
    assert model.noise(turning)[2, 2] == default[1][2, 2]  # the heading's noise is the turns'
    np.testing.assert_array_equal(model.noise(turning, 1.0), default[1])


def drive_matched(walls: np.ndarray, share: float, seed: int, scans: int = 60
                  ) -> WheelNoiseLearner:
    """Scan odometry through ``walls`` at 0.5 m/s with 10 Hz scans, the wheels' 5 cm steps
    off by noise of ``share`` times the default model's variance: the learner it told."""
    from fusion.scan_odometry import ScanOdometry
    from fusion.settings.scan_odometry import ScanOdometryConfig
    from tests.test_scan_odometry import scan_points

    rng = np.random.default_rng(seed)
    learner = WheelNoiseLearner(CONFIG, MOTION, ROLLING)
    model = OdometryMotionModel(MOTION)
    scan_odometry = ScanOdometry(ScanOdometryConfig(), model, learner)
    step = np.array([0.05, 0.0, 0.0])
    sigma = np.sqrt(share * model.noise(step, 1.0)[0, 0])
    pose, wheels = np.array([2.0, 3.0, 0.0]), 0.0
    for k in range(scans):
        scan_odometry.on_wheels(wheels, 0.0, 0.0, t=0.1 * k)
        correction = scan_odometry.match(0.1 * k, scan_points(walls, pose))
        if correction is not None:
            scan_odometry.commit(correction)
        pose = pose + step
        wheels += 0.05 + rng.normal(0.0, sigma)
    return learner


def test_a_room_shows_how_well_the_wheels_roll_and_a_corridor_does_not() -> None:
    """In a room every match observes the step along the wheels' direction: wheels that err a
    third of the default model's variance are found so, good ones at the floor. Along a
    featureless corridor no match observes it, and nothing is learned."""
    from tests.test_scan_odometry import CORRIDOR, ROOM

    assert drive_matched(ROOM, 0.3, 4).factor == pytest.approx(0.3, rel=0.4)
    assert drive_matched(ROOM, 0.0, 5).factor == pytest.approx(LEAST, rel=0.5)
    corridor = drive_matched(CORRIDOR, 0.3, 6)
    assert corridor.factor == 1.0 and corridor.summary()["matches"] == 0

"""The node's odometry buffer (no ROS needed): the pose at a reading's own stamp is that
reading, between two readings it is on the segment between them (the heading the short way
round), and outside them the nearest."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fusion.ros2.odometry import OdometryBuffer

finite = st.floats(-100.0, 100.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


@given(st.lists(st.tuples(finite, finite, angle), min_size=2, max_size=20),
       st.floats(0.0, 1.0))
def test_the_pose_between_readings_lies_between_them(poses, w):
    buffer = OdometryBuffer(100)
    for k, (x, y, theta) in enumerate(poses):
        buffer.append(0.1 * k, x, y, theta)
    for k, pose in enumerate(poses):
        got = buffer.at(0.1 * k)
        assert got is not None
        np.testing.assert_allclose(got[:2], pose[:2], atol=1e-9)
        assert abs(math.remainder(got[2] - pose[2], math.tau)) < 1e-9
        assert -math.pi <= got[2] <= math.pi
    a, b = np.array(poses[0]), np.array(poses[1])
    mid = buffer.at(0.1 * w)
    assert mid is not None
    np.testing.assert_allclose(mid[:2], a[:2] + w * (b[:2] - a[:2]), atol=1e-9)
    turn = math.remainder(b[2] - a[2], math.tau)
    assert abs(math.remainder(mid[2] - a[2], math.tau) - w * turn) < 1e-9
    np.testing.assert_allclose(buffer.at(-5.0), poses[0])  # the readings as they came
    np.testing.assert_allclose(buffer.at(99.0), poses[-1])
    assert buffer.last_before(0.15) == (0.1, *poses[1])
    assert buffer.newest_time == 0.1 * (len(poses) - 1)


def test_an_empty_buffer_has_no_pose_and_keeps_only_the_newest():
    buffer = OdometryBuffer(3)
    assert buffer.at(0.0) is None and buffer.last_before(0.0) is None
    assert buffer.newest_time == -math.inf
    for k in range(5):
        buffer.append(float(k), float(k), 0.0, 0.0)
    assert buffer.last_before(1.5) is None  # readings 0 and 1 are gone
    assert buffer.last_before(3.5) == (3.0, 3.0, 0.0, 0.0)

"""When each scan's pose is reported (fusion/time_order.py), without ROS: which estimates
leave, in which order, and when. The replay and the ROS 2 node share this owner; that they give
the same poses on the same stream is tested in tests/test_ros2_node.py."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion.estimate import Estimate
from fusion.settings.filter import FilterConfig
from fusion.status import ScanStatus
from fusion.time_order import Held, TimeOrder, settled
from fusion.tracker import PoseTracker


def estimate(t: float) -> Estimate:
    return Estimate(t, np.zeros(3), np.eye(3), ScanStatus.ACCEPTED)


# an input stream: ("scan", stamp), ("odometry", stamp) or ("tick", seconds of wall time)
_STEP = st.one_of(st.tuples(st.just("scan"), st.floats(0.0, 10.0)),
                  st.tuples(st.just("odometry"), st.floats(0.0, 10.0)),
                  st.tuples(st.just("tick"), st.floats(0.0, 0.5)))


@given(st.lists(_STEP, max_size=60), st.floats(0.0, 1.0))
def test_poses_are_reported_in_scan_order_once_and_only_when_due(steps, wait):
    """Every scan's estimate is reported once, in scan order, and only when due: at once when
    the odometry covers its stamp and nothing waits before it; later when an odometry reading
    covers it, when the next scan arrives, when it waited ``wait`` of wall time, or when the
    stream ends. After every input the oldest still held is not covered by the odometry."""
    order = TimeOrder(wait)
    odometry, now, scans, reported = None, 0.0, 0, []  # reported: scan numbers, in order
    for kind, value in steps:
        if kind == "scan":
            reported.extend(int(h.t_out) for h in order.scan_arriving())
            assert len(order) == 0  # the next scan ends every wait
            due = order.localized(estimate(value), float(scans), odometry, now)
            if due and not due[0].waited:  # at once: covered, nothing held before it
                assert odometry is None or value <= odometry
            else:
                assert due == [] and len(order) == 1
            reported.extend(int(h.t_out) for h in due)
            scans += 1
        elif kind == "odometry":
            odometry = value if odometry is None else max(odometry, value)
            due = order.odometry(odometry)
            assert all(h.estimate.t <= odometry for h in due)
            reported.extend(int(h.t_out) for h in due)
        else:
            now += value
            due = order.overdue(now)
            assert all(now - h.arrived >= wait for h in due)
            reported.extend(int(h.t_out) for h in due)
        oldest = order.oldest
        if oldest is not None:
            assert odometry is not None and oldest.estimate.t > odometry
            assert kind != "tick" or now - oldest.arrived < wait
    reported.extend(int(h.t_out) for h in order.drain())
    assert reported == list(range(scans))  # in scan order, each once


def test_a_covered_scan_waits_behind_an_older_one():
    """Estimates held past the odometry leave oldest first: one the odometry covers waits
    behind an older one it does not."""
    order = TimeOrder()
    assert order.localized(estimate(1.0), 1.0, 0.5) == []
    assert order.localized(estimate(0.7), 0.7, 0.5) == []
    assert order.odometry(0.8) == []  # 0.7 is covered, but waits behind the one at 1.0
    assert [h.t_out for h in order.odometry(1.0)] == [1.0, 0.7]
    assert order.overdue(100.0) == [] and order.drain() == []
    with pytest.raises(ValueError, match="wait"):
        TimeOrder(wait=-1.0)


def test_a_pose_that_waited_is_read_again_at_its_scans_time():
    """A scan at 0.15 s, after the newest reading (0.1 s): the estimate the localizer gave then
    carried the pose past the reading. Reported after the reading at 0.2 s, its pose is the
    filter's at 0.15 s now, between the two readings; reported at once, as it was."""
    tracker = PoseTracker.from_config(FilterConfig(), np.zeros(3))
    tracker.on_odometry(0.0, 0.0, 0.0, 0.0)
    tracker.on_odometry(0.1, 0.1, 0.0, 0.0)
    ahead = tracker.pose_at(0.15)
    assert ahead is not None
    early = Estimate(0.15, ahead[0], ahead[1], ScanStatus.NO_FIX)
    order = TimeOrder()
    assert order.localized(early, 0.15, tracker.odometry_time) == []
    tracker.on_odometry(0.2, 0.3, 0.0, 0.0)  # the robot sped up: 3 m/s, not 1 m/s
    (held,) = order.odometry(tracker.odometry_time)
    reported = settled(held, tracker)
    assert reported.pose[0] == pytest.approx(0.2, abs=1e-9)  # halfway from 0.1 to 0.3 m
    assert early.pose[0] == pytest.approx(0.15, abs=1e-9)  # carried at 1 m/s
    assert settled(Held(early, 0.15), tracker) is early  # reported at once: as it was

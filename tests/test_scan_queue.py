"""The ROS 2 node's scans held for the odometry (fusion.ros2.scan_queue), without ROS: what
leaves, in which order, and what is dropped."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fusion.events import Scan
from fusion.ros2.scan_queue import ScanQueue

EMPTY = np.zeros(0)


def scan(t: float) -> Scan:
    return Scan(t, EMPTY, EMPTY)


# an input stream: ("scan", stamp), ("odometry", stamp) or ("tick", seconds of waiting)
_STEP = st.one_of(st.tuples(st.just("scan"), st.floats(0.0, 10.0)),
                  st.tuples(st.just("odometry"), st.floats(0.0, 10.0)),
                  st.tuples(st.just("tick"), st.floats(0.0, 0.5)))


@given(st.lists(_STEP, max_size=60), st.integers(1, 5), st.floats(0.05, 1.0))
def test_scans_leave_in_arrival_order_once_and_only_when_due(steps, size, wait):
    """Every scan leaves at most once, in the order it came; by the odometry only when a reading
    at or after its stamp is in and every scan before it has left; by the clock only after
    ``wait`` seconds; and only the oldest is ever dropped, counted."""
    queue = ScanQueue(size)
    now, arrived, left, dropped = 0.0, 0, [], 0  # left: arrival numbers, in the order they left
    for kind, value in steps:
        if kind == "scan":
            if arrived - len(left) == size:  # full: the oldest held is dropped
                left.append(len(left))
                dropped += 1
            queue.push(scan(value), str(arrived), now)  # the sensor name numbers the arrival
            arrived += 1
        elif kind == "odometry":
            for pending in queue.reached(value):
                assert pending.scan.t <= value
                left.append(int(pending.sensor))
        else:
            now += value
            for pending in queue.overdue(now, wait):
                assert now - pending.arrived >= wait
                left.append(int(pending.sensor))
    assert left == list(range(len(left)))  # in arrival order, each once
    assert queue.dropped == dropped
    assert arrived - len(left) <= size


def test_a_scan_ahead_of_the_odometry_holds_the_ones_behind_it():
    """The odometry at 1.0 s releases the scan at 0.5 s, not the one at 2.0 s, nor the one at
    0.8 s that came after it: scans leave in their arrival order."""
    queue = ScanQueue()
    for t in (0.5, 2.0, 0.8):
        queue.push(scan(t), "laser", 0.0)
    assert [p.scan.t for p in queue.reached(1.0)] == [0.5]
    assert [p.scan.t for p in queue.reached(2.0)] == [2.0, 0.8]
    queue.push(scan(3.0), "laser", 0.0)
    assert list(queue.overdue(0.09, 0.1)) == []
    assert [p.scan.t for p in queue.overdue(0.1, 0.1)] == [3.0]

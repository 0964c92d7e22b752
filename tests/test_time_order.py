"""When each measurement meets the filter (fusion/time_order.py), without ROS: what leaves, in
which order, and when. The replay and the ROS 2 node share this owner; that they give the same
poses on the same stream is tested in tests/test_ros2_node.py."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fusion.events import Scan
from fusion.io.timing import MAX_TIME_STEP
from fusion.time_order import Held, TimeOrder

EMPTY = np.zeros(0)


def scan(t: float, number: int, sensor: str = "laser") -> Scan:
    return Scan(t, EMPTY, EMPTY, sensor=sensor, line=number)  # the line numbers the arrival


# an input stream: ("scan", stamp, sensor), ("odometry", stamp) or ("tick", seconds of wall time)
_STAMP = st.one_of(st.floats(0.0, 10.0), st.sampled_from([math.nan, math.inf, 100.0]))
_STEP = st.one_of(st.tuples(st.just("scan"), _STAMP, st.sampled_from(["front", "rear"])),
                  st.tuples(st.just("odometry"), st.floats(0.0, 10.0)),
                  st.tuples(st.just("tick"), st.floats(0.0, 0.5)))


class _Stream:
    """What the stream has shown so far, kept by the test itself: the law's terms."""

    def __init__(self) -> None:
        self.odometry: float | None = None
        self.sensors: list[str] = []  # of each arrival
        self.superseded: set[int] = set()  # arrivals whose sensor has sent a newer one

    def arrive(self, sensor: str) -> None:
        self.superseded |= {k for k, s in enumerate(self.sensors) if s == sensor}
        self.sensors.append(sensor)

    def due(self, held: Held) -> bool:
        """May this measurement go on without waiting longer for the odometry?"""
        t, odometry = held.event.t, self.odometry
        return (odometry is None or held.event.line in self.superseded or not math.isfinite(t)
                or t - odometry > MAX_TIME_STEP or t <= odometry)


@given(st.lists(_STEP, max_size=60), st.integers(1, 5), st.floats(0.0, 1.0))
def test_measurements_leave_in_arrival_order_once_and_only_when_due(steps, size, wait):
    """Every measurement leaves once, in the order it came, and only when due: the odometry has
    reached its stamp, its sensor has sent a newer one, no odometry has come, its stamp cannot
    be reached (not finite, or a stray far ahead), the queue was full (the oldest only), it
    waited ``wait`` of wall time, or the stream ended. After every input the oldest still held
    is not due: nothing waits longer than the rules say. At most ``size`` are held."""
    order, stream = TimeOrder(wait, size), _Stream()
    now, left = 0.0, []  # left: arrival numbers, in the order they left

    def leave(due: list[Held], pushed_out: int = 0) -> None:
        for k, held in enumerate(due):
            if k >= pushed_out:
                assert stream.due(held)
            left.append(held.event.line)

    for step in steps:
        kind = step[0]
        if kind == "scan":
            full = len(stream.sensors) - len(left) == size
            number = len(stream.sensors)
            stream.arrive(step[2])
            leave(order.measurement(scan(step[1], number, step[2]), now), pushed_out=int(full))
        elif kind == "odometry":
            stream.odometry = step[1] if stream.odometry is None else max(stream.odometry,
                                                                           step[1])
            leave(order.odometry(step[1]))
        else:
            now += step[1]
            due = order.overdue(now)
            assert all(now - held.arrived >= wait for held in due)
            left.extend(held.event.line for held in due)
        assert len(order) == len(stream.sensors) - len(left) <= size
        oldest = order.oldest
        if oldest is not None:  # not due by the data, nor by the wall clock after a tick
            assert not stream.due(oldest)
            assert kind != "tick" or now - oldest.arrived < wait
    held = len(order)
    leave(order.drain(), pushed_out=held)  # the stream ended: every one goes on
    assert left == list(range(len(stream.sensors)))  # in arrival order, each once
    assert len(order) == 0


def test_a_scan_ahead_of_the_odometry_holds_the_ones_behind_it():
    """Three lasers: the odometry at 0.55 s releases the front laser's scan at 0.5 s, not the
    rear one's at 0.7 s, nor the side one's at 0.6 s that came after it: measurements leave in
    their arrival order. The odometry stops at 0.7 s: the front laser's next scan releases its
    scan at 3.0 s, and the wall clock the others, each after 0.25 s held."""
    order = TimeOrder(wait=0.25)
    order.odometry(0.45)
    for k, (t, sensor) in enumerate(((0.5, "front"), (0.7, "rear"), (0.6, "side"))):
        assert order.measurement(scan(t, k, sensor)) == []
    assert [h.event.t for h in order.odometry(0.55)] == [0.5]
    assert [h.event.t for h in order.odometry(0.7)] == [0.7, 0.6]
    assert order.measurement(scan(3.0, 3, "front"), now=10.0) == []
    assert order.measurement(scan(3.05, 4, "rear"), now=10.05) == []
    assert [h.event.t for h in order.measurement(scan(3.1, 5, "front"), now=10.1)] == [3.0]
    assert [h.event.t for h in order.overdue(10.34)] == [3.05]
    assert [h.event.t for h in order.overdue(10.35)] == [3.1]


def test_stray_stamps_and_a_stream_without_odometry_do_not_wait():
    """Before any odometry there is none to wait for; a stamp that is not finite, or further
    ahead of the odometry than a record may run (MAX_TIME_STEP), goes on at once (the localizer
    says what it makes of it)."""
    order = TimeOrder()
    assert [h.event.t for h in order.measurement(scan(5.0, 0))] == [5.0]
    order.odometry(1.0)
    assert [h.event.t for h in order.measurement(scan(1.0 + 2 * MAX_TIME_STEP, 1))] == [11.0]
    nan = order.measurement(scan(math.nan, 2))
    assert len(nan) == 1 and math.isnan(nan[0].event.t)
    assert order.measurement(scan(4.9, 3)) == []  # ahead of the odometry, within its reach

"""When each measurement meets the filter: the one owner of time ordering, for the replay
(:func:`fusion.replay.replay`) and the ROS 2 node alike.

Odometry goes to the localizer as it arrives. A measurement (a scan, a point set, a landmark)
is localized once the odometry has reached its stamp, so that the filter predicts to it before
it corrects (as AMCL waits for the odom → base transform); until then it is held here. A held
measurement goes on without that odometry when the data show none is coming in time:

* the next measurement of the same sensor has arrived: a whole period of the sensor passed
  without the odometry reaching it (the odometry stopped, or is stamped behind the sensor's
  clock: then every reading that came meanwhile would hand it motion from after its time);
* no odometry has come at all (the stream's start, or a robot without wheels), or the
  measurement's stamp is not finite or beyond ``MAX_TIME_STEP`` ahead of the odometry: the
  localizer, not the wait, says what it makes of it;
* ``size`` measurements are held: the oldest goes on;
* the caller says so: the stream ended (:meth:`TimeOrder.drain`), or, on a robot, it waited
  ``wait`` seconds of wall time (:meth:`TimeOrder.overdue`).

Measurements leave in their arrival order: one the odometry has reached waits behind an older
one it has not. The rules read the data only (the wall-time one aside, which only the node
uses), so the same stream in the same order gives the same poses offline and on a robot.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from fusion.events import Landmark, PointSet, Scan
from fusion.io.timing import MAX_TIME_STEP

Measurement = Scan | PointSet | Landmark

ODOMETRY_WAIT = 0.25
"""s of wall time a measurement waits for the odometry at its stamp before it goes on without
(on a robot: the node's ``houghloc.odom_wait``): several odometry periods at 20–100 Hz."""
HELD_MEASUREMENTS = 10
"""Measurements held for the odometry at most; beyond, the oldest goes on without."""


@dataclass(slots=True)
class Held:
    """A measurement and when it arrived (monotonic seconds of the caller's wall clock)."""

    event: Measurement
    arrived: float = 0.0
    superseded: bool = False
    """the next measurement of its sensor has arrived"""


class TimeOrder:
    """The measurements waiting for the odometry, oldest first (module docstring)."""

    def __init__(self, wait: float = ODOMETRY_WAIT, size: int = HELD_MEASUREMENTS) -> None:
        if not (wait >= 0.0 and size >= 1):
            raise ValueError(f"wait {wait} s and size {size}: expected wait ≥ 0 and size ≥ 1")
        self.wait, self.size = wait, size
        self.odometry_time: float | None = None
        """the newest odometry stamp"""
        self._held: deque[Held] = deque()

    def __len__(self) -> int:
        return len(self._held)

    @property
    def oldest(self) -> Held | None:
        """The measurement that leaves next, None when none is held."""
        return self._held[0] if self._held else None

    def clear(self) -> None:
        """Forget the measurements held and the odometry's time (the localizer starts again)."""
        self._held.clear()
        self.odometry_time = None

    def odometry(self, t: float) -> list[Held]:
        """An odometry reading at ``t`` (given to the localizer already): the measurements now
        due, oldest first."""
        if math.isfinite(t):
            self.odometry_time = t if self.odometry_time is None else max(self.odometry_time, t)
        return self._due()

    def measurement(self, event: Measurement, now: float = 0.0) -> list[Held]:
        """A measurement arrived (at ``now``, wall time): held, and the measurements now due,
        oldest first (itself among them when nothing holds it)."""
        if len(self._held) == self.size:
            due = [self._held.popleft()]
        else:
            due = []
        for held in self._held:
            held.superseded = held.superseded or held.event.sensor == event.sensor
        self._held.append(Held(event, now))
        return due + self._due()

    def overdue(self, now: float) -> list[Held]:
        """The measurements, oldest first, that have waited ``wait`` seconds of wall time."""
        due = []
        while self._held and now - self._held[0].arrived >= self.wait:
            due.append(self._held.popleft())
        return due

    def drain(self) -> list[Held]:
        """Every measurement held, oldest first: the stream ended."""
        due = list(self._held)
        self._held.clear()
        return due

    def _due(self) -> list[Held]:
        due = []
        while self._held and self._goes_on(self._held[0]):
            due.append(self._held.popleft())
        return due

    def _goes_on(self, held: Held) -> bool:
        """Does a held measurement wait no longer for the odometry?"""
        t, odometry = held.event.t, self.odometry_time
        return held.superseded or odometry is None or not self._plausible(t) or t <= odometry

    def _plausible(self, t: float) -> bool:
        """A stamp the odometry could yet reach: finite and at most ``MAX_TIME_STEP`` ahead of
        it (the localizer drops one further ahead as a stray stamp)."""
        odometry = self.odometry_time
        return math.isfinite(t) and (odometry is None or t - odometry <= MAX_TIME_STEP)

"""When each scan's pose is reported: the one owner of time ordering, for the replay
(:func:`fusion.replay.replay`) and the ROS 2 node alike.

Odometry and scans go to the localizer as they arrive. A scan stamped after the newest odometry
reading (its reading for the same instant is next in the stream, or the clocks differ by a
rounding) is localized at once, the filter carrying the pose past that reading
(:mod:`fusion.pose_history`); its pose is *reported* once the odometry covering its stamp has
arrived, so that the pose at its time holds the odometry on both sides of it. Until then its
estimate is held here. A held estimate is reported without that odometry when the data show
none is coming in time:

* the next scan arrives: odometry stamped behind the scans (a run of readings sharing one
  stamp) would otherwise hold it until the stamps catch up, and then give it all the motion
  since;
* the caller says so: the stream ended (:meth:`TimeOrder.drain`), or, on a robot, it waited
  ``wait`` seconds of wall time (:meth:`TimeOrder.overdue`).

Estimates leave in scan order. The rules read the data only (the wall-time one aside, which
only the node uses), so the same stream in the same order gives the same poses offline and on
a robot. Waiting to *localize* a scan until the odometry reaches it (as AMCL waits for the
odom → base transform) was measured and not kept (docs/experiments.md, "The time order").
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fusion.estimate import Estimate
    from fusion.tracker import PoseTracker

ODOMETRY_WAIT = 0.25
"""s of wall time a pose waits for the odometry at its scan's stamp before it is reported
without (on a robot: the node's ``houghloc.odom_wait``): several odometry periods at
20–100 Hz."""


@dataclass(frozen=True, slots=True)
class Held:
    """A scan's estimate, the time its pose is reported at (the record's own stamp where the
    reader had to replace it), and when it arrived (monotonic seconds of the caller's clock)."""

    estimate: Estimate
    t_out: float
    arrived: float = 0.0
    waited: bool = False
    """held for the odometry: its pose is read again when it is reported (:func:`settled`)"""


class TimeOrder:
    """The estimates waiting for the odometry to cover their scans, oldest first (module
    docstring)."""

    def __init__(self, wait: float = ODOMETRY_WAIT) -> None:
        if not wait >= 0.0:
            raise ValueError(f"wait {wait} s: expected wait ≥ 0")
        self.wait = wait
        self._held: deque[Held] = deque()

    def __len__(self) -> int:
        return len(self._held)

    @property
    def oldest(self) -> Held | None:
        """The estimate reported next, None when none is held."""
        return self._held[0] if self._held else None

    def scan_arriving(self) -> list[Held]:
        """A scan arrived, before it is localized: every estimate held is reported now."""
        return self.drain()

    def localized(self, estimate: Estimate, t_out: float, odometry_time: float | None,
                  now: float = 0.0) -> list[Held]:
        """A scan's ``estimate`` (``odometry_time``: the filter's newest reading): reported at
        once when the odometry covers its stamp and nothing is held before it, else held; the
        estimates now due, oldest first."""
        if not self._held and (odometry_time is None or estimate.t <= odometry_time):
            return [Held(estimate, t_out, now)]
        self._held.append(Held(estimate, t_out, now, waited=True))
        return []

    def odometry(self, odometry_time: float | None) -> list[Held]:
        """An odometry reading was taken (``odometry_time``: the filter's newest reading): the
        estimates it covers, oldest first."""
        due = []
        while (self._held and odometry_time is not None
               and self._held[0].estimate.t <= odometry_time):
            due.append(self._held.popleft())
        return due

    def overdue(self, now: float) -> list[Held]:
        """The estimates, oldest first, that have waited ``wait`` seconds of wall time."""
        due = []
        while self._held and now - self._held[0].arrived >= self.wait:
            due.append(self._held.popleft())
        return due

    def drain(self) -> list[Held]:
        """Every estimate held, oldest first."""
        due = list(self._held)
        self._held.clear()
        return due

    def clear(self) -> None:
        """Forget the estimates held (the localizer they came from is gone)."""
        self._held.clear()


def settled(held: Held, tracker: PoseTracker) -> Estimate:
    """The scan's estimate as reported: one that waited for the odometry with the filter's pose
    and covariance at its time now (the odometry since has arrived, or will not in time), or as
    it was when the filter has no pose there; one reported at once as it is."""
    if not held.waited:
        return held.estimate
    at_t = tracker.pose_at(held.estimate.t)
    if at_t is None:
        return held.estimate
    return replace(held.estimate, pose=at_t[0], cov=at_t[1])

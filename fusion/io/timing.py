"""The one policy for time, applied by every reader (here) and by the Localizer.

* A stamp is a plain number of seconds: negative stamps are ordinary times (some logs count
  from an origin set later), equal stamps are simultaneous readings (a zero interval is not a
  jump: coarse or repeated stamps keep their motion).
* A stamp that goes back is counted (``ReadStats.backwards_timestamps``); the filter drops
  odometry older than its newest reading and applies late measurements at their time.
* A stamp that jumps ahead of the log's clock by more than :data:`MAX_TIME_STEP` is held until
  the next record: if that one is at or after it, the gap was real and both are used; if it is
  back before it, the held record was a stray stamp (a clock glitch, a corrupted digit) and is
  dropped with a warning naming its line. A dropped record never moves the clock.

Readers apply it to a log (:class:`StrayStampFilter`); the Localizer to its odometry stream, one
reading at a time (:class:`HeldOdometry`), and drops a scan stamped that far ahead of its
odometry.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from typing import NamedTuple

from fusion.events import Event, Odometry, PointSet, ReadStats, Scan

log = logging.getLogger(__name__)
LOGGED = 20  # warnings of this kind shown as they happen; all are counted in metrics.json

MAX_TIME_STEP = 5.0
"""s: how far a record may run ahead of the log's clock before it needs the next record to
confirm it. Odometry comes at 5–100 Hz, but real clocks jitter: Intel's log stamps go forward
and back by up to 1.4 s between neighbouring records."""


def _line(event: Event) -> str:
    line = getattr(event, "line", None)
    return f"line {line}" if line is not None else f"t = {event.t:.6g} s"


class StrayStampFilter:
    """Re-iterable events of ``source`` without records whose stamp jumps ahead and back."""

    def __init__(self, source: Iterable[Event], stats: ReadStats,
                 max_step: float = MAX_TIME_STEP, name: str = "") -> None:
        self.source, self.stats, self.max_step, self.name = source, stats, max_step, name

    def __iter__(self) -> Iterator[Event]:
        clock: float | None = None
        held: Event | None = None
        for event in self.source:
            t = event.t
            if held is not None:
                if t >= held.t:  # the gap was real
                    clock = held.t
                    yield held
                else:
                    self._drop(held, clock)
                held = None
            if clock is not None and t - clock > self.max_step:
                held = event
                continue
            if clock is None or t > clock:
                clock = t
            yield event
        if held is not None:  # nothing after it to tell: the log ended after a pause
            yield held

    def _drop(self, event: Event, clock: float | None) -> None:
        kind = type(event).__name__
        self.stats.stray_timestamps += 1
        message = (f"{self.name + ': ' if self.name else ''}{_line(event)}: {kind} stamped "
                   f"{event.t:.6g} s, {event.t - (clock or 0.0):.3g} s ahead of the records "
                   "before and after it; dropped")
        self.stats.warn(message, kind="stray timestamp")
        if self.stats.stray_timestamps <= LOGGED:
            log.warning("%s", message)


def from_first_scan(events: Iterable[Event], limit: int | None = None) -> Iterator[Event]:
    """The events from the first scan (or point set) on, with the last odometry reading before
    it, which anchors the odometry frame there: an initial pose is the pose at the first scan,
    whatever the odometry did before (most real logs carry decimetres and degrees of motion
    before their first scan). At most ``limit`` scans."""
    last_odom = None
    started = False
    scans = 0
    for e in events:
        if not started:
            if isinstance(e, Odometry):
                last_odom = e
                continue
            if not isinstance(e, Scan | PointSet):
                continue
            started = True
            if last_odom is not None:
                yield last_odom
        if isinstance(e, Scan):
            if limit is not None and scans >= limit:
                return
            scans += 1
        yield e


class OdometryReading(NamedTuple):
    """An odometry reading as the Localizer takes it (``unmeasured``: seconds of motion before
    ``t`` that the increment misses)."""

    t: float
    x: float
    y: float
    theta: float
    unmeasured: float = 0.0


class HeldOdometry:
    """The policy above for a stream of odometry readings: a reading more than
    :data:`MAX_TIME_STEP` after the odometry's clock is held; the next reading at or after it,
    or a scan stamped no more than MAX_TIME_STEP before it, confirms it; a reading before it
    shows it a stray stamp."""

    def __init__(self) -> None:
        self.reading: OdometryReading | None = None

    def hold(self, reading: OdometryReading, clock: float | None) -> bool:
        """Hold ``reading`` back when it is more than MAX_TIME_STEP after ``clock``."""
        if clock is not None and reading.t - clock > MAX_TIME_STEP:
            self.reading = reading
            return True
        return False

    def next_reading(self, t: float) -> tuple[OdometryReading | None, OdometryReading | None]:
        """A reading at ``t`` came: the held one as (confirmed, None) or (None, a stray stamp);
        (None, None) when none was held."""
        held, self.reading = self.reading, None
        if held is None:
            return None, None
        return (held, None) if t >= held.t else (None, held)

    def scan_at(self, t: float) -> OdometryReading | None:
        """A scan at ``t`` came: the held reading when the scan confirms it."""
        held = self.reading
        if held is None or not t >= held.t - MAX_TIME_STEP:
            return None
        self.reading = None
        return held

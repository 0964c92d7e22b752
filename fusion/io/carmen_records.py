"""One CARMEN record to events: the fields of ODOM, FLASER and ROBOTLASER1 lines checked and
converted, every problem a :class:`_BadRecord` that names the field (the reader turns it into a
warning with the line's number).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from fusion.events import MAX_POSE_COORDINATE, Event, Odometry, Scan, Truth
from fusion.io.carmen_conventions import (
    NOMINAL_ODOMETRY_RATE,
    NOMINAL_PACE,
    RecordSource,
    StampClock,
    flaser_angles,
)
from fusion.io.errors import LogError
from fusion.io.numbers import parse_floats
from houghloc.geometry import compose, relative

# the reader's logger: warnings name the log they come from
log = logging.getLogger("fusion.io.carmen")

NO_RETURN_RANGE = 80.0
"""Ranges at or above this (metres) are "no return" (SICK logs use 81.83 / 81.91)."""
LOGGED_WARNINGS = 20
"""How many bad records per file are reported through ``logging`` (all are counted)."""


_KNOWN_RECORDS = frozenset(
    {
        "ODOM",
        "FLASER",
        "RLASER",
        "LASER3",
        "LASER4",
        "ROBOTLASER1",
        "ROBOTLASER2",
        "RAWLASER1",
        "RAWLASER2",
        "RAWLASER3",
        "RAWLASER4",
        "TRUEPOS",
        "PARAM",
        "SYNC",
        "NEFF",
        "SONAR",
        "BUMPER",
        "GPSNMEA",
        "GPSGGA",
        "GPSRMC",
        "VECTORMOVE",
        "ROBOTVELOCITY",
        "FOLLOWTRAJECTORY",
        "BASEVELOCITY",
        "IMU",
        "ARM",
    }
)


_LASER_RECORDS = ("FLASER", "ROBOTLASER1")


def _odometry(t: float, pose: NDArray[np.float64], line: int | None,
              unmeasured: float = 0.0) -> Odometry:
    x, y, theta = pose.tolist()
    return Odometry(t, x, y, theta, line=line, unmeasured=unmeasured)


class _BadRecord(ValueError):
    """A record that cannot be used; the message says why (the caller adds the line number)."""


class CarmenParser:
    """One pass over a log: parses records, rebuilds raw odometry, fills the stats."""

    def __init__(self, source: RecordSource) -> None:
        self.source = source
        self.stats = source.stats
        self.corrected = source.conventions.corrected
        self.laser_odometry = source.conventions.laser_odometry
        # beam angles by layout: every scan of a log shares one array (read-only)
        self._angles: dict[int | tuple[float, float, int], NDArray[np.float64]] = {}
        self._last_t: float | None = None
        # Raw-odometry reconstruction for corrected logs (see the module docstring).
        self._raw: NDArray[np.float64] | None = None  # last emitted raw pose
        self._prev_logged: NDArray[np.float64] | None = None  # logged pose of the last ODOM t > 0
        self._anchor: NDArray[np.float64] | None = None  # re-anchoring pose since then, if any
        self._laser_pose: NDArray[np.float64] | None = None  # pose of a laser record not yet
        # followed by an ODOM line (the next ODOM may be its re-anchoring line)
        self._raw_t = -math.inf  # time of the last emitted raw pose
        self._clock = source.conventions.clock
        self._clock_t = 0.0  # a clock kept from the records' order (StampClock.ORDER)
        self._clock_pose: NDArray[np.float64] | None = None

    def events(self, f: TextIO) -> Iterator[Event]:
        path = self.source.path
        emitted = 0
        number = 0
        try:
            for number, line in enumerate(f, start=1):
                tokens = line.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                try:
                    produced = self._record(tokens, number)
                except _BadRecord as err:
                    self._warn(f"line {number}: {tokens[0][:20]} record skipped: {err}")
                    continue
                if produced is None:
                    continue
                self.stats.records += 1
                for event in produced:
                    self._check_order(event.t, number)
                    emitted += 1
                    yield event
        except (OSError, EOFError) as err:  # a truncated or corrupt gzip stream
            self._warn(f"line {number + 1}: stream ends early ({err}); the rest is lost",
                       "stream ends early")
        for kind, (count, _first) in self.stats.kinds.items():
            if count > LOGGED_WARNINGS:
                log.warning("%s: %d more of kind %r not shown (metrics.json counts them)", path,
                            count - LOGGED_WARNINGS, kind)
        if emitted == 0:
            raise LogError(
                path, f"no usable record ({number} lines read, {self.stats.skipped} bad records)"
            )

    def _warn(self, message: str, kind: str = "bad record", skipped: bool = True) -> None:
        """Count a warning of its kind; log the first of each kind and the first
        LOGGED_WARNINGS of each (metrics.json has them all by kind)."""
        # a damaged line may hold terminal escapes: never echo them
        message = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
        self.stats.warn(message, kind=kind, skipped=skipped)
        if self.stats.kinds[kind][0] <= LOGGED_WARNINGS:
            log.warning("%s: %s", self.source.path, message)

    def _check_order(self, t: float, number: int) -> None:
        if self._last_t is not None and t < self._last_t:
            self.stats.backwards_timestamps += 1
            self._warn(f"line {number}: stamp {t:.6g} s is {self._last_t - t:.3g} s behind the "
                       "record before it (odometry older than the newest is not used)",
                       "backwards timestamp", skipped=False)
        self._last_t = t

    # -- records --------------------------------------------------------------------------------

    def _record(self, tokens: list[str], number: int) -> list[Event] | None:
        """Events of one record; [] for a record that is used but emits nothing (an anchor);
        None for a record type that is not used."""
        kind = tokens[0]
        if kind == "ODOM":
            return self._odom(tokens, number)
        if kind == "FLASER":
            return self._flaser(tokens, number)
        if kind == "ROBOTLASER1":
            return self._robotlaser1(tokens, number)
        if kind == "TRUEPOS":
            return self._truepos(tokens)
        if kind not in _KNOWN_RECORDS and not _looks_like_record_type(kind):
            raise _BadRecord("not a CARMEN record")
        return None

    def _odom(self, tokens: list[str], number: int) -> list[Event]:
        _need(tokens, 9, "ODOM")
        pose = _pose(tokens, 1)
        if not self.corrected:
            return [_odometry(self._time(tokens[7], pose), pose, number)]
        laser_pose, self._laser_pose = self._laser_pose, None
        if laser_pose is not None and np.array_equal(pose, laser_pose):
            # The re-anchoring line right after a laser record repeats its corrected pose. Its
            # timestamp is usually 0 but sometimes uninitialised memory (1e-42, 1.13, −0.96), so
            # it is recognised by the repeated pose and its timestamp is ignored.
            self._anchor = pose
            return []
        if _time(tokens[7]) == 0.0:
            self._anchor = pose  # a re-anchoring line: the reference pose, not motion
            return []
        if self._raw is None:
            raw = pose
        else:
            base = self._anchor if self._anchor is not None else self._prev_logged
            assert base is not None  # logged with the first raw pose
            raw = compose(self._raw, relative(base, pose))
        t = self._time(tokens[7], raw)
        self._raw, self._prev_logged, self._anchor = raw, pose, None
        self._raw_t = t
        return [_odometry(t, raw, number)]

    def _flaser(self, tokens: list[str], number: int) -> list[Event]:
        n = _count(tokens[1], "beam count")
        _need(tokens, 2 + n + 8, f"FLASER with {n} beams")
        ranges = self._valid_ranges(tokens[2 : 2 + n], number)
        pose = _pose(tokens, 2 + n)
        odom = _pose(tokens, 2 + n + 3)
        t = self._time(tokens[2 + n + 6], odom if self.laser_odometry else None)
        angles = self._angles.get(n)
        if angles is None:
            angles = self._angles[n] = flaser_angles(n, self.source.spacing)
        return self._laser_events(
            t, ranges, angles, self.source.no_return_range, pose, odom, number
        )

    def _valid_ranges(self, fields: list[str], number: int) -> NDArray[np.float64]:
        ranges, invalid = _ranges(fields)
        if invalid:
            self._warn(f"line {number}: {invalid} NaN or negative range(s) taken as no return",
                       "invalid range", skipped=False)
        return ranges

    def _robotlaser1(self, tokens: list[str], number: int) -> list[Event]:
        _need(tokens, 10, "ROBOTLASER1")
        start, fov, resolution, max_range = (_number(v) for v in tokens[2:6])
        n = _count(tokens[8], "beam count")
        _need(tokens, 10 + n, f"ROBOTLASER1 with {n} beams")
        m = _count(tokens[9 + n], "remission count")
        k = 10 + n + m  # first field after the remissions
        _need(tokens, k + 13, f"ROBOTLASER1 with {n} beams and {m} remissions")
        ranges = self._valid_ranges(tokens[9 : 9 + n], number)
        robot = _pose(tokens, k + 3)
        t = self._time(tokens[k + 11], robot if self.laser_odometry else None)
        angles = self._angles.get((start, resolution, n))
        if angles is None:
            angles = start + resolution * np.arange(n, dtype=np.float64)
            angles.flags.writeable = False
            self._angles[(start, resolution, n)] = angles
        if n > 1 and abs(angles[-1] - start - fov) > resolution + 1e-6:
            raise _BadRecord(f"field of view {fov:g} disagrees with {n} beams × {resolution:g}")
        limit = min(max_range, self.source.no_return_range) if max_range > 0 else None
        return self._laser_events(t, ranges, angles, limit, robot, robot, number)

    def _laser_events(
        self,
        t: float,
        ranges: NDArray[np.float64],
        angles: NDArray[np.float64],
        max_range: float | None,
        pose: NDArray[np.float64],
        odom: NDArray[np.float64],
        number: int,
    ) -> list[Event]:
        reference = tuple(pose.tolist()) if self.corrected else None
        self._laser_pose = pose
        hole: list[Event] = []
        if self.corrected and self._raw is not None and t > self._raw_t:
            # The ODOM line before a laser record normally carries its time; when the last one
            # is older, the motion from it to the laser record ends in the re-anchoring jump
            # and is lost with it: say so at the scan, so the filter knows before it matches.
            hole = [_odometry(t, self._raw, number, unmeasured=t - self._raw_t)]
            self._raw_t = t
        scan = Scan(
            t,
            ranges,
            angles,
            max_range=self.source.no_return_range if max_range is None else max_range,
            reference=reference,
            line=number,
        )
        if self.laser_odometry:
            return [_odometry(t, odom, None), scan]
        return [*hole, scan]

    def _truepos(self, tokens: list[str]) -> list[Event]:
        _need(tokens, 9, "TRUEPOS")
        pose = _pose(tokens, 1)
        return [Truth(self._time(tokens[7], None), *pose.tolist())]

    def _time(self, text: str, odometry: NDArray[np.float64] | None) -> float:
        """A record's time by the log's clock (:class:`StampClock`).
        ``odometry``: the record's odometry pose, when it carries the odometry; such a record
        advances a clock kept from the records' order, by a nominal interval, or by the time
        the robot needs to drive the increment since the last one at a nominal pace when that
        is longer (a driver that stalled for seconds reports all the motion at once)."""
        t = _time(text)
        if self._clock is StampClock.NEGATED:
            return -t
        if self._clock is not StampClock.ORDER:
            return t
        if odometry is not None:
            step = 1.0 / NOMINAL_ODOMETRY_RATE
            if self._clock_pose is not None:
                dx, dy, dth = relative(self._clock_pose, odometry)
                step = max(step, math.hypot(dx, dy) / NOMINAL_PACE[0],
                           abs(dth) / NOMINAL_PACE[1])
            self._clock_t += step
            self._clock_pose = odometry
        return self._clock_t


def _looks_like_record_type(token: str) -> bool:
    # Unknown CARMEN record types are upper-case identifiers (skipped silently); anything else is
    # a corrupt line (reported).
    return token.isascii() and token.isupper() and token.replace("_", "").isalnum()


def _need(tokens: list[str], count: int, what: str) -> None:
    if len(tokens) < count:
        raise _BadRecord(f"{what} needs {count} fields, found {len(tokens)} (truncated?)")


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _BadRecord(f"non-numeric field {text[:20]!r}") from None
    if not math.isfinite(value):
        raise _BadRecord(f"non-finite field {text!r}")
    return value


def _count(text: str, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise _BadRecord(f"{what} {text[:20]!r} is not an integer") from None
    if value < 0 or value > 100_000:
        raise _BadRecord(f"{what} {value} out of range")
    return value


def _time(text: str) -> float:
    """A timestamp: any finite number of seconds (negative stamps count from a later origin)."""
    return _number(text)


def _pose(tokens: list[str], start: int) -> NDArray[np.float64]:
    # plain floats first: this runs for every odometry line
    try:
        x, y, theta = (float(v) for v in tokens[start : start + 3])
    except ValueError:
        raise _BadRecord(f"non-numeric pose {' '.join(tokens[start : start + 3])[:40]!r}") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
        raise _BadRecord(f"non-finite pose {' '.join(tokens[start : start + 3])!r}")
    if max(abs(x), abs(y), abs(theta)) > MAX_POSE_COORDINATE:
        raise _BadRecord(f"pose {x:g} {y:g} {theta:g} beyond {MAX_POSE_COORDINATE:g}: "
                         "no robot's")
    return np.array((x, y, theta))


def _ranges(fields: list[str]) -> tuple[NDArray[np.float64], int]:
    """The ranges, with NaN and negative ones (invalid beams) made +inf, "no return", as the ROS
    reader does with NaN (REP 117); and how many there were."""
    try:
        ranges = parse_floats(fields)
    except ValueError:
        raise _BadRecord("non-numeric range") from None
    invalid = np.isnan(ranges) | (ranges < 0)
    ranges[invalid] = np.inf
    return ranges, int(invalid.sum())

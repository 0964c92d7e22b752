"""Streaming reader for CARMEN text logs (plain or gzip).

Records used: ``ODOM``, ``FLASER``, ``ROBOTLASER1`` and, when present, ``TRUEPOS`` (as ``Truth``).
Every other record type (``PARAM``, ``SYNC``, ``NEFF``, ``RLASER``, ``RAWLASER*``, …) and ``#``
comments are skipped silently. Field layouts:

* ``ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp``
* ``FLASER n r1 … rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname
  logger_timestamp`` — n beams over 180° from −90° (right) to +90° (left), see ``FlaserSpacing``.
* ``ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode
  n r1 … rn m rem1 … remm laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
  forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname logger_timestamp``
* ``TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname
  logger_timestamp``

``ipc_timestamp`` is the measurement time. Ranges at or beyond the no-return range (default 80 m,
``Scan.max_range``) mean "no return"; ranges are passed on unchanged.

**Corrected logs** (GMapping output, see ``data/SOURCES.md``): the laser record's pose is the
corrected map-frame pose and goes to ``Scan.reference`` only. After each laser record the
``ODOM`` chain is re-anchored: the next ``ODOM`` line (the *anchor*) repeats the corrected pose and
the following ``ODOM`` lines continue from it with the raw wheel motion. Anchors are recognised by
repeating the laser record's pose or by ``ipc_timestamp == 0`` (in the real logs their timestamp is
usually 0 but sometimes uninitialised memory such as 1e-42, 1.13 or −0.96). The reader rebuilds one
continuous raw odometry trajectory from the increments, ``prev⁻¹ ⊕ next`` without an anchor in
between and ``anchor⁻¹ ⊕ next`` with one, so the correction (the jump from ``prev`` to the anchor)
never reaches the odometry. The raw chain starts at the log's first ``ODOM`` pose. The ``ODOM``
line before a laser record normally carries the record's time; when it is older, the motion from
it to the record went into the re-anchoring jump and is lost: an ``Odometry`` at the record's time
repeats the raw pose with that interval as ``unmeasured``.

**Bad records** (truncated, non-numeric, NaN/inf pose or time, NaN/negative range, wrong count) are
skipped; each adds a message with its line number to ``ReadStats`` (``ReadStats.warn``) and the
first ``LOGGED_WARNINGS`` of them are also emitted on the ``logging`` logger ``fusion.io.carmen`` at
WARNING level, followed by one summary line if there were more (``logging`` rather than the
``warnings`` module because a corrupt log can produce thousands, and ``warnings`` would either
flood or de-duplicate them by source line). **Bad files** raise ``LogError``.

Timestamps that go backwards are passed on unchanged, in file order, and counted in
``ReadStats.backwards_timestamps``: ordering is the localizer's job.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from fusion.events import Event, ReadStats
from fusion.io.carmen_conventions import (
    NOMINAL_ODOMETRY_RATE,
    CarmenConventions,
    FlaserSpacing,
    StampClock,
)
from fusion.io.carmen_records import _KNOWN_RECORDS, _LASER_RECORDS, NO_RETURN_RANGE, CarmenParser
from fusion.io.errors import LogError
from fusion.io.textfile import open_text_log

log = logging.getLogger(__name__)

MIN_STAMPS_JUDGED = 20
"""records read ahead before a log's stamps are judged unusable"""

SNIFF_LINES = 20000
"""Lines read ahead to detect the log's conventions (corrected or raw, odometry source)."""


@dataclass
class CarmenLog:
    """A CARMEN log opened for streaming. Iterate it to get events in file order.

    ``stats`` is filled while iterating (``records`` counts the records used, re-anchoring ODOM
    lines included) (and reset in place when iterating again, so a reference
    taken before iterating stays valid). Iteration raises ``LogError`` if the file turns out to have
    no usable record at all.
    """

    path: Path
    conventions: CarmenConventions
    spacing: FlaserSpacing = FlaserSpacing.PI_OVER_N
    no_return_range: float = NO_RETURN_RANGE
    stats: ReadStats = field(default_factory=ReadStats)

    @property
    def corrected(self) -> bool:
        return self.conventions.corrected

    def __iter__(self) -> Iterator[Event]:
        _reset(self.stats)
        with open_text_log(self.path) as f:
            yield from CarmenParser(self).events(f)


def read_carmen(
    path: str | Path,
    raw_odometry: bool | None = None,
    *,
    spacing: FlaserSpacing | str = FlaserSpacing.PI_OVER_N,
    no_return_range: float = NO_RETURN_RANGE,
    laser_odometry: bool | None = None,
) -> CarmenLog:
    """Open a CARMEN log (plain or ``.gz``) for streaming; see the module docstring.

    ``raw_odometry``: True — the ``ODOM`` poses are raw odometry, used as they are; False — the log
    is *corrected* (ODOM re-anchored on reference poses, laser poses are references); None —
    detect it (corrected when an ``ODOM`` line with timestamp 0 follows a laser record).
    ``laser_odometry``: take odometry from the laser records (old logs without ``ODOM``); None —
    when the log has no ``ODOM`` record. Never done for corrected logs (their laser-line odometry
    is the corrected pose). ``spacing``: FLASER beam layout. ``no_return_range``: ranges at or above
    it mean no return (``Scan.max_range``).

    Raises ``LogError`` when the file is missing, binary, empty or has no CARMEN record in its
    first lines; iterating raises it when no record at all is usable.
    """
    path = Path(path)
    detected = _sniff(path)
    corrected = detected.corrected if raw_odometry is None else not raw_odometry
    if laser_odometry is None:
        laser_odometry = detected.laser_odometry
    conventions = CarmenConventions(
        corrected=corrected, laser_odometry=laser_odometry and not corrected,
        clock=detected.clock,
    )
    if conventions.clock is StampClock.NEGATED:
        log.warning("%s: its timestamps run backwards throughout (%s): read negated, which keeps "
                    "their intervals", path, detected.why)
    elif conventions.clock is StampClock.ORDER:
        log.warning("%s: its timestamps cannot order its records (%s): the records' order is "
                    "used instead, at a nominal %g odometry records a second", path,
                    detected.why, NOMINAL_ODOMETRY_RATE)
    return CarmenLog(path, conventions, FlaserSpacing(spacing), float(no_return_range))


def _reset(stats: ReadStats) -> None:
    stats.records = stats.skipped = stats.backwards_timestamps = stats.stray_timestamps = 0
    stats.warnings.clear()
    stats.kinds.clear()


@dataclass(frozen=True, slots=True)
class _Sniffed:
    corrected: bool
    laser_odometry: bool
    clock: StampClock
    why: str


def _judge_stamps(stamps: list[float]) -> tuple[StampClock, str]:
    """Can these stamps (the records' read ahead, re-anchoring zeros left out) order a log?"""
    if len(stamps) < MIN_STAMPS_JUDGED:
        return StampClock.STAMPS, ""
    distinct = sorted(set(stamps))
    if len(distinct) <= 2:
        shown = " and ".join(f"{v:g}" for v in distinct)
        return StampClock.ORDER, f"its first {len(stamps)} records carry only {shown}"
    steps = [b - a for a, b in itertools.pairwise(stamps) if b != a]
    if steps and sum(d < 0 for d in steps) == len(steps):
        return StampClock.NEGATED, (f"its first {len(stamps)} records run from {stamps[0]:g} to "
                                    f"{stamps[-1]:g} s")
    return StampClock.STAMPS, ""


def _sniff(path: Path) -> _Sniffed:
    """Read the first lines to tell CARMEN from other files and detect the conventions."""
    odom = laser = anchors = known = nonblank = stamped = 0
    stamps: list[float] = []
    lines_since_laser = None
    with open_text_log(path) as f:
        for number, line in enumerate(f, start=1):
            if number > SNIFF_LINES or laser >= 10:
                break
            tokens = line.split(maxsplit=1)
            if not tokens:
                continue
            nonblank += 1
            if tokens[0].startswith("#"):
                continue
            kind = tokens[0]
            if kind in _KNOWN_RECORDS:
                known += 1
            if kind in _LASER_RECORDS or kind == "ODOM":
                stamp = _stamp_of(line)  # every record ends ipc_timestamp ipc_hostname logger_t
                anchor = kind == "ODOM" and lines_since_laser is not None and lines_since_laser < 3
                if stamp is not None and not (anchor and stamp == 0.0 and stamped):
                    stamps.append(stamp)
            if kind in _LASER_RECORDS:
                laser += 1
                lines_since_laser = 0
                continue
            if lines_since_laser is not None:
                lines_since_laser += 1
            if kind == "ODOM":
                odom += 1
                stamped += _odom_time(line) not in (None, 0.0)
                # The re-anchoring line of a corrected log: timestamp 0 right after a laser record.
                if (
                    lines_since_laser is not None
                    and lines_since_laser <= 3
                    and _odom_time(line) == 0
                ):
                    anchors += 1
    if nonblank == 0:
        raise LogError(path, "empty file (no records)")
    if known == 0:
        raise LogError(path, "not a CARMEN log (no ODOM/FLASER/ROBOTLASER1/PARAM record found)")
    # a log whose stamps are all zero has no anchors, only unstamped readings
    clock, why = _judge_stamps(stamps)
    return _Sniffed(corrected=anchors > 0 and stamped > 0, laser_odometry=odom == 0 and laser > 0,
                    clock=clock, why=why)


def _stamp_of(line: str) -> float | None:
    tokens = line.split()
    try:
        value = float(tokens[-3])
    except (IndexError, ValueError):
        return None
    return value if value == value and abs(value) != float("inf") else None


def _odom_time(line: str) -> float | None:
    tokens = line.split()
    try:
        return float(tokens[7])
    except (IndexError, ValueError):
        return None


# -- field parsing -------------------------------------------------------------------------------



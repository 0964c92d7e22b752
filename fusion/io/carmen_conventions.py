"""How a CARMEN log is to be read: its laser's beam spacing, where its records' times come
from, what it holds (corrected or raw odometry), and what a pass over its records needs of it
(:mod:`fusion.io.carmen` detects them; :mod:`fusion.io.carmen_records` applies them).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fusion.events import ReadStats


class FlaserSpacing(StrEnum):
    """Angular layout of the n beams of an ``FLASER`` record over its 180° field of view.

    ``ENDPOINTS``: spacing π/(n−1), beams at ``linspace(−π/2, π/2, n)`` (first beam at −90°, last at
    +90°; the Intel ``.mat`` uses this, ``beam_start = −π/2``, ``beam_end = +π/2``).
    ``PI_OVER_N``: spacing π/n, beams at −π/2 + i·π/n (first beam at −90°, last one step short).

    On the three corrected logs, endpoints projected from the reference poses occupy 1–9 % fewer
    5 cm cells with ``PI_OVER_N`` than with ``ENDPOINTS`` (a sharper map: the convention of the
    tool that corrected them), also fewer than ``ENDPOINTS`` shifted by −½ step or ``PI_OVER_N``
    shifted by ±¼ or −½ step. ``PI_OVER_N`` is therefore the default; logs that state their layout
    (``ROBOTLASER1``, the simulator's) carry it explicitly.
    """

    ENDPOINTS = "pi/(n-1)"
    PI_OVER_N = "pi/n"


def flaser_angles(n: int, spacing: FlaserSpacing = FlaserSpacing.PI_OVER_N) -> NDArray[np.float64]:
    """Beam angles (robot frame, radians) of an n-beam ``FLASER`` record."""
    if spacing == FlaserSpacing.ENDPOINTS:
        angles = np.linspace(-np.pi / 2, np.pi / 2, n)
    else:
        angles = -np.pi / 2 + np.arange(n, dtype=np.float64) * (np.pi / n)
    angles.flags.writeable = False  # shared between all scans with the same n
    return angles


class StampClock(StrEnum):
    """Where a record's time comes from."""

    STAMPS = "stamps"
    """its ``ipc_timestamp``, as it is"""
    NEGATED = "negated"
    """its ``ipc_timestamp`` negated: a log whose stamps run backwards throughout (written with
    the sign flipped) still has the right intervals"""
    ORDER = "order"
    """the records' order, at :data:`NOMINAL_ODOMETRY_RATE` (or the time its increment takes at
    :data:`NOMINAL_PACE`, when longer): a log whose stamps cannot order its records (all zero,
    or every record one or two stamps, as ``%g`` prints Unix time)"""


NOMINAL_ODOMETRY_RATE = 5.0
"""Hz: odometry records a second assumed when a log's stamps cannot be used; each laser record
is taken at its odometry record's time. Robots publish odometry at 5–50 Hz: a clock that runs
slow only makes the motion look slower than it was, which nothing rejects (the motion model is
per metre and radian), where one that runs fast makes real motion look like jumps beyond
``filter.motion.max_speed``."""


NOMINAL_PACE = (0.5, 1.0)
"""m/s and rad/s: a robot indoors drives no faster, on the clock kept from the records' order;
a record whose increment is larger is taken as that much later."""


@dataclass(frozen=True, slots=True)
class CarmenConventions:
    """How a log is to be interpreted; detected from its first lines unless given."""

    corrected: bool
    """ODOM lines are re-anchored on corrected poses; laser poses are references."""
    laser_odometry: bool
    """No ODOM records: odometry comes from the laser records' ``odom_x odom_y odom_theta``."""
    clock: StampClock = StampClock.STAMPS
    """How the records' times are read (:class:`StampClock`)."""


class RecordSource(Protocol):
    """What a pass over a log's records reads of the log (:class:`fusion.io.carmen.CarmenLog`)."""

    @property
    def path(self) -> Path: ...
    @property
    def conventions(self) -> CarmenConventions: ...
    @property
    def spacing(self) -> FlaserSpacing: ...
    @property
    def no_return_range(self) -> float: ...
    @property
    def stats(self) -> ReadStats: ...

"""Time-stamped inputs of the localizer: what readers and the simulator produce.

Times are float seconds of the data's own clock. Odometry poses are in the odometry's own
(arbitrary) frame; scans and point sets are in the robot (``base``) frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

MAX_POSE_COORDINATE = 1.0e6
"""A pose farther than this from its frame's origin (m), or turned further (rad: 160,000
turns), is no robot's: readers skip such a record, the Localizer drops such a reading."""


@dataclass(frozen=True, slots=True)
class Odometry:
    """A wheel-odometry pose (x, y, θ) in the odometry frame at time ``t`` (``line``: the
    record's line number in its file, for messages).

    ``unmeasured``: seconds just before ``t`` whose motion the increment from the previous
    reading does not contain (a hole in a log the reader could not bridge); the robot may have
    moved anywhere within its speed limits then, and the filter's prediction says so."""

    t: float
    x: float
    y: float
    theta: float
    line: int | None = None
    unmeasured: float = 0.0


@dataclass(frozen=True, slots=True)
class Scan:
    """A range scan: ``ranges[i]`` along ``angles[i]`` (robot frame, radians).

    ``max_range``: returns at or beyond it mean "no return". ``reference``: the pose a corrected
    log attached to this scan (map frame), for evaluation only — never an input to the filter.
    ``line``: the record's line number in its file, for messages. ``stamp``: the record's own
    timestamp when the reader had to replace ``t`` by an in-order time (a log whose records are in
    order but some stamps are not); outputs are written at it, so they line up with references.
    """

    t: float
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float = np.inf
    sensor: str = "laser"
    reference: tuple[float, float, float] | None = None
    line: int | None = None
    stamp: float | None = None


@dataclass(frozen=True, slots=True)
class PointSet:
    """Points already triangulated into the robot frame (e.g. a camera's floor lines).

    ``t`` is when the data was taken; ``arrival`` is when it reached the localizer (≥ t) — late
    measurements are applied at ``t`` by the filter's history.
    """

    t: float
    points: NDArray[np.float64]
    sensor: str = "camera"
    arrival: float | None = None
    line: int | None = None


@dataclass(frozen=True, slots=True)
class Truth:
    """Ground-truth pose (map frame), known in simulation."""

    t: float
    x: float
    y: float
    theta: float


@dataclass(frozen=True, slots=True)
class Landmark:
    """A recognised map landmark (e.g. a goal by its colour) seen at ``bearing`` (robot frame)."""

    t: float
    label: str
    bearing: float
    sensor: str = "camera"


Event = Odometry | Scan | PointSet | Truth | Landmark


@dataclass
class ReadStats:
    """What a reader saw and skipped, for warnings and ``metrics.json``.

    ``warnings`` keeps the first messages; ``kinds`` counts every warning by kind with the first
    message of each, so a kind that comes late in a long log is never hidden by a cap."""

    records: int = 0
    skipped: int = 0
    backwards_timestamps: int = 0
    stray_timestamps: int = 0
    warnings: list[str] = field(default_factory=list)
    kinds: dict[str, list] = field(default_factory=dict)  # kind → [count, first message]

    def warn(self, message: str, keep: int = 50, kind: str = "bad record",
             skipped: bool = True) -> bool:
        """Count a warning (a skipped record, unless ``skipped`` is False: a record used with a
        repair); True when it is the first of its kind."""
        self.skipped += skipped
        if len(self.warnings) < keep:
            self.warnings.append(message)
        entry = self.kinds.setdefault(kind, [0, message])
        entry[0] += 1
        return entry[0] == 1

    def by_kind(self) -> dict[str, dict[str, object]]:
        return {kind: {"count": count, "first": first}
                for kind, (count, first) in self.kinds.items()}

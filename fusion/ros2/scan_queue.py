"""The node's scans, held until the odometry reaches them (:class:`ScanQueue`).

A scan is localized once an odometry reading at or after its stamp is in, so that the filter
predicts to the scan before the scan corrects it (as AMCL waits for the odom → base transform);
at most ``wait`` seconds, so that a robot without odometry still localizes, with that much
latency. Scans leave in their arrival order; a queue that is full drops its oldest (the node is
behind), and counts it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

from fusion.events import Scan

PENDING_SCANS = 10
"""Scans held for odometry at most; beyond, the oldest is dropped (the node is behind)."""


@dataclass
class Pending:
    scan: Scan
    sensor: str
    arrived: float  # monotonic s


class ScanQueue:
    """Scans waiting for the odometry, oldest first."""

    def __init__(self, size: int = PENDING_SCANS) -> None:
        self.size = size
        self.dropped = 0
        self._held: deque[Pending] = deque()

    def clear(self) -> None:
        """Forget the scans held (the count of those dropped is kept)."""
        self._held.clear()

    def push(self, scan: Scan, sensor: str, now: float) -> None:
        """A scan arrived at ``now`` (monotonic s); the oldest is dropped if the queue is full."""
        if len(self._held) == self.size:
            self._held.popleft()
            self.dropped += 1
        self._held.append(Pending(scan, sensor, now))

    def reached(self, odometry_time: float) -> Iterator[Pending]:
        """The scans, oldest first, up to the first the odometry has not reached yet."""
        while self._held and self._held[0].scan.t <= odometry_time:
            yield self._held.popleft()

    def overdue(self, now: float, wait: float) -> Iterator[Pending]:
        """The scans, oldest first, that have waited ``wait`` seconds or more."""
        while self._held and now - self._held[0].arrived >= wait:
            yield self._held.popleft()

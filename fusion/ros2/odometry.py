"""The node's recent odometry: where ``map → odom`` is placed at a scan's time, and the reading a
new Localizer starts from."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import NDArray


class OdometryBuffer:
    """The newest ``kept`` odometry readings (t, x, y, θ), in arrival order."""

    def __init__(self, kept: int) -> None:
        self._readings: deque[tuple[float, float, float, float]] = deque(maxlen=kept)

    def append(self, t: float, x: float, y: float, theta: float) -> None:
        self._readings.append((t, x, y, theta))

    @property
    def newest_time(self) -> float:
        """The newest reading's stamp; −∞ before any."""
        return self._readings[-1][0] if self._readings else -math.inf

    def last_before(self, t: float) -> tuple[float, float, float, float] | None:
        """The newest reading at or before ``t``."""
        return next((r for r in reversed(self._readings) if r[0] <= t), None)

    def at(self, t: float) -> NDArray[np.float64] | None:
        """The odometry pose at ``t``, interpolated between the readings around it (the last
        one when ``t`` is past it, the first when before it)."""
        readings = self._readings
        if not readings:
            return None
        # the first reading at or after t; scans come shortly before the newest reading, so the
        # search starts from the end
        k = len(readings)
        while k > 0 and readings[k - 1][0] >= t:
            k -= 1
        if k == 0 or k == len(readings):
            return np.array(readings[min(k, len(readings) - 1)][1:])
        a, b = np.array(readings[k - 1]), np.array(readings[k])
        w = (t - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 1.0
        pose = a[1:] + w * (b[1:] - a[1:])
        pose[2] = math.remainder(a[3] + w * math.remainder(b[3] - a[3], math.tau), math.tau)
        return pose

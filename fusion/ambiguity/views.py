"""The views collected for a global match (the paper's strategy (ii): several views, related by
odometry, matched as one set), and when to try one."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.settings.ambiguity import AmbiguityConfig
from houghloc.geometry import relative, transform_points


@dataclass
class View:
    odom: NDArray[np.float64]
    points: NDArray[np.float64]


@dataclass
class Views:
    """The last ``max_views`` views, each ``view_spacing`` (or ``view_spacing_deg``) from the
    previous one, and the count of global matches that found nothing (``failures``)."""

    config: AmbiguityConfig
    views: deque[View] = field(default_factory=deque)
    failures: int = 0
    since_attempt: int = 0
    first_match_views: int | None = None
    """views before the first match, when fewer than ``min_views`` (None: ``min_views``)"""

    def __len__(self) -> int:
        return len(self.views)

    @property
    def latest_odom(self) -> NDArray[np.float64]:
        return self.views[-1].odom

    def clear(self) -> None:
        self.views.clear()

    def restart(self) -> None:
        """Tracking was given up: collect from scratch, with no failure counted (and the first
        match after ``min_views`` again)."""
        self.views.clear()
        self.failures = 0
        self.since_attempt = 0
        self.first_match_views = None

    def add(self, odom: NDArray[np.float64], points: NDArray[np.float64]) -> bool:
        """Keep this view if the robot moved since the last one (a robot standing still adds
        no evidence); False when it did not."""
        if self.views and not self._moved_since_last(odom):
            return False
        self.views.append(View(odom, points))
        while len(self.views) > self.config.max_views:
            self.views.popleft()
        self.since_attempt += 1
        return True

    def due(self, following: bool) -> bool:
        """Is a global match due: ``min_views`` collected and ``retry_every`` views since the
        last attempt (more once lost: a match costs tens of scans, and the same views rarely
        give another answer; at least that while ``following`` hypotheses are weighed)?"""
        backoff = max(0, self.failures - self.config.failures_until_lost + 1)
        wait = self.config.retry_every * 2 ** min(backoff, 2) if self.failures else 0
        if following:  # followed poses are being weighed: new ones now and then
            wait = max(wait, self.config.retry_every)
        least = self.config.min_views
        if self.first_match_views is not None:
            least, wait = min(least, self.first_match_views), 0
        if len(self.views) < least or self.since_attempt < wait:
            return False
        self.since_attempt = 0
        self.first_match_views = None
        return True

    def _moved_since_last(self, odom: NDArray) -> bool:
        step = relative(self.views[-1].odom, odom)
        return (math.hypot(step[0], step[1]) >= self.config.view_spacing
                or abs(step[2]) >= math.radians(self.config.view_spacing_deg))

    def points(self) -> NDArray[np.float64]:
        """All views' points in the latest view's robot frame, by odometry (at most
        ``max_points``, evenly subsampled)."""
        latest = self.views[-1].odom
        chunks = [transform_points(relative(latest, v.odom), v.points) for v in self.views]
        pts = np.concatenate(chunks) if chunks else np.empty((0, 2))
        if len(pts) > self.config.max_points:
            pts = pts[np.linspace(0, len(pts) - 1, self.config.max_points).astype(int)]
        return pts

"""Tied poses, the rules-based way (``hypotheses: null``): when a global match leaves several
poses within ``decisive_margin`` (a symmetric map), each is carried by odometry, corrected by
the scans it fixes and scored by the fraction of each scan's points on walls there; a pose is
taken when it leads (``tie_lead`` over ``tie_window`` scans, or ``tie_steady_lead`` on every
one), or when the last trusted pose makes the nearest far likelier (``kidnap_prior_*``). The
default follows each pose with its own filter instead (:mod:`fusion.hypotheses`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.settings.ambiguity import AmbiguityConfig
from houghloc import HoughConfig, Hypothesis, SegmentMap, localize_scan, observe_lines
from houghloc.geometry import compose, relative, wrap_scalar
from houghloc.localize import clean_points
from houghloc.matching import gate_threshold


@dataclass(frozen=True, slots=True)
class TieBroken:
    """The pose a tie ends with, and why (``by_distance``: the last trusted pose chose it)."""

    pose: NDArray[np.float64]
    reason: str
    by_distance: bool = False


@dataclass
class Ties:
    """The tied poses being followed (none: no tie)."""

    config: AmbiguityConfig
    poses: list[NDArray[np.float64]] = field(default_factory=list)  # at ``odom``
    odom: NDArray[np.float64] | None = None
    fits: list[deque] = field(default_factory=list)  # per pose: recent fractions on walls
    slid: bool = False  # found by sliding along a corridor

    def __bool__(self) -> bool:
        return bool(self.poses)

    def start(self, tied: list[Hypothesis], odom: NDArray[np.float64]) -> None:
        """Follow each of ``tied``'s poses from the view at ``odom``."""
        self.poses = [np.asarray(h.pose, float) for h in tied]
        self.odom = odom.copy()
        self.fits = [deque(maxlen=self.config.tie_window) for _ in tied]
        self.slid = any(getattr(h, "slid", False) for h in tied)

    def clear(self) -> None:
        self.poses, self.fits = [], []

    def carried(self, odom: NDArray) -> list[NDArray[np.float64]]:
        """The tied poses moved by the odometry since they were found."""
        if not self.poses or self.odom is None:
            return []
        step = relative(self.odom, odom)
        return [compose(h, step) for h in self.poses]

    def follow(self, odom: NDArray, points: NDArray, kinds: tuple[str, ...],
               hough: HoughConfig, map: SegmentMap, fit: ScanFit,
               last_trusted: tuple[NDArray, NDArray] | None) -> TieBroken | None:
        """Carry each tied pose by odometry, correct it with this scan when the scan fixes it,
        and record the fraction of the scan's points that lie on the map's walls there. A pose
        that leads all others by ``tie_lead`` over a full window is the pose; one that trails the
        best by twice that is dropped."""
        prior = np.diag([0.1**2, 0.1**2, math.radians(3.0) ** 2])
        observed = observe_lines(clean_points(points)[0], hough)  # one scan, every tied pose
        moved = []
        for pose, fits in zip(self.carried(odom), self.fits, strict=True):
            fix = localize_scan(points, map, pose, hough, pose_cov=prior, observed=observed)
            if fix.ok:
                pose = fix.pose
            fits.append(fit.fraction(pose, points, kinds))
            moved.append(pose)
        self.poses, self.odom = moved, odom.copy()
        means = np.array([np.mean(f) for f in self.fits])
        best = int(np.argmax(means))
        keep = means >= means[best] - 2 * self.config.tie_lead
        if not keep.all():
            self.poses = [h for h, k in zip(self.poses, keep, strict=True) if k]
            self.fits = [f for f, k in zip(self.fits, keep, strict=True) if k]
            means = means[keep]
            best = int(np.argmax(means))
        full = all(len(f) == self.config.tie_window for f in self.fits)
        if not full:
            return None
        others = np.delete(means, best)
        rival = others.max() if len(others) else 0.0
        chosen, by_distance, why = None, False, ""
        if len(others) == 0 or means[best] - rival >= self.config.tie_lead:
            chosen = best
        elif self._leads_every_scan(best) and fit.like_tracking(means[best]):
            chosen = best
        else:
            nearest, why = self._nearest_to(last_trusted, odom)
            if nearest is not None and means[nearest] >= means[best] - self.config.tie_lead:
                chosen, by_distance = nearest, True
        if chosen is None:
            return None
        pose = self.poses[chosen]
        self.clear()
        if by_distance:
            return TieBroken(pose, f"{why}; {means[chosen]:.2f} of the points on walls", True)
        return TieBroken(pose, f"tie broken: {means[best]:.2f} of the points on walls at one "
                               f"pose, {rival:.2f} at the next best")

    def _leads_every_scan(self, best: int) -> bool:
        """Does tied pose ``best`` fit better than every other on each scan of the window, by
        ``tie_steady_lead`` on average? A few points more on walls in every one of ten scans
        (a wall glimpsed through a door at one pose only) is evidence, however small; a lead
        that comes and goes is clutter."""
        if self.config.tie_steady_lead is None:
            return False
        fits = np.array([list(f) for f in self.fits])  # hypotheses × window
        lead = fits[best] - np.delete(fits, best, axis=0).max(axis=0)
        return bool((lead > 0).all() and lead.mean() >= self.config.tie_steady_lead)

    def _nearest_to(self, last_trusted: tuple[NDArray, NDArray] | None, odom: NDArray
                    ) -> tuple[int | None, str]:
        """Of the followed tied poses, the one nearest the last trusted pose (``last_trusted``:
        pose and odometry then) carried by odometry, when a displacement prior
        N(0, ``kidnap_prior_sigma``²) makes it ``kidnap_prior_odds`` times as likely as every
        rival: the views cannot tell them apart, and a robot that was pushed or carried is more
        plausibly near where it was than across the building. 3 m against 6 m from it (the next
        look-alike room) is 30 : 1 with σ = 2 m; 3 m against 4 m is 3 : 1, a coin toss left to
        the evidence. None without a trusted pose (global start), when the poses were found by
        sliding along a corridor (the right one may have been dropped; the nearest would then be
        wrong and look right for as long as the corridor lasts), and when the pose it would
        replace came from this rule itself (the manager then forgets the trusted pose): a pose
        chosen by distance alone is no evidence for the next choice."""
        sigma = self.config.kidnap_prior_sigma
        if sigma is None or last_trusted is None or self.slid or len(self.poses) < 2:
            return None, ""
        pose, trusted_odom = last_trusted
        moved = compose(pose, relative(trusted_odom, odom))
        dist = np.array([math.hypot(*(h[:2] - moved[:2])) for h in self.poses])
        order = np.argsort(dist)
        nearest, next_nearest = dist[order[0]], dist[order[1]]
        log_odds = (next_nearest**2 - nearest**2) / (2 * sigma**2)
        if log_odds < math.log(self.config.kidnap_prior_odds):
            return None, ""
        return int(order[0]), (f"tie broken by the last trusted pose: {nearest:.1f} m from it, "
                               f"the next {next_nearest:.1f} m")

    def landmark(self, odom: NDArray, position: tuple[float, float], bearing: float,
                 tolerance: float) -> list[NDArray[np.float64]] | None:
        """The tied poses that would see a landmark at ``position`` at ``bearing`` (within
        ``tolerance``), kept; None when every pose would (nothing learnt)."""
        poses = self.carried(odom)
        seen = [abs(wrap_scalar(math.atan2(position[1] - h[1], position[0] - h[0]) - h[2]
                                - bearing)) <= tolerance for h in poses]
        if all(seen):
            return None
        self.poses = [h for h, s in zip(poses, seen, strict=True) if s]
        self.fits = [f for f, s in zip(self.fits, seen, strict=True) if s]
        self.odom = np.asarray(odom, float).copy()
        return self.poses


def break_with_prior(tied: list[Hypothesis], prior: tuple[NDArray, NDArray, NDArray] | None,
                     odom: NDArray) -> Hypothesis | None:
    """Of tied hypotheses, the one alone inside the gate of the tracker's belief when it was
    abandoned (``prior``: pose, covariance, odometry then; carried by odometry to ``odom``, its
    covariance grown generously): a symmetric map only fools a robot without memory. None when
    there is no belief or it doesn't single one out (after a kidnap, the old belief holds none
    of them)."""
    if prior is None:
        return None
    pose, cov, prior_odom = prior
    moved = compose(pose, relative(prior_odom, odom))
    spread = cov + np.diag([0.5**2, 0.5**2, math.radians(15.0) ** 2])  # odometry since
    inside = []
    for h in tied:
        e = np.asarray(h.pose, float) - moved
        e[2] = wrap_scalar(e[2])
        if e @ np.linalg.solve(spread, e) <= gate_threshold(0.999, 3):
            inside.append(h)
    return inside[0] if len(inside) == 1 else None

"""While tracking: is it time to give tracking up?

:class:`TrackingWatch` keeps the evidence against the belief, from the scans without a usable
fix (whether a fix is usable is decided in :mod:`fusion.decision`); the state machine
(:mod:`fusion.ambiguity.manager`) acts on what it says. :class:`Belief` is what tracking last
believed: global localization weighs its poses against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.ambiguity.spacing import (
    SAME_WALL_GAP,
    closest_parallel_spacing,
    visible_parallel_spacing,
)
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.status import ScanStatus
from houghloc import SegmentMap
from houghloc.geometry import compose, relative


@dataclass
class Belief:
    """What tracking last believed, kept for when it is given up."""

    prior: tuple[NDArray, NDArray, NDArray] | None = None  # pose, cov, odometry: the last scan
    last_trusted: tuple[NDArray, NDArray] | None = None  # pose, odometry at the last used fix

    def displacement_prior(self, pose: NDArray, odom: NDArray, config: AmbiguityConfig
                           ) -> float:
        """How plausible a pose (where the odometry read ``odom``) is from where tracking
        last was, carried by odometry: N(d; 0, ``kidnap_prior_sigma``²) in the distance d, over
        a floor of ``kidnap_probability`` for a robot carried anywhere; 1 without a belief
        (global start)."""
        sigma = config.kidnap_prior_sigma
        if sigma is None or self.prior is None:
            return 1.0
        belief, _, belief_odom = self.prior
        moved = compose(belief, relative(belief_odom, odom))
        d = math.hypot(pose[0] - moved[0], pose[1] - moved[1])
        return max(math.exp(-0.5 * (d / sigma) ** 2), config.kidnap_probability)

    def moved_since_trusted(self, odom: NDArray | None) -> float | None:
        """The odometry's distance since the last used fix (None without one)."""
        if odom is None or self.last_trusted is None:
            return None
        return math.hypot(*(np.asarray(odom, float)[:2] - self.last_trusted[1][:2]))


class TrackingWatch:
    """The evidence for giving tracking up: scans without a usable fix that contradict the
    belief, or a covariance too large for the lines in view."""

    def __init__(self, map: SegmentMap, config: AmbiguityConfig, fit: ScanFit,
                 belief: Belief) -> None:
        self.config = config
        self.fit = fit
        self.belief = belief
        self._line_spacing = closest_parallel_spacing(map)
        self._without_fix = 0  # scans without a usable fix since the last one ...
        self._seen_through = 0.0  # ... and the scans' worth of their points seen through walls
        self.evidence_against = 0.0
        """The share of the evidence that gives tracking up gathered since the last usable
        fix, in [0, 1): what the integrity output holds against the belief while tracking."""

    def give_up_reason(self, status: ScanStatus, cov: NDArray, pose: NDArray | None,
                       odom: NDArray | None, in_view: tuple[NDArray, NDArray] | None,
                       guess_fit: float | None, points: NDArray | None,
                       kinds: tuple[str, ...]) -> str | None:
        """After a tracking scan ended with ``status``: why tracking must be given up, or None.

        The belief (``pose``, ``cov`` where the odometry read ``odom``) is kept first. Scans
        without a usable fix count as evidence unless their ``guess_fit`` (the fraction of points
        on walls at the guess) holds up (``hold_fit_ratio``); tracking is given up when they
        have seen ``through_wall_scans`` scans' worth of their ``points`` through the map's
        walls from the belief, or, for a sensor that does not see walls (no ``"wall"`` in
        ``kinds``) or with ``through_wall_scans`` None, after ``max_scans_without_fix`` of
        them. Or when the position's σ passes ``max_position_sigma_fraction`` of the closest
        parallel lines in view (``in_view``: the references' robot-frame (θ, ρ); the map's
        closest pair if not given)."""
        if pose is not None and odom is not None:
            self.belief.prior = (np.array(pose, float), np.array(cov, float),
                                 np.array(odom, float))
            if status == ScanStatus.ACCEPTED:
                self.belief.last_trusted = (np.array(pose, float), np.array(odom, float))
        through_walls = (self.config.through_wall_scans is not None and "wall" in kinds
                         and pose is not None and points is not None)
        if status in (ScanStatus.RE_SEARCHED, ScanStatus.ACCEPTED):
            self.fix_found()
            if status == ScanStatus.ACCEPTED and guess_fit is not None:
                self.fit.accepted(guess_fit)
                if pose is not None and points is not None:
                    self.fit.learn_glass(pose, points, odom, kinds)
        elif not self.fit.guess_holds(guess_fit):
            self._without_fix += 1
            if through_walls:
                assert pose is not None and points is not None
                self._seen_through += self.fit.seen_through(pose, points, kinds)
        if through_walls:
            assert self.config.through_wall_scans is not None
            self.evidence_against = min(1.0, self._seen_through / self.config.through_wall_scans)
            if self._seen_through >= self.config.through_wall_scans:
                return (f"{self._without_fix} scans without a usable fix saw "
                        f"{self._seen_through:.1f} scans' worth of points through the map's "
                        f"walls (last: {status})")
        else:
            self.evidence_against = min(1.0, self._without_fix / self.config.max_scans_without_fix)
            if self._without_fix >= self.config.max_scans_without_fix:
                return f"{self._without_fix} scans without a usable fix (last: {status})"
        return self._too_uncertain(cov, in_view)

    def _too_uncertain(self, cov: NDArray, in_view: tuple[NDArray, NDArray] | None
                       ) -> str | None:
        """Why the position's σ is too large for the parallel lines in view, or None."""
        fraction = self.config.max_position_sigma_fraction
        if fraction is None:
            return None
        sigma = math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2])[-1], 0.0))
        if in_view is None:
            spacing = self._line_spacing
        elif sigma > fraction * SAME_WALL_GAP:
            spacing = visible_parallel_spacing(*in_view)
        else:  # no spacing in view can be smaller: the usual case, without the K×K comparison
            return None
        if sigma > fraction * spacing:
            return (f"position σ {sigma:.2f} m exceeds {fraction:g} of the {spacing:.2f} m "
                    f"between parallel lines in view")
        return None

    def fix_found(self) -> None:
        """A usable fix, or a new pose: the evidence for giving tracking up starts again."""
        self._without_fix, self._seen_through, self.evidence_against = 0, 0.0, 0.0

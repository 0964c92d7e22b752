"""While not tracking: the paper's strategy (ii) — views accumulated, the whole set of lines
matched to the whole map, its poses followed until one is taken (:class:`Relocalization`).

Each pose of a global match gets its own filter (:class:`HypothesisBank`), tracking's last
belief among them, and the scans decide between them. Transitions go through the state
machine's ``go`` (:mod:`fusion.ambiguity.manager`).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.ambiguity.tracking import Belief
from fusion.ambiguity.views import Views
from fusion.hypotheses import BankVerdict, HypothesisBank, MakeTracker
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.status import State
from fusion.visualize import Logger
from houghloc import GlobalResult, HoughConfig, Hypothesis, SegmentMap, observe_lines
from houghloc.geometry import compose, relative
from houghloc.global_match import advance, global_match_stages
from houghloc.match_result import Stages


@dataclass
class Decision:
    """What the localizer must do after a scan: nothing, or re-initialise the filter."""

    reset_pose: NDArray[np.float64] | None = None
    reset_cov: NDArray[np.float64] | None = None
    result: GlobalResult | None = None


@dataclass(frozen=True, slots=True)
class PendingMatch:
    """A global match under way (:data:`Stages`) and the odometry of the views it
    matches."""

    stages: Stages
    odom: NDArray[np.float64]


def reinit_floor(config: AmbiguityConfig) -> NDArray[np.float64]:
    """The least covariance the filter is re-initialised with (``reinit_sigma_*``)."""
    return np.diag([config.reinit_sigma_xy**2] * 2
                   + [math.radians(config.reinit_sigma_theta_deg) ** 2])


GoTo = Callable[[float, State, str], None]  # the state machine's transition, with its reason


class Relocalization:
    """Views, the global match under way, and the followed poses."""

    def __init__(self, map: SegmentMap, config: AmbiguityConfig, fit: ScanFit, belief: Belief,
                 counts: Counter, go: GoTo, logger: Logger | None = None,
                 make_tracker: MakeTracker | None = None) -> None:
        self.map = map
        self.config = config
        self.fit = fit
        self.belief = belief
        self.counts = counts
        self.go = go
        self.logger = logger
        self.make_tracker = make_tracker
        self.views = Views(config)
        self.bank: HypothesisBank | None = None
        self.match: PendingMatch | None = None

    def start(self, t: float) -> None:
        """Tracking given up: views start again, and its belief becomes the first followed
        hypothesis. Scans that did not fit for a while are evidence against it, not proof: if
        it keeps fitting it is taken back within a few scans, and a wrong one falls behind the
        poses global matching proposes (no rule decides between giving up too early and too
        late)."""
        self.views.restart()
        self.bank = None
        if self.make_tracker is None or self.belief.prior is None:
            return
        pose, cov, odom = self.belief.prior
        self.bank = self._new_bank()
        self.bank.seed(t, odom, [pose], [cov], [1.0], origin="tracked")

    def step(self, t: float, odom: NDArray, points: NDArray, kinds: tuple[str, ...],
             hough: HoughConfig | None) -> Decision:
        """One scan while not tracking: every followed pose takes it, and may be taken;
        else it joins the views, and when they are enough (and no match is under way) a global
        match of them starts; a match under way advances by ``match_lookups_per_scan``."""
        if self.bank is not None and hough is not None:
            decision = self._take(t, self.bank.step(t, odom, points, hough,
                                                    self.least_right_fit()))
            if decision.reset_pose is not None:
                return decision
        added = self.views.add(odom, points)
        if self.match is None:
            if not added or not self.views.due(self.bank is not None):
                return Decision()
            self.go(t, State.RELOCALIZING, f"{len(self.views)} views accumulated")
            self.match = PendingMatch(self._match_stages(kinds), self.views.latest_odom)
        return self._match_step(t, odom)

    def _match_stages(self, kinds: tuple[str, ...]) -> Stages:
        """The global match of the views collected so far, in stages: their lines, then
        :func:`houghloc.global_match.global_match_stages`."""
        pts = self.views.points()
        grid, _, lines = observe_lines(pts, self.config.global_match.hough)
        yield len(pts) * grid.n_theta
        return (yield from global_match_stages(lines, pts, self.map, self.config.global_match,
                                               kinds=kinds))

    def _match_step(self, t: float, odom: NDArray) -> Decision:
        """The global match under way: its next stages, ``match_lookups_per_scan`` of work (no
        scan waits for a whole match). When it ends, its poses, found in the frame of the views
        it matched, are carried to this scan by the odometry since."""
        assert self.match is not None
        result = advance(self.match.stages, self.config.match_lookups_per_scan)
        if result is None:
            return Decision()
        start = self.match.odom
        self.match = None
        self.counts["global_matches"] += 1
        return self._seed_bank(t, result, start, odom)

    def _seed_bank(self, t: float, result: GlobalResult, matched_at: NDArray,
                   odom: NDArray) -> Decision:
        """Follow the match's poses, each with its own filter (:mod:`fusion.hypotheses`): they
        were found where the odometry read ``matched_at``, and are followed from ``odom``."""
        hyps = result.hypotheses
        if not hyps:
            self._failed(t, f"no global hypothesis ({result.reason or 'none'})")
            return Decision(result=result)
        if self.bank is None:
            self.bank = self._new_bank()
        floor = reinit_floor(self.config)
        covs = [0.5 * (np.asarray(h.cov, float) + np.asarray(h.cov, float).T) + floor
                for h in hyps]
        since = relative(matched_at, odom)
        poses = [compose(np.asarray(h.pose, float), since) for h in hyps]
        self.bank.seed(t, odom, poses, covs, [h.score for h in hyps],
                       [self.belief.displacement_prior(pose, odom, self.config) for pose in poses])
        self.log_hypotheses(t, hyps[:len(self.bank)])
        self.go(t, State.COLLECTING,
                f"following {len(self.bank)} hypotheses (best score {hyps[0].score:.2f})")
        return Decision(result=result)

    def _failed(self, t: float, reason: str) -> None:
        """A global match found nothing: collecting again, or lost after repeated failures."""
        self.views.failures += 1
        lost = self.views.failures >= self.config.failures_until_lost
        self.go(t, State.LOST if lost else State.COLLECTING, reason)

    def _new_bank(self) -> HypothesisBank:
        if self.make_tracker is None:
            raise RuntimeError("following a global match's poses needs a filter for each: the "
                               "manager was made without make_tracker (a Localizer gives it "
                               "its own)")
        return HypothesisBank(self.map, self.config.hypotheses, self.make_tracker,
                              self.fit.fractions, self.fit.shares_with_glass, self.fit.glass)

    def least_right_fit(self) -> float | None:
        """The least a right pose's scan fits (tracking's accepted scans' low quantile), if
        known: a followed pose that fits less is not taken, nor reported likely."""
        return self.fit.least_right(self.config.hypotheses.fit_quantile)

    def _take(self, t: float, verdict: BankVerdict, why: str = "") -> Decision:
        """The bank's pose, if its verdict names one: tracking starts again from it."""
        if verdict.pose is None or verdict.cov is None:
            return Decision()
        self.bank = None
        self.views.failures = 0
        self.views.clear()
        self.go(t, State.TRACKING, f"relocalized: {verdict.reason}{why}")
        return Decision(verdict.pose, verdict.cov)

    def landmark_step(self, t: float, odom: NDArray, position: tuple[float, float],
                      bearing: float, label: str, tolerance: float) -> Decision:
        """A landmark seen at ``bearing`` (``tolerance``: its 3σ) weighs the followed poses;
        the pose when one is taken."""
        if self.bank is None:
            return Decision()
        verdict = self.bank.weigh_bearing(t, np.asarray(odom, float), position, bearing,
                                          tolerance / 3.0, self.least_right_fit())
        return self._take(t, verdict, f" after {label} at {math.degrees(bearing):.0f}°")

    def log_hypotheses(self, t: float, hyps: list[Hypothesis]) -> None:
        if self.logger is not None:
            self.logger.log_hypotheses(t, np.array([h.pose for h in hyps]),
                                       np.array([h.score for h in hyps]))

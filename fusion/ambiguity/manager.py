"""The ambiguity manager: when tracking can't be trusted, switch to the paper's global strategy
(ii) — accumulate several views, match the whole set of peaks to the whole map — and back.

States and triggers (:class:`fusion.status.State`)::

    tracking ──(scans without a usable fix: ambiguous, rejected, misfits (fixes that put the
    │           scan off the walls) or none, while the prediction no longer fits the scan
    │           either, that see through the map's walls from the belief; covariance too
    │           large for the line spacing in view)──▶ collecting
    collecting ──(enough views, spaced by motion)──▶ relocalizing (a global match, spread
    │            over scans: ``match_lookups_per_scan`` of it each)
    relocalizing ──▶ collecting, its poses followed, each by its own filter
                     (:mod:`fusion.hypotheses`), tracking's last belief among them
                 ──(nothing fits, repeatedly)──▶ lost (still collecting)
    collecting ──(a followed pose the scans keep fitting, clearly ahead of the rest)──▶ tracking
    no initial pose ──▶ lost

Where tracking is given up: :meth:`AmbiguityManager.tracking_step`. Where a pose is taken
back: :meth:`AmbiguityManager.collecting_step`. With ``hypotheses: null`` a global match's
poses are judged by score, and ties by the rules of :mod:`fusion.ambiguity.ties`.

Every transition is recorded with its reason (``transitions``), counted in ``counts``, logged,
and written to ``metrics.json`` (:meth:`AmbiguityManager.summary`).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.config import AmbiguityConfig
from fusion.ambiguity.fit import ScanFit
from fusion.ambiguity.local_search import LocalSearch
from fusion.ambiguity.spacing import (
    SAME_WALL_GAP,
    closest_parallel_spacing,
    visible_parallel_spacing,
)
from fusion.ambiguity.ties import Ties, break_with_prior
from fusion.ambiguity.views import Views
from fusion.hypotheses import BankVerdict, HypothesisBank
from fusion.status import ScanStatus, State
from fusion.tracker import PoseTracker
from fusion.visualize import Logger
from houghloc import (
    GlobalResult,
    HoughConfig,
    Hypothesis,
    ScanCorrection,
    SegmentMap,
    observe_lines,
)
from houghloc.geometry import compose, relative, wrap_scalar
from houghloc.global_match import advance, finish, global_match_stages, prepare_map
from houghloc.jit import one_blas_thread
from houghloc.match_result import Stages


@dataclass(frozen=True, slots=True)
class Transition:
    t: float
    old: State
    new: State
    reason: str


@dataclass(frozen=True, slots=True)
class PendingMatch:
    """A global match under way (:data:`Stages`) and the odometry of the views it
    matches."""

    stages: Stages
    odom: NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Verdict:
    """The manager's word on a tracking fix, before the filter sees it: ``use`` it, or not and
    why (``status``). ``guess_fit``/``fix_fit``: the fractions of the scan's points on walls at
    the guess and at the fix (None when no check wanted them)."""

    use: bool
    status: ScanStatus | None = None
    guess_fit: float | None = None
    fix_fit: float | None = None


@dataclass
class Decision:
    """What the localizer must do after a scan: nothing, or re-initialise the filter."""

    reset_pose: NDArray[np.float64] | None = None
    reset_cov: NDArray[np.float64] | None = None
    result: GlobalResult | None = None


@dataclass
class AmbiguityManager:
    """The state machine between tracking and global localization (module docstring).

    It owns what decides: the fit of scans on the map (:class:`ScanFit`), the local re-search
    (:class:`LocalSearch`), the views collected for a global match, the followed hypotheses
    (:class:`HypothesisBank`) or, rules-based, the tied poses (:class:`Ties`); what is left
    here (about 390 lines) is every transition and its bookkeeping, kept in one class so that
    the state machine reads in one place."""

    map: SegmentMap
    config: AmbiguityConfig = field(default_factory=AmbiguityConfig)
    state: State = State.TRACKING
    transitions: list[Transition] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)
    logger: Logger | None = None
    # a filter at a pose with a covariance, for each followed hypothesis (the Localizer's own
    # settings); None: hypotheses are not followed by filters
    make_tracker: Callable[[NDArray, NDArray], PoseTracker] | None = None
    _without_fix: int = 0  # scans without a usable fix since the last one ...
    _seen_through: float = 0.0  # ... and the scans' worth of their points seen through walls
    _prior: tuple[NDArray, NDArray, NDArray] | None = None  # pose, cov, odometry when tracking
    _last_trusted: tuple[NDArray, NDArray] | None = None  # pose, odometry at the last used fix
    _trusted_by_prior_only: bool = False  # tracking since a tie broken by _last_trusted alone
    _bank: HypothesisBank | None = None
    _match: PendingMatch | None = None

    def __post_init__(self) -> None:
        self._line_spacing = closest_parallel_spacing(self.map)
        self.fit = ScanFit(self.map, self.config, self.counts)
        self._local = LocalSearch(self.map, self.config, self.fit, self.counts)
        self.ties = Ties(self.config)
        self.views = Views(self.config)

    def prepare(self, kinds: tuple[str, ...]) -> None:
        """Build the map's look-ups that global matching and the scan fit use for ``kinds``
        (cached on the map)."""
        prepare_map(self.map, self.config.global_match, kinds)

    def start_lost(self, t: float, reason: str) -> None:
        self._go(t, State.LOST, reason)

    # ------------------------------------------------------------------ tracking
    def judge(self, guess: NDArray, fix: ScanCorrection, points: NDArray,
              kinds: tuple[str, ...], min_lines: int) -> Verdict:
        """Should the filter be offered this tracking fix? One the matcher vouches for (not
        ambiguous, of rank > 0, at least ``min_lines`` lines matched) is, and one it cannot
        vouch for is when the scan itself does (:meth:`ScanFit.fix_gains`: the odometry slipped
        in a turn); either only if it keeps the scan on the walls about as well as recent fixes
        did (:meth:`ScanFit.fix_fits`: the robot is elsewhere, or the lines were matched to the
        wrong walls, however small the innovation). A few more points on walls than a guess
        that has none does not vouch for a fix that leaves the scan off them."""
        fit = self.fit
        # the fractions of the scan on walls at the guess and at the fix, once (in one pass),
        # for every check that wants them
        want_guess = fit.judges_by_fit
        want_fix = fix.rank > 0 and (fit.judges_fixes or want_guess)
        wanted = [pose for pose, want in ((guess, want_guess), (fix.pose, want_fix)) if want]
        fits = fit.fractions(np.array(wanted), points, kinds).tolist() if wanted else []
        guess_fit = fits.pop(0) if want_guess else None
        fix_fit = fits.pop(0) if want_fix else None
        matched = 0 if fix.matches is None else len(fix.matches)
        vouched = not fix.ambiguous and fix.rank > 0 and matched >= min_lines
        by_fit = (not vouched and fix.rank > 0
                  and fit.fix_gains(fix.pose, points, kinds, guess_fit, fix_fit))
        if not (vouched or by_fit):
            status = ScanStatus.AMBIGUOUS if fix.ambiguous else ScanStatus.NO_FIX
            return Verdict(False, status, guess_fit, fix_fit)
        if not fit.fix_fits(fix.pose, points, kinds, guess_fit, fix_fit):
            return Verdict(False, ScanStatus.MISFIT, guess_fit, fix_fit)
        return Verdict(True, None, guess_fit, fix_fit)

    def re_search(self, t: float, status: ScanStatus, verdict: Verdict, guess: NDArray,
                  guess_cov: NDArray, points: NDArray, fix: ScanCorrection,
                  kinds: tuple[str, ...], hough: HoughConfig,
                  odometry: Callable[[], NDArray | None]) -> Decision | None:
        """After a tracking scan's update (``status``): when the scan fits worse than usual (at
        the guess if no fix was accepted, at the fix if one was), the local search near the
        guess (:meth:`local_search`; its heading reach grows with ``guess_cov``), bounded by
        the motion since the last accepted fix (``odometry()``: the odometry at the scan, asked
        only then); None when none was wanted."""
        guess_fit = verdict.guess_fit
        fix_fit = verdict.fix_fit if status == ScanStatus.ACCEPTED else None
        if guess_fit is None or not self.wants_local_search(guess_fit, fix_fit):
            return None
        # tracking failed and the prediction no longer fits: the odometry slipped, or
        # reported a motion the robot did not make. Look for the pose near it first.
        return self.local_search(t, guess, points, fix, kinds, max(guess_fit, fix_fit or 0.0),
                                 hough, odometry(), guess_cov)

    def wants_local_search(self, guess_fit: float | None, fix_fit: float | None = None) -> bool:
        """Is a local re-search on, and does the scan fit worse than usual
        (:meth:`ScanFit.worse_than_usual`)?"""
        if (self.config.local_search_xy is None or guess_fit is None
                or self.state is not State.TRACKING):
            return False
        return self.fit.worse_than_usual(guess_fit, fix_fit)

    @one_blas_thread  # global matching's arrays: see one_blas_thread
    def local_search(self, t: float, guess: NDArray, points: NDArray, fix: ScanCorrection,
                     kinds: tuple[str, ...], guess_fit: float, hough: HoughConfig,
                     odom: NDArray | None, guess_cov: NDArray | None = None) -> Decision:
        """The pose near ``guess`` that the scan fits (:class:`LocalSearch`), within reach of
        the odometry ``odom``'s motion since the last accepted fix: it re-initialises the
        filter."""
        moved = (None if odom is None or self._last_trusted is None else
                 math.hypot(*(np.asarray(odom, float)[:2] - self._last_trusted[1][:2])))
        found = self._local.find(guess, points, fix, kinds, guess_fit, hough, moved, guess_cov)
        if found.pose is None or found.cov is None:
            return Decision(result=found.result)
        shift = found.pose - np.asarray(guess, float)
        if self.logger is not None:
            self.logger.log_state(t, self.state.value, (
                f"local re-search: moved {math.hypot(shift[0], shift[1]):.2f} m, "
                f"{math.degrees(wrap_scalar(shift[2])):.1f}°; {found.fit:.2f} of the points on "
                f"walls (guess {guess_fit:.2f})"))
        cov = found.cov
        return Decision(found.pose, 0.5 * (cov + cov.T) + self._reinit_floor, found.result)

    def tracking_step(self, t: float, status: ScanStatus, cov: NDArray,
                      pose: NDArray | None = None, odom: NDArray | None = None,
                      in_view: tuple[NDArray, NDArray] | None = None,
                      guess_fit: float | None = None, points: NDArray | None = None,
                      kinds: tuple[str, ...] = ("wall",)) -> None:
        """After a tracking scan: **where tracking is given up.** It is when the scans without
        a usable fix since the last one (not counting those whose ``guess_fit``, the fraction
        of points on walls at the guess, holds up: see ``hold_fit_ratio``) contradict the
        belief ``pose``: together they have seen ``through_wall_scans`` scans' worth of their
        ``points`` through the map's walls. A sensor that does not see walls (no ``"wall"`` in
        ``kinds``), or ``through_wall_scans`` None, gives it up after ``max_scans_without_fix``
        such scans instead. And when the position's σ passes ``max_position_sigma_fraction``
        of the closest parallel lines in view, ``in_view`` the references' robot-frame (θ, ρ)
        (the map's closest pair if not given)."""
        if self.state is not State.TRACKING:
            return
        if pose is not None and odom is not None:  # the belief, should tracking be abandoned
            self._prior = (np.array(pose, float), np.array(cov, float), np.array(odom, float))
            if status == ScanStatus.ACCEPTED:
                self._last_trusted = (np.array(pose, float), np.array(odom, float))
        through_walls = (self.config.through_wall_scans is not None and "wall" in kinds
                         and pose is not None and points is not None)
        if status in (ScanStatus.RE_SEARCHED, ScanStatus.ACCEPTED):
            self._fix_found()
            if status == ScanStatus.ACCEPTED and guess_fit is not None:
                self.fit.accepted(guess_fit)
        elif not self.fit.guess_holds(guess_fit):
            self._without_fix += 1
            if through_walls:
                assert pose is not None and points is not None
                self._seen_through += self.fit.seen_through(pose, points, kinds)
        if through_walls:
            assert self.config.through_wall_scans is not None
            if self._seen_through >= self.config.through_wall_scans:
                self._go(t, State.COLLECTING, (
                    f"{self._without_fix} scans without a usable fix saw "
                    f"{self._seen_through:.1f} scans' worth of points through the map's walls "
                    f"(last: {status})"))
                return
        elif self._without_fix >= self.config.max_scans_without_fix:
            self._go(t, State.COLLECTING,
                     f"{self._without_fix} scans without a usable fix (last: {status})")
            return
        fraction = self.config.max_position_sigma_fraction
        if fraction is None:
            return
        sigma = math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2])[-1], 0.0))
        if in_view is None:
            spacing = self._line_spacing
        elif sigma > fraction * SAME_WALL_GAP:
            spacing = visible_parallel_spacing(*in_view)
        else:  # no spacing in view can be smaller: the usual case, without the K×K comparison
            return
        if sigma > fraction * spacing:
            self._go(t, State.COLLECTING, f"position σ {sigma:.2f} m exceeds {fraction:g} of the "
                                          f"{spacing:.2f} m between parallel lines in view")

    def _fix_found(self) -> None:
        """A usable fix, or a new pose: the evidence for giving tracking up starts again."""
        self._without_fix, self._seen_through = 0, 0.0

    @property
    def _reinit_floor(self) -> NDArray[np.float64]:
        """The least covariance the filter is re-initialised with (``reinit_sigma_*``)."""
        return np.diag([self.config.reinit_sigma_xy**2] * 2
                       + [math.radians(self.config.reinit_sigma_theta_deg) ** 2])

    # ------------------------------------------------------------------ global mode
    @one_blas_thread
    def collecting_step(self, t: float, odom: NDArray, points: NDArray,
                        kinds: tuple[str, ...] = ("wall",),
                        hough: HoughConfig | None = None) -> Decision:
        """**Where a pose is taken back.** Every followed hypothesis takes this scan
        (``hough`` settings) and the bank may name the pose; else the view is accumulated and,
        when there are enough, the set is matched and its poses are followed."""
        odom = np.asarray(odom, float)
        if self._bank is not None and hough is not None:
            decision = self._follow_bank(t, odom, points, hough)
            if decision.reset_pose is not None:
                return decision
        elif self.ties and hough is not None:
            decision = self._follow_ties(t, odom, points, kinds, hough)
            if decision.reset_pose is not None:
                return decision
        added = self.views.add(odom, points)
        if self._match is None:
            if not added or not self.views.due(self._bank is not None):
                return Decision()
            self._go(t, State.RELOCALIZING, f"{len(self.views)} views accumulated")
            self._match = PendingMatch(self._match_stages(kinds), self.views.latest_odom)
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
        """The global match under way: its next stages, ``match_lookups_per_scan`` of work,
        when its poses are followed (no scan waits for a whole match); whole otherwise. When it
        ends, its poses, found in the frame of the views it matched, are carried to this scan
        by the odometry since."""
        assert self._match is not None
        following = self.config.hypotheses is not None and self.make_tracker is not None
        result = (advance(self._match.stages, self.config.match_lookups_per_scan) if following
                  else finish(self._match.stages))
        if result is None:
            return Decision()
        start = self._match.odom
        self._match = None
        self.counts["global_matches"] += 1
        if following:
            return self._seed_bank(t, result, start, odom)
        decision = self._decide(t, result)
        decision.result = result
        return decision

    def _seed_bank(self, t: float, result: GlobalResult, matched_at: NDArray,
                   odom: NDArray) -> Decision:
        """Follow the match's poses, each with its own filter (:mod:`fusion.hypotheses`): they
        were found where the odometry read ``matched_at``, and are followed from ``odom``."""
        hyps = result.hypotheses
        if not hyps:
            self.views.failures += 1
            lost = self.views.failures >= self.config.failures_until_lost
            self._go(t, State.LOST if lost else State.COLLECTING,
                     f"no global hypothesis ({result.reason or 'none'})")
            return Decision(result=result)
        if self._bank is None:
            self._bank = self._new_bank()
        covs = [0.5 * (np.asarray(h.cov, float) + np.asarray(h.cov, float).T)
                + self._reinit_floor for h in hyps]
        since = relative(matched_at, odom)
        poses = [compose(np.asarray(h.pose, float), since) for h in hyps]
        self._bank.seed(t, odom, poses, covs, [h.score for h in hyps],
                        [self._displacement_prior(pose, odom) for pose in poses])
        self._log_hypotheses(t, hyps[:len(self._bank)])
        self._go(t, State.COLLECTING,
                 f"following {len(self._bank)} hypotheses (best score {hyps[0].score:.2f})")
        return Decision(result=result)

    def _new_bank(self) -> HypothesisBank:
        assert self.config.hypotheses is not None and self.make_tracker is not None
        return HypothesisBank(self.map, self.config.hypotheses, self.make_tracker,
                              self.fit.fractions, self.fit.shares)

    def _follow_belief(self, t: float) -> None:
        """Tracking given up: its belief becomes the first followed hypothesis. Scans that
        did not fit for a while are evidence against it, not proof: if it keeps fitting it is
        taken back within a few scans, and a wrong one falls behind the poses global matching
        proposes (no rule decides between giving up too early and too late)."""
        if self.config.hypotheses is None or self.make_tracker is None or self._prior is None:
            return
        pose, cov, odom = self._prior
        self._bank = self._new_bank()
        self._bank.seed(t, odom, [pose], [cov], [1.0], origin="tracked")

    @property
    def followed(self) -> list[tuple[NDArray[np.float64], float]]:
        """Every followed hypothesis's pose and weight, likeliest first (none while tracking)."""
        if self._bank is None:
            return []
        return [(h.pose.copy(), h.weight)
                for h in sorted(self._bank.hypotheses, key=lambda h: -h.weight)]

    @property
    def leading_hypothesis(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The pose and covariance of the likeliest followed hypothesis, None if none is."""
        if self._bank is None or not len(self._bank):
            return None
        leader = self._bank.leader
        return leader.pose, leader.cov

    def _least_right_fit(self) -> float | None:
        assert self.config.hypotheses is not None
        return self.fit.least_right(self.config.hypotheses.fit_quantile)

    def _displacement_prior(self, pose: NDArray, odom: NDArray) -> float:
        """How plausible a pose (where the odometry read ``odom``) is from where tracking
        last was, carried by odometry: N(d; 0, ``kidnap_prior_sigma``²) in the distance d, over
        a floor of ``kidnap_probability`` for a robot carried anywhere; 1 without a belief
        (global start)."""
        sigma = self.config.kidnap_prior_sigma
        if sigma is None or self._prior is None:
            return 1.0
        belief, _, belief_odom = self._prior
        moved = compose(belief, relative(belief_odom, odom))
        d = math.hypot(pose[0] - moved[0], pose[1] - moved[1])
        return max(math.exp(-0.5 * (d / sigma) ** 2), self.config.kidnap_probability)

    def _follow_bank(self, t: float, odom: NDArray, points: NDArray,
                     hough: HoughConfig) -> Decision:
        """One scan for every followed hypothesis; the pose when one is taken."""
        assert self._bank is not None
        return self._take(t, self._bank.step(t, odom, points, hough, self._least_right_fit()))

    def _take(self, t: float, verdict: BankVerdict, why: str = "") -> Decision:
        """The bank's pose, if its verdict names one: tracking starts again from it."""
        if verdict.pose is None or verdict.cov is None:
            return Decision()
        self._bank = None
        self.views.failures = 0
        self.ties.clear()
        self.views.clear()
        self._fix_found()
        self._go(t, State.TRACKING, f"relocalized: {verdict.reason}{why}")
        return Decision(verdict.pose, verdict.cov)

    # ------------------------------------------------------------------ rules-based (ties)
    def _decide(self, t: float, result: GlobalResult) -> Decision:
        """Without followed hypotheses: the best pose when it scores ``min_score`` and no rival
        comes within ``decisive_margin``; rivals are a tie (:class:`Ties`) unless the tracker's
        last belief singles one out."""
        good = [h for h in result.hypotheses if h.score >= self.config.min_score]
        if not good:
            self.views.failures += 1
            lost = self.views.failures >= self.config.failures_until_lost
            self._go(t, State.LOST if lost else State.COLLECTING,
                     f"no global hypothesis ({result.reason or 'none scored enough'})")
            return Decision()
        top = good[0].score
        rivals = [h for h in result.hypotheses[1:] if h.score > top - self.config.decisive_margin]
        if result.ambiguous or rivals:
            tied = [good[0], *rivals]
            chosen = (break_with_prior(tied, self._prior, self.views.latest_odom)
                      if self.views else None)
            if chosen is not None:
                return self._accept(t, chosen, "tie broken by the last tracked pose")
            if not self.ties:  # a new tie: follow each of its poses from now on
                self.ties.start(tied, self.views.latest_odom)
            self.counts["ties"] += 1
            self._go(t, State.COLLECTING,
                     f"{len(tied)} hypotheses tie (score {top:.2f}): symmetric map, collecting")
            self._log_hypotheses(t, tied)
            return Decision()
        return self._accept(t, good[0], "")

    def _accept(self, t: float, best: Hypothesis, how: str) -> Decision:
        self.views.failures = 0
        self.ties.clear()
        cov = np.array(best.cov, dtype=float)
        cov = 0.5 * (cov + cov.T) + self._reinit_floor
        self.views.clear()
        self._fix_found()
        self._log_hypotheses(t, [best])
        self._go(t, State.TRACKING, f"relocalized: score {best.score:.2f}, "
                                    f"{best.n_lines_explained} lines explained"
                                    + (f" ({how})" if how else ""))
        return Decision(np.asarray(best.pose, float), cov)

    def _follow_ties(self, t: float, odom: NDArray, points: NDArray, kinds: tuple[str, ...],
                     hough: HoughConfig) -> Decision:
        """Every tied pose takes this scan (:meth:`Ties.follow`); tracking starts again from
        the one that breaks the tie."""
        broken = self.ties.follow(odom, points, kinds, hough, self.map, self.fit,
                                  self._last_trusted)
        if broken is None:
            return Decision()
        self.views.clear()
        self._fix_found()
        if broken.by_distance:
            self.counts["ties_broken_by_distance"] += 1
        self._go(t, State.TRACKING, broken.reason)
        self._trusted_by_prior_only = broken.by_distance
        return Decision(broken.pose, self._reinit_floor)

    def landmark_step(self, t: float, odom: NDArray, position: tuple[float, float],
                      bearing: float, label: str, tolerance: float = math.radians(15.0)
                      ) -> Decision:
        """A recognised landmark seen at ``bearing``: followed hypotheses are weighed by it
        (``tolerance`` is its 3σ); tied hypotheses that would see it elsewhere are dropped.
        When one is left, or one's weight is enough, it is the pose."""
        if self._bank is not None:
            verdict = self._bank.weigh_bearing(t, np.asarray(odom, float), position, bearing,
                                               tolerance / 3.0, self._least_right_fit())
            return self._take(t, verdict, f" after {label} at {math.degrees(bearing):.0f}°")
        keep = self.ties.landmark(odom, position, bearing, tolerance)
        if keep is None:
            return Decision()
        self.counts["landmark_prunes"] += 1
        if not keep:  # none fits: the tie was not between the right poses; start over
            self._go(t, State.COLLECTING, f"{label} fits no hypothesis: collecting again")
            return Decision()
        if len(keep) > 1:
            return Decision()
        self.views.clear()
        self._fix_found()
        self._go(t, State.TRACKING, f"tie broken by {label} at {math.degrees(bearing):.0f}°")
        self.ties.clear()
        cov = np.diag([0.1**2, 0.1**2, math.radians(3.0) ** 2])
        return Decision(keep[0], cov)

    # ------------------------------------------------------------------ transitions
    def _go(self, t: float, new: State, reason: str) -> None:
        if new is self.state and new is not State.COLLECTING:
            return
        if new is State.COLLECTING and self.state is State.TRACKING:
            self.views.restart()
            self._bank = None
            self._follow_belief(t)
            if self._trusted_by_prior_only:  # it may have been the wrong one of the tie
                self._last_trusted = None
                self._trusted_by_prior_only = False
        if new is State.LOST:
            self._prior = None  # no belief to break ties with
        if new is State.TRACKING or self.state is State.TRACKING:
            self._match = None  # a match under way is for the views it started from
        if new is State.TRACKING:
            self._trusted_by_prior_only = False  # set again by the caller when it is so
        self.transitions.append(Transition(t, self.state, new, reason))
        self.counts[f"{self.state.value}->{new.value}"] += 1
        self.state = new
        if self.logger is not None:
            self.logger.log_state(t, new.value, reason)

    def _log_hypotheses(self, t: float, hyps: list[Hypothesis]) -> None:
        if self.logger is not None:
            self.logger.log_hypotheses(t, np.array([h.pose for h in hyps]),
                                       np.array([h.score for h in hyps]))

    def summary(self) -> dict:
        return {"state": self.state.value, "transitions": len(self.transitions),
                "counts": dict(self.counts),
                "log": [{"t": round(tr.t, 3), "from": tr.old.value, "to": tr.new.value,
                         "reason": tr.reason} for tr in self.transitions[-50:]]}

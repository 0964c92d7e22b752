"""The ambiguity manager (DESIGN §3.6, §4): when tracking can't be trusted, switch to the
paper's global strategy (ii) — accumulate several views, match the whole set of peaks to the
whole map — and back.

States and triggers::

    tracking ──(ambiguous matches, repeated rejections, misfits (fixes that put the scan off
    │           the walls) or scans without a fix, covariance too large for the map's line
    │           spacing, a kidnap)──▶ collecting
    collecting ──(enough views: at least two non-parallel lines)──▶ relocalizing
    relocalizing ──(one clear hypothesis)──▶ tracking (filter re-initialised from it)
                 ──(a tie: a symmetric map)──▶ collecting, hypotheses kept and carried by
                   odometry until the evidence (or, after a kidnap, the last trusted pose)
                   breaks the tie
                 ──(nothing fits, repeatedly)──▶ lost (still collecting)
    no initial pose ──▶ lost

Every transition is recorded with its reason (``transitions``), counted in ``counts`` and
logged.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from fusion.hypotheses import BankVerdict, HypothesisBank, HypothesisConfig
from fusion.status import ScanStatus, State
from fusion.tracker import PoseTracker
from fusion.visualize import Logger
from houghloc import (
    GlobalMatchConfig,
    GlobalResult,
    HoughConfig,
    ScanCorrection,
    SegmentMap,
    global_match,
    localize_scan,
    observe_lines,
)
from houghloc.displacement import UNOBSERVED_VARIANCE
from houghloc.geometry import compose, relative, transform_points, wrap_angle, wrap_scalar
from houghloc.global_match import Neighbourhood
from houghloc.localize import clean_points
from houghloc.map_lookup import wall_distance
from houghloc.matching import gate_threshold

_TRACKED_FITS = 200  # accepted scans whose fits tell what a right pose fits
_SAME_WALL_GAP = 0.05  # m: parallel references closer than this are pieces of one wall


class AmbiguityConfig(BaseModel):
    """When to stop trusting the tracker, and how to find the pose again."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_scans_without_fix: int = Field(
        25, ge=1, description="consecutive scans rejected, ambiguous or unmatched")
    max_position_sigma_fraction: float | None = Field(
        None, gt=0.0, description="σ_xy beyond this fraction of the closest parallel-line "
        "spacing makes nearest-neighbour matching unsafe (None: no such check; on a real map "
        "the spacing of two pieces of one wall is centimetres)")
    min_views: int = Field(5, ge=1, description="views accumulated before a global match")
    max_views: int = Field(30, ge=1, description="sliding window of accumulated views")
    view_spacing: float = Field(
        0.03, ge=0.0, description="m travelled (or view_spacing_deg turned) between views: a "
        "robot standing still adds no evidence")
    view_spacing_deg: float = Field(2.0, ge=0.0, description="° turned between views")
    max_points: int = Field(4000, ge=100, description="accumulated points kept (subsampled)")
    min_score: float = Field(0.85, ge=0.0, le=1.0, description="global hypothesis acceptance")
    decisive_margin: float = Field(
        0.05, ge=0.0, description="the winner must beat any other pose by this much; closer "
        "rivals are a tie and more views are collected")
    reinit_sigma_xy: float = Field(0.05, gt=0.0, description="m, floor on the new covariance")
    reinit_sigma_theta_deg: float = Field(1.0, gt=0.0, description="°, floor on the new "
                                          "covariance")
    failures_until_lost: int = Field(3, ge=1, description="global matches without a decisive "
                                     "pose before the state says lost (and retries back off)")
    tie_window: int = Field(
        10, ge=2, description="scans over which tied poses are compared by how well they fit")
    tie_lead: float = Field(
        0.1, gt=0.0, description="lead in the fraction of points on walls that breaks a tie")
    tie_steady_lead: float | None = Field(
        0.01, gt=0.0, description="a smaller lead breaks it too when held on every scan of "
        "the window (None: never) ...")
    tie_min_fit: float = Field(
        0.9, ge=0.0, le=1.0, description="... by a pose whose fraction on walls is at least "
        "this much of tracking's")
    retry_every: int = Field(3, ge=1, description="scans between global attempts")
    # A fix that puts the scan where the map has no walls is not used, however well it passes
    # the filter's gate: a single matched line (rank 2) after a kidnap can steer the heading
    # wherever the odometry drifts while every innovation stays small.
    misfit_ratio: float = Field(
        0.5, ge=0.0, le=1.0, description="a fix with a fraction of points on walls below this "
        "times the recent typical fraction is a misfit (0 turns the check off)")
    fit_window: int = Field(20, ge=3, description="recent used fixes that set the typical fit")
    # The scan's own points on the map's walls judge a fix that the matcher alone cannot. On
    # Intel and ACES, of the fixes that put 0.1 fewer of the points on walls than the filter's
    # guess did, 28 of 34 were wrong (> 2° or 15 cm from the reference): two lines of a corner
    # matched to the wrong walls while the robot spins pass every gate. Single-line fixes and
    # fixes whose lines disagree (a map wall modelled a degree off) that put clearly more points
    # on walls than the guess were right in 4 of 5 cases: the odometry had slipped in a turn.
    max_fit_loss: float | None = Field(
        0.03, ge=0.0, le=1.0, description="a fix whose fraction of points on walls is below "
        "the guess's by more than this is a misfit (None: no such check)")
    min_fit_gain: float | None = Field(
        0.03, ge=0.0, le=1.0, description="a fix from too few lines, or flagged ambiguous, is "
        "used when its fraction on walls beats the guess's by this much (None: never)")
    # A robot whose predicted pose keeps the scan on the walls as well as when fixes were
    # accepted is not lost, however many scans the matcher cannot use (a wall modelled a degree
    # off makes two lines "disagree" for seconds): such scans do not count towards
    # max_scans_without_fix.
    hold_fit_ratio: float | None = Field(
        0.9, gt=0.0, le=1.0, description="a scan without a fix whose guess has at least this "
        "times the recent accepted scans' fraction on walls does not count as a failure")
    # After a kidnap the pose is more plausibly near where the robot was last known to be than
    # across the building: a displacement prior N(0, σ²) about the last trusted pose (carried by
    # odometry) breaks ties that the views cannot. Without such a pose (global start) nothing
    # changes.
    kidnap_prior_sigma: float | None = Field(
        2.0, gt=0.0, description="m; scale of a plausible kidnap (None: never use the prior)")
    kidnap_probability: float = Field(
        0.01, gt=0.0, le=1.0, description="how plausible a pose far beyond the kidnap scale is "
        "next to one where the odometry says the robot is (the displacement prior's floor)")
    kidnap_prior_odds: float = Field(
        10.0, gt=1.0, description="the nearest tied pose is taken when the prior makes it this "
        "many times as likely as every rival: exp((d₂² − d₁²) / 2σ²)")
    # When tracking fails and the prediction no longer fits the scan (guess fit below
    # hold_fit_ratio of the recent ones), the scan's own lines are matched to the map's within a
    # neighbourhood of the dead-reckoned pose before the filter is given up: a wheel slip or a
    # motion the odometry did not report (driving backwards) leaves the robot near it, where the
    # rest of the building cannot compete.
    local_search_xy: float | None = Field(
        1.0, gt=0.0, description="m; radius of the local re-search (None: no local search)")
    local_search_theta_deg: float = Field(20.0, gt=0.0, le=180.0,
                                          description="°; heading range of the local re-search")
    # What keeps a wrong pose out is a rival, not a level: a cluttered room fits 0.45-0.7 at the
    # right pose where a corridor fits 0.8, so a pose needing 0.9 of the recent fixes' fraction
    # was refused there, and lowering that level alone let wrong poses in (Freiburg 079: at a
    # reversal a pose 23° off led the right one by 0.06; 0.6 of the recent fraction with a rival
    # margin of 0.05: 9.8 % lost). With a margin of 0.1 the level hardly matters (0 to 0.5:
    # 3.97-3.99 % lost; margin 0.15: 4.7 %); Intel and ACES are unchanged by either.
    local_fit_gain: float = Field(
        0.1, ge=0.0, le=1.0, description="the pose found must put this much more of the scan's "
        "points on walls than the guess ...")
    local_min_fit: float = Field(
        0.5, ge=0.0, le=1.0, description="... at least this times the recent accepted "
        "scans' fraction ...")
    local_rival_margin: float = Field(
        0.1, ge=0.0, le=1.0, description="... and beat every other pose found in the "
        "neighbourhood by this much")
    # A scan that fits nowhere well (a person in front of the laser, a blurred turn) can lead the
    # re-search to a wrong pose that merely fits it a little better: shortly after a used fix the
    # odometry cannot have slipped far, so a pose found is accepted only within reach of the
    # motion since that fix (a reversal the wheels report as forward motion errs by twice it).
    # Freiburg 079 at 898.0 s: 0.14 s after an accepted fix a re-search moved the estimate
    # 0.77 m; refused, 0.3 → 0.1 % lost and ATE 5.5 → 4.8 cm (3.0 per metre: the same; Intel
    # and ACES unchanged). The heading is not limited: slips in turns are what it recovers.
    local_reach_base: float = Field(
        0.25, gt=0.0, description="m; the pose found may be this far from the guess ...")
    local_reach_per_metre: float | None = Field(
        2.0, gt=0.0, description="... plus this times the distance the odometry moved since the "
        "last accepted fix (None: anywhere within local_search_xy)")
    global_match: GlobalMatchConfig = GlobalMatchConfig()
    hypotheses: HypothesisConfig | None = Field(
        HypothesisConfig(), description="follow a global match's poses each with its own "
        "filter and take the one the scans keep fitting (None: the score, tie and prior rules "
        "above)")


@dataclass(frozen=True, slots=True)
class Transition:
    t: float
    old: State
    new: State
    reason: str


@dataclass
class _View:
    odom: NDArray[np.float64]
    points: NDArray[np.float64]


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
    map: SegmentMap
    config: AmbiguityConfig = field(default_factory=AmbiguityConfig)
    state: State = State.TRACKING
    transitions: list[Transition] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)
    hypotheses: list[NDArray[np.float64]] = field(default_factory=list)  # in the latest view
    _views: deque = field(default_factory=deque)
    _without_fix: int = 0
    _failures: int = 0
    _since_attempt: int = 0
    _hyp_odom: NDArray[np.float64] | None = None
    _hyp_fit: list = field(default_factory=list)  # per tied pose: recent fractions on walls
    _prior: tuple[NDArray, NDArray, NDArray] | None = None  # pose, cov, odometry when tracking
    _last_trusted: tuple[NDArray, NDArray] | None = None  # pose, odometry at the last used fix
    _trusted_by_prior_only: bool = False  # tracking since a tie broken by _last_trusted alone
    _ties_slid: bool = False  # the followed ties were found by sliding along a corridor
    # the last fit_window fractions on walls (windows made in __post_init__): of used fixes, of
    # the guesses they corrected, and of the fixes that passed fix_fits_map
    _recent_fit: deque = field(init=False)
    _guess_fits: deque = field(init=False)
    _fix_fits: deque = field(init=False)
    logger: Logger | None = None
    # a filter at a pose with a covariance, for each followed hypothesis (the Localizer's own
    # settings); None: hypotheses are not followed by filters
    make_tracker: Callable[[NDArray, NDArray], PoseTracker] | None = None
    _bank: HypothesisBank | None = None
    # fractions on walls of the latest accepted scans' guesses: what a right pose fits here
    _tracked_fits: deque = field(default_factory=lambda: deque(maxlen=_TRACKED_FITS))

    def __post_init__(self) -> None:
        self._line_spacing = _closest_parallel_spacing(self.map)
        window = self.config.fit_window
        self._recent_fit, self._guess_fits, self._fix_fits = (
            deque(maxlen=window), deque(maxlen=window), deque(maxlen=window))

    # ------------------------------------------------------------------ tracking-mode triggers
    def start_lost(self, t: float, reason: str) -> None:
        self._go(t, State.LOST, reason)

    @property
    def judges_fixes(self) -> bool:
        """Does :meth:`fix_fits_map` look at the scan at all?"""
        return self.config.misfit_ratio > 0.0 or self.judges_by_fit

    @property
    def judges_by_fit(self) -> bool:
        """Do the fit checks need the fraction of each scan's points on walls at the guess?"""
        c = self.config
        return c.max_fit_loss is not None or c.min_fit_gain is not None or \
            c.hold_fit_ratio is not None or c.local_search_xy is not None or \
            c.hypotheses is not None

    def tracking_step(self, t: float, status: ScanStatus, cov: NDArray, pose: NDArray | None = None,
                      odom: NDArray | None = None,
                      in_view: tuple[NDArray, NDArray] | None = None,
                      guess_fit: float | None = None) -> None:
        """After a tracking scan: count scans without a usable fix (not those whose
        ``guess_fit``, the fraction of points on walls at the guess, holds up: see
        ``hold_fit_ratio``); check the covariance against the closest parallel lines in view,
        ``in_view`` the references' robot-frame (θ, ρ) (the map's closest pair if not given)."""
        if self.state is not State.TRACKING:
            return
        if pose is not None and odom is not None:  # the belief, should tracking be abandoned
            self._prior = (np.array(pose, float), np.array(cov, float), np.array(odom, float))
            if status == ScanStatus.ACCEPTED:
                self._last_trusted = (np.array(pose, float), np.array(odom, float))
        if status == ScanStatus.RE_SEARCHED:
            self._without_fix = 0
        elif status == ScanStatus.ACCEPTED:
            self._without_fix = 0
            if guess_fit is not None:
                self._guess_fits.append(guess_fit)
                self._tracked_fits.append(guess_fit)
        elif not self._guess_holds(guess_fit):
            self._without_fix += 1
        if self._without_fix >= self.config.max_scans_without_fix:
            self._go(t, State.COLLECTING,
                     f"{self._without_fix} scans without a usable fix (last: {status})")
            return
        fraction = self.config.max_position_sigma_fraction
        if fraction is None:
            return
        sigma = math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2])[-1], 0.0))
        if in_view is None:
            spacing = self._line_spacing
        elif sigma > fraction * _SAME_WALL_GAP:
            spacing = visible_parallel_spacing(*in_view)
        else:  # no spacing in view can be smaller: the usual case, without the K×K comparison
            return
        if sigma > fraction * spacing:
            self._go(t, State.COLLECTING, f"position σ {sigma:.2f} m exceeds {fraction:g} of the "
                                          f"{spacing:.2f} m between parallel lines in view")

    def judge(self, guess: NDArray, fix: ScanCorrection, points: NDArray,
              kinds: tuple[str, ...], min_lines: int) -> Verdict:
        """Should the filter be offered this tracking fix? A fix the matcher vouches for (not
        ambiguous, of rank > 0, at least ``min_lines`` lines matched) is, unless it puts the
        scan off the walls (:meth:`fix_fits_map`: the robot is elsewhere, or the lines were
        matched to the wrong walls, however small the innovation); one it cannot vouch for is
        when the scan itself does (:meth:`fix_gains_fit`: the odometry slipped in a turn)."""
        # the fractions of the scan on walls at the guess and at the fix, once (in one pass),
        # for every check that wants them
        want_guess = self.judges_by_fit
        want_fix = fix.rank > 0 and (self.judges_fixes or want_guess)
        wanted = [pose for pose, want in ((guess, want_guess), (fix.pose, want_fix)) if want]
        fits = self.fit_fractions(np.array(wanted), points, kinds).tolist() if wanted else []
        guess_fit = fits.pop(0) if want_guess else None
        fix_fit = fits.pop(0) if want_fix else None
        matched = 0 if fix.matches is None else len(fix.matches)
        vouched = not fix.ambiguous and fix.rank > 0 and matched >= min_lines
        by_fit = (not vouched and fix.rank > 0
                  and self.fix_gains_fit(fix.pose, points, kinds, guess_fit, fix_fit))
        if not (vouched or by_fit):
            status = ScanStatus.AMBIGUOUS if fix.ambiguous else ScanStatus.NO_FIX
            return Verdict(False, status, guess_fit, fix_fit)
        if vouched and not self.fix_fits_map(fix.pose, points, kinds, guess_fit, fix_fit):
            return Verdict(False, ScanStatus.MISFIT, guess_fit, fix_fit)
        return Verdict(True, None, guess_fit, fix_fit)

    def re_search(self, t: float, status: ScanStatus, verdict: Verdict, guess: NDArray,
                  points: NDArray, fix: ScanCorrection, kinds: tuple[str, ...],
                  hough: HoughConfig, odom: NDArray | None) -> Decision | None:
        """After a tracking scan's update (``status``): when the scan fits worse than usual (at
        the guess if no fix was accepted, at the fix if one was), the local search near the
        guess (:meth:`local_search`); None when none was wanted."""
        guess_fit = verdict.guess_fit
        fix_fit = verdict.fix_fit if status == ScanStatus.ACCEPTED else None
        if guess_fit is None or not self.wants_local_search(guess_fit, fix_fit):
            return None
        # tracking failed and the prediction no longer fits: the odometry slipped, or
        # reported a motion the robot did not make. Look for the pose near it first.
        return self.local_search(t, guess, points, fix, kinds, max(guess_fit, fix_fit or 0.0),
                                 hough, odom)

    def wants_local_search(self, guess_fit: float | None, fix_fit: float | None = None) -> bool:
        """Is a local re-search on, and does the scan fit worse than usual: at the guess when no
        fix was used, at the fix (``fix_fit``) when one was (two lines matched to the wrong
        walls after a slip can pass the gates and still leave the scan off the walls)?"""
        if (self.config.local_search_xy is None or guess_fit is None
                or self.state is not State.TRACKING or len(self._guess_fits) < 5):
            return False
        if fix_fit is None:
            return not self._guess_holds(guess_fit)
        if not self._fix_fits:  # no fix used yet: nothing says how well one usually fits
            return False
        ratio = self.config.hold_fit_ratio or 1.0
        return fix_fit < ratio * statistics.median(self._fix_fits)

    def local_search(self, t: float, guess: NDArray, points: NDArray, fix: ScanCorrection,
                     kinds: tuple[str, ...], guess_fit: float, hough: HoughConfig,
                     odom: NDArray | None) -> Decision:
        """Match one scan's lines (those of the tracking ``fix`` from the same ``points``) to
        the map near ``guess`` (``local_search_xy``, ``local_search_theta_deg``); the pose found
        re-initialises the filter when it clearly fits the scan better than the guess and about
        as well as tracking did, no other pose in the neighbourhood scores as well (a corridor
        leaves the position along it open), and it is within reach of the odometry ``odom``'s
        motion since the last accepted fix (``local_reach_per_metre``)."""
        lines, radius = fix.lines, self.config.local_search_xy
        if (lines is None or len(lines) < 2 or lines.members.shape[0] != len(points)
                or fix.grid is None or fix.accumulator is None or radius is None):
            return Decision()
        near = Neighbourhood(np.asarray(guess, float), radius,
                             math.radians(self.config.local_search_theta_deg))
        # only the best three are polished below: refining more would be wasted
        local = self.config.global_match.model_copy(update={"max_refined": 3})
        result = global_match(lines, points, self.map, local, kinds, near)
        self.counts["local_searches"] += 1
        if not self._fix_fits:
            return Decision(result=result)
        # Candidates: the matcher's poses (clustered by 5°, so each is polished by tracking from
        # it) and the guess turned and moved along its heading step by step (a slip in a turn,
        # an unreported reversal), each corrected by tracking from there.
        sweep = _sweep(np.asarray(guess, float), radius,
                       math.radians(self.config.local_search_theta_deg))
        raw = self.fit_fractions(sweep, points, kinds)  # polish the promising ones only
        starts = [np.asarray(h.pose, float) for h in result.hypotheses[:3]]
        starts += list(sweep[np.argsort(-raw, kind="stable")[:6]])
        prior = np.diag([0.1**2, 0.1**2, math.radians(2.0) ** 2])
        observed = (fix.grid, fix.accumulator, lines)  # one scan, matched from every start
        found = []
        for start in starts:
            polished = _polished(localize_scan(points, self.map, start, hough, pose_cov=prior,
                                               observed=observed), np.asarray(guess, float))
            if polished is not None:
                found.append((self.fit_fraction(polished[0], points, kinds), *polished))
        if not found:
            return Decision(result=result)
        found.sort(key=lambda f: -f[0])
        fit, pose, cov = found[0]
        typical = statistics.median(self._fix_fits)
        rivals = [f for f in found[1:] if f[0] > fit - self.config.local_rival_margin
                  and not _same_pose(f[1], pose)]
        if (fit < guess_fit + self.config.local_fit_gain
                or fit < self.config.local_min_fit * typical or rivals
                or not self._within_reach(pose, guess, odom)):
            return Decision(result=result)
        self.counts["local_fixes"] += 1
        shift = pose - np.asarray(guess, float)
        if self.logger is not None:
            self.logger.log_state(t, self.state.value, (
                f"local re-search: moved {math.hypot(shift[0], shift[1]):.2f} m, "
                f"{math.degrees(wrap_scalar(shift[2])):.1f}°; {fit:.2f} of the points on walls "
                f"(guess {guess_fit:.2f})"))
        cov = np.array(cov, dtype=float)
        return Decision(np.asarray(pose, float), 0.5 * (cov + cov.T) + self._reinit_floor,
                        result)

    def _within_reach(self, pose: NDArray, guess: NDArray, odom: NDArray | None) -> bool:
        """Is the re-search's ``pose`` within ``local_reach_base`` + ``local_reach_per_metre`` ×
        the odometry's displacement since the last accepted fix of the ``guess``? Without
        odometry (None) or an accepted fix there is no motion to bound it by."""
        per_metre = self.config.local_reach_per_metre
        if per_metre is None or odom is None or self._last_trusted is None:
            return True
        moved = math.hypot(*(np.asarray(odom, float)[:2] - self._last_trusted[1][:2]))
        shift = math.hypot(*(np.asarray(pose, float)[:2] - np.asarray(guess, float)[:2]))
        if shift <= self.config.local_reach_base + per_metre * moved:
            return True
        self.counts["local_out_of_reach"] += 1
        return False

    @property
    def _reinit_floor(self) -> NDArray[np.float64]:
        """The least covariance the filter is re-initialised with (``reinit_sigma_*``)."""
        return np.diag([self.config.reinit_sigma_xy**2] * 2
                       + [math.radians(self.config.reinit_sigma_theta_deg) ** 2])

    def _guess_holds(self, guess_fit: float | None) -> bool:
        ratio = self.config.hold_fit_ratio
        if ratio is None or guess_fit is None or len(self._guess_fits) < 5:
            return False
        return guess_fit >= ratio * statistics.median(self._guess_fits)

    def fix_gains_fit(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...],
                      guess_fit: float | None, fraction: float | None = None) -> bool:
        """Does a fix that the matcher could not vouch for (one line, or lines that disagree) put
        ``min_fit_gain`` more of the scan's points on walls than the guess (``guess_fit``)?
        ``fraction``: the fix's own fraction on walls, if the caller has it."""
        gain = self.config.min_fit_gain
        if gain is None or guess_fit is None or len(points) == 0:
            return False
        if fraction is None:
            fraction = self.fit_fraction(pose, points, kinds)
        if fraction < guess_fit + gain:
            return False
        self.counts["fixes_by_fit"] += 1
        return True

    def fix_fits_map(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...] = ("wall",),
                     guess_fit: float | None = None, fraction: float | None = None) -> bool:
        """Does a tracking fix put the scan on the map's walls about as well as recent fixes did,
        and about as well as the guess it corrects (``guess_fit``, its fraction on walls)?

        The fraction of ``points`` (robot frame) within the global matcher's inlier distance of
        a wall at ``pose`` is compared with the median of the last ``fit_window`` fixes that
        passed: below ``misfit_ratio`` times that the fix is a misfit (the robot is not where the
        filter thinks, e.g. kidnapped). Relative, so that clutter and unmapped furniture, which
        lower every fix's fraction alike, do not make good fixes misfits. With ``max_fit_loss``
        set, a fix whose fraction is below ``guess_fit`` by more than that is a misfit too: it
        moved the scan off walls that the guess had it on (a wrong correspondence).
        ``fraction``: the fix's own fraction on walls, if the caller has it."""
        loss = self.config.max_fit_loss if guess_fit is not None else None
        if not self.judges_fixes or len(points) == 0:
            return True
        if fraction is None:
            fraction = self.fit_fraction(pose, points, kinds)
        if loss is not None and guess_fit is not None and fraction < guess_fit - loss:
            self.counts["fit_losses"] += 1
            return False
        self._fix_fits.append(fraction)
        if self.config.misfit_ratio <= 0.0:
            return True
        recent = self._recent_fit
        if len(recent) >= 5 and fraction < self.config.misfit_ratio * statistics.median(recent):
            self.counts["misfits"] += 1
            return False
        recent.append(fraction)
        return True

    def fit_fractions(self, poses: NDArray, points: NDArray,
                      kinds: tuple[str, ...] = ("wall",)) -> NDArray[np.float64]:
        """:meth:`fit_fraction` at each of ``poses`` (P×3) at once."""
        if len(points) == 0:
            return np.zeros(len(poses))
        gm = self.config.global_match
        walls = wall_distance(self.map, tuple(kinds), gm.dt_cell)
        return (walls.at(poses, points[:, 0], points[:, 1]) <= gm.inlier_distance).mean(axis=1)

    def fit_fraction(self, pose: NDArray, points: NDArray,
                     kinds: tuple[str, ...] = ("wall",)) -> float:
        """The fraction of ``points`` (robot frame) on the map's segments of ``kinds`` at
        ``pose``."""
        if len(points) == 0:
            return 0.0
        return float(self.fit_fractions(np.asarray(pose, float).reshape(1, 3), points, kinds)[0])

    # ------------------------------------------------------------------ global mode
    def collecting_step(self, t: float, odom: NDArray, points: NDArray,
                        kinds: tuple[str, ...] = ("wall",),
                        hough: HoughConfig | None = None) -> Decision:
        """Accumulate a view; when there are enough, match the set; decide. While poses tie,
        each is also followed on every scan (``hough`` settings) and scored by how well the scan
        fits it: the tie breaks as soon as the views stop fitting all of them equally."""
        odom = np.asarray(odom, float)
        if self._bank is not None and hough is not None:
            decision = self._follow_bank(t, odom, points, hough)
            if decision.reset_pose is not None:
                return decision
        elif self.hypotheses and hough is not None:
            decision = self._follow_ties(t, odom, points, kinds, hough)
            if decision.reset_pose is not None:
                return decision
        if self._views and not self._moved_since_last_view(odom):
            return Decision()
        self._views.append(_View(odom, points))
        while len(self._views) > self.config.max_views:
            self._views.popleft()
        self._since_attempt += 1
        # retry every few views; once lost (repeated failures) back off: a global match costs
        # tens of scans, and the same views rarely give a different answer
        backoff = max(0, self._failures - self.config.failures_until_lost + 1)
        wait = self.config.retry_every * 2 ** min(backoff, 2) if self._failures else 0
        if self._bank is not None:  # followed poses are being weighed: new ones now and then
            wait = max(wait, self.config.retry_every)
        if len(self._views) < self.config.min_views or self._since_attempt < wait:
            return Decision()
        self._since_attempt = 0
        previous = self.state
        self._go(t, State.RELOCALIZING, f"{len(self._views)} views accumulated")
        pts = self.accumulated_points()
        _, _, lines = observe_lines(pts, self.config.global_match.hough)
        result = global_match(lines, pts, self.map, self.config.global_match, kinds=kinds)
        self.counts["global_matches"] += 1
        if self.config.hypotheses is not None and self.make_tracker is not None:
            return self._seed_bank(t, result)
        decision = self._decide(t, result, previous)
        decision.result = result
        return decision

    def _seed_bank(self, t: float, result: GlobalResult) -> Decision:
        """Follow the match's poses, each with its own filter (:mod:`fusion.hypotheses`)."""
        hyps = result.hypotheses
        if not hyps:
            self._failures += 1
            lost = self._failures >= self.config.failures_until_lost
            self._go(t, State.LOST if lost else State.COLLECTING,
                     f"no global hypothesis ({result.reason or 'none'})")
            return Decision(result=result)
        if self._bank is None:
            self._bank = self._new_bank()
        covs = [0.5 * (np.asarray(h.cov, float) + np.asarray(h.cov, float).T)
                + self._reinit_floor for h in hyps]
        poses = [np.asarray(h.pose, float) for h in hyps]
        self._bank.seed(t, self._views[-1].odom, poses, covs, [h.score for h in hyps],
                        [self._displacement_prior(pose) for pose in poses])
        self._log_hypotheses(t, hyps[:len(self._bank)])
        self._go(t, State.COLLECTING,
                 f"following {len(self._bank)} hypotheses (best score {hyps[0].score:.2f})")
        return Decision(result=result)

    def _new_bank(self) -> HypothesisBank:
        assert self.config.hypotheses is not None and self.make_tracker is not None
        return HypothesisBank(self.map, self.config.hypotheses, self.make_tracker,
                              self.fit_fractions)

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
        """The fit that all but ``fit_quantile`` of the accepted scans reached (None before 20
        of them): a pose taken must fit at least as well as tracking usually did."""
        assert self.config.hypotheses is not None
        if len(self._tracked_fits) < 20:
            return None
        return float(np.quantile(np.fromiter(self._tracked_fits, float),
                                 self.config.hypotheses.fit_quantile))

    def _displacement_prior(self, pose: NDArray) -> float:
        """How plausible a pose is from where tracking last was, carried by odometry:
        N(d; 0, ``kidnap_prior_sigma``²) in the distance d, over a floor of
        ``kidnap_probability`` for a robot carried anywhere; 1 without a belief (global
        start)."""
        sigma = self.config.kidnap_prior_sigma
        if sigma is None or self._prior is None or not self._views:
            return 1.0
        belief, _, odom = self._prior
        moved = compose(belief, relative(odom, self._views[-1].odom))
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
        self._failures = 0
        self.hypotheses = []
        self._views.clear()
        self._without_fix = 0
        self._go(t, State.TRACKING, f"relocalized: {verdict.reason}{why}")
        return Decision(verdict.pose, verdict.cov)

    def _moved_since_last_view(self, odom: NDArray) -> bool:
        step = relative(self._views[-1].odom, odom)
        return (math.hypot(step[0], step[1]) >= self.config.view_spacing
                or abs(step[2]) >= math.radians(self.config.view_spacing_deg))

    def accumulated_points(self) -> NDArray[np.float64]:
        """All views' points in the latest view's robot frame, by odometry."""
        latest = self._views[-1].odom
        chunks = [transform_points(relative(latest, v.odom), v.points) for v in self._views]
        pts = np.concatenate(chunks) if chunks else np.empty((0, 2))
        if len(pts) > self.config.max_points:
            pts = pts[np.linspace(0, len(pts) - 1, self.config.max_points).astype(int)]
        return pts

    def _decide(self, t: float, result: GlobalResult, previous: State) -> Decision:
        good = [h for h in result.hypotheses if h.score >= self.config.min_score]
        if not good:
            self._failures += 1
            lost = self._failures >= self.config.failures_until_lost
            self._go(t, State.LOST if lost else State.COLLECTING,
                     f"no global hypothesis ({result.reason or 'none scored enough'})")
            return Decision()
        top = good[0].score
        rivals = [h for h in result.hypotheses[1:] if h.score > top - self.config.decisive_margin]
        if result.ambiguous or rivals:
            tied = [good[0], *rivals]
            chosen = self._break_tie_with_prior(tied)
            if chosen is not None:
                return self._accept(t, chosen, "tie broken by the last tracked pose")
            if not self.hypotheses:  # a new tie: follow each of its poses from now on
                self.hypotheses = [np.asarray(h.pose, float) for h in tied]
                self._hyp_odom = self._views[-1].odom.copy()
                self._hyp_fit = [deque(maxlen=self.config.tie_window) for _ in tied]
                self._ties_slid = any(getattr(h, "slid", False) for h in tied)
            self.counts["ties"] += 1
            self._go(t, State.COLLECTING,
                     f"{len(tied)} hypotheses tie (score {top:.2f}): symmetric map, collecting")
            self._log_hypotheses(t, tied)
            return Decision()
        return self._accept(t, good[0], "")

    def _break_tie_with_prior(self, tied: list) -> object | None:
        """Of tied hypotheses, the one alone inside the gate of the tracker's belief when it was
        abandoned (carried by odometry, its covariance grown generously): a symmetric map only
        fools a robot without memory. None when there is no belief or it doesn't single one out
        (after a kidnap, the old belief holds none of them)."""
        if self._prior is None or not self._views:
            return None
        pose, cov, odom = self._prior
        moved = compose(pose, relative(odom, self._views[-1].odom))
        spread = cov + np.diag([0.5**2, 0.5**2, math.radians(15.0) ** 2])  # odometry since
        inside = []
        for h in tied:
            e = np.asarray(h.pose, float) - moved
            e[2] = wrap_scalar(e[2])
            if e @ np.linalg.solve(spread, e) <= gate_threshold(0.999, 3):
                inside.append(h)
        return inside[0] if len(inside) == 1 else None

    def _nearest_to_last_trusted(self, odom: NDArray) -> tuple[int | None, str]:
        """Of the followed tied poses, the one nearest the last trusted pose carried by
        odometry, when a displacement prior N(0, ``kidnap_prior_sigma``²) makes it
        ``kidnap_prior_odds`` times as likely as every rival: the views cannot tell them apart,
        and a robot that was pushed or carried is more plausibly near where it was than across
        the building. 3 m against 6 m from it (the next look-alike room) is 30 : 1 with σ = 2 m;
        3 m against 4 m is 3 : 1, a coin toss left to the evidence. None without a trusted pose
        (global start), when the poses were found by sliding along a corridor (the right one may
        have been dropped; the nearest would then be wrong and look right for as long as the
        corridor lasts), and when the pose it would replace came from this rule itself: a pose
        chosen by distance alone is no evidence for the next choice."""
        sigma = self.config.kidnap_prior_sigma
        if (sigma is None or self._last_trusted is None or self._ties_slid
                or len(self.hypotheses) < 2):
            return None, ""
        pose, trusted_odom = self._last_trusted
        moved = compose(pose, relative(trusted_odom, odom))
        dist = np.array([math.hypot(*(h[:2] - moved[:2])) for h in self.hypotheses])
        order = np.argsort(dist)
        nearest, next_nearest = dist[order[0]], dist[order[1]]
        log_odds = (next_nearest**2 - nearest**2) / (2 * sigma**2)
        if log_odds < math.log(self.config.kidnap_prior_odds):
            return None, ""
        return int(order[0]), (f"tie broken by the last trusted pose: {nearest:.1f} m from it, "
                               f"the next {next_nearest:.1f} m")

    def _fits_like_tracking(self, mean_fit: float) -> bool:
        """Does a followed pose fit the scans nearly as well as tracking did before it was
        abandoned (``tie_min_fit`` of the recent fixes' median; of 1 without any)? A small
        steady lead only ranks the tied poses; when the right pose is not among them, the best
        of the wrong ones leads too, but fits visibly worse than tracking did."""
        typical = float(np.median(self._recent_fit)) if self._recent_fit else 1.0
        return mean_fit >= self.config.tie_min_fit * typical

    def _accept(self, t: float, best, how: str) -> Decision:
        self._failures = 0
        self.hypotheses = []
        cov = np.array(best.cov, dtype=float)
        cov = 0.5 * (cov + cov.T) + self._reinit_floor
        self._views.clear()
        self._without_fix = 0
        self._log_hypotheses(t, [best])
        self._go(t, State.TRACKING, f"relocalized: score {best.score:.2f}, "
                                    f"{best.n_lines_explained} lines explained"
                                    + (f" ({how})" if how else ""))
        return Decision(np.asarray(best.pose, float), cov)

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
        hyps = self.carried_hypotheses(odom)
        if not hyps:
            return Decision()
        keep = []
        for h in hyps:
            predicted = math.atan2(position[1] - h[1], position[0] - h[0]) - h[2]
            if abs(wrap_scalar(predicted - bearing)) <= tolerance:
                keep.append(h)
        if len(keep) == len(hyps):
            return Decision()
        self.counts["landmark_prunes"] += 1
        if not keep:  # none fits: the tie was not between the right poses; start over
            self.hypotheses = []
            self._go(t, State.COLLECTING, f"{label} fits no hypothesis: collecting again")
            return Decision()
        self.hypotheses, self._hyp_odom = keep, np.asarray(odom, float).copy()
        if len(keep) > 1:
            return Decision()
        self._views.clear()
        self._without_fix = 0
        self._go(t, State.TRACKING, f"tie broken by {label} at {math.degrees(bearing):.0f}°")
        self.hypotheses = []
        cov = np.diag([0.1**2, 0.1**2, math.radians(3.0) ** 2])
        return Decision(keep[0], cov)

    def _follow_ties(self, t: float, odom: NDArray, points: NDArray, kinds: tuple[str, ...],
                     hough: HoughConfig) -> Decision:
        """Carry each tied pose by odometry, correct it with this scan when the scan fixes it,
        and record the fraction of the scan's points that lie on the map's walls there. A pose
        that leads all others by ``tie_lead`` over a full window is the pose; one that trails the
        best by twice that is dropped."""
        prior = np.diag([0.1**2, 0.1**2, math.radians(3.0) ** 2])
        observed = observe_lines(clean_points(points)[0], hough)  # one scan, every tied pose
        moved = []
        for pose, fit in zip(self.carried_hypotheses(odom), self._hyp_fit, strict=True):
            fix = localize_scan(points, self.map, pose, hough, pose_cov=prior, observed=observed)
            if fix.ok:
                pose = fix.pose
            fit.append(self.fit_fraction(pose, points, kinds))
            moved.append(pose)
        self.hypotheses, self._hyp_odom = moved, odom.copy()
        means = np.array([np.mean(f) for f in self._hyp_fit])
        best = int(np.argmax(means))
        keep = means >= means[best] - 2 * self.config.tie_lead
        if not keep.all():
            self.hypotheses = [h for h, k in zip(self.hypotheses, keep, strict=True) if k]
            self._hyp_fit = [f for f, k in zip(self._hyp_fit, keep, strict=True) if k]
            means = means[keep]
            best = int(np.argmax(means))
        full = all(len(f) == self.config.tie_window for f in self._hyp_fit)
        if not full:
            return Decision()
        others = np.delete(means, best)
        rival = others.max() if len(others) else 0.0
        chosen, by_distance = None, False
        if len(others) == 0 or means[best] - rival >= self.config.tie_lead:
            chosen = best
        elif self._leads_every_scan(best) and self._fits_like_tracking(means[best]):
            chosen = best
        else:
            nearest, why = self._nearest_to_last_trusted(odom)
            if nearest is not None and means[nearest] >= means[best] - self.config.tie_lead:
                chosen, by_distance = nearest, True
        if chosen is None:
            return Decision()
        pose = self.hypotheses[chosen]
        self.hypotheses, self._hyp_fit = [], []
        self._views.clear()
        self._without_fix = 0
        if by_distance:
            self.counts["ties_broken_by_distance"] += 1
            self._go(t, State.TRACKING, f"{why}; {means[chosen]:.2f} of the points on walls")
            self._trusted_by_prior_only = True
        else:
            self._go(t, State.TRACKING, f"tie broken: {means[best]:.2f} of the points on walls "
                                        f"at one pose, {rival:.2f} at the next best")
        return Decision(pose, self._reinit_floor)

    def _leads_every_scan(self, best: int) -> bool:
        """Does tied pose ``best`` fit better than every other on each scan of the window, by
        ``tie_steady_lead`` on average? A few points more on walls in every one of ten scans
        (a wall glimpsed through a door at one pose only) is evidence, however small; a lead
        that comes and goes is clutter."""
        if self.config.tie_steady_lead is None:
            return False
        fits = np.array([list(f) for f in self._hyp_fit])  # hypotheses × window
        lead = fits[best] - np.delete(fits, best, axis=0).max(axis=0)
        return bool((lead > 0).all() and lead.mean() >= self.config.tie_steady_lead)

    def carried_hypotheses(self, odom: NDArray) -> list[NDArray[np.float64]]:
        """The tied hypotheses moved by the odometry since they were found."""
        if not self.hypotheses or self._hyp_odom is None:
            return []
        step = relative(self._hyp_odom, odom)
        return [compose(h, step) for h in self.hypotheses]

    def _go(self, t: float, new: State, reason: str) -> None:
        if new is self.state and new is not State.COLLECTING:
            return
        if new is State.COLLECTING and self.state is State.TRACKING:
            self._views.clear()
            self._bank = None
            self._failures = 0
            self._since_attempt = 0
            self._follow_belief(t)
            if self._trusted_by_prior_only:  # it may have been the wrong one of the tie
                self._last_trusted = None
                self._trusted_by_prior_only = False
        if new is State.LOST:
            self._prior = None  # no belief to break ties with
        if new is State.TRACKING:
            self._trusted_by_prior_only = False  # set again by the caller when it is so
        self.transitions.append(Transition(t, self.state, new, reason))
        self.counts[f"{self.state.value}->{new.value}"] += 1
        self.state = new
        if self.logger is not None:
            self.logger.log_state(t, new.value, reason)

    def _log_hypotheses(self, t: float, hyps: list) -> None:
        if self.logger is not None:
            self.logger.log_hypotheses(t, np.array([h.pose for h in hyps]),
                                       np.array([h.score for h in hyps]))

    def summary(self) -> dict:
        return {"state": self.state.value, "transitions": len(self.transitions),
                "counts": dict(self.counts),
                "log": [{"t": round(tr.t, 3), "from": tr.old.value, "to": tr.new.value,
                         "reason": tr.reason} for tr in self.transitions[-50:]]}


def _polished(fix: ScanCorrection, guess: NDArray, sigma_along: float = 0.3
              ) -> tuple[NDArray, NDArray] | None:
    """A local re-search candidate from a fix tracked from it: a full fix as it is; one that
    observes the heading and the position across the walls in view only (a corridor, or one
    wall of a cluttered room) keeps the guess's position along them, ``sigma_along`` uncertain
    (the fix cannot say where along the corridor the start was, so every start along it gives
    the same candidate and none of them is a rival). None when ambiguous or without heading."""
    if fix.ambiguous or fix.rank < 2:
        return None
    if fix.rank == 3:
        return fix.pose, fix.cov
    v = fix.unobservable  # 3×1, in x, y
    along = v @ v.T
    pose = fix.pose - along @ (fix.pose - guess)
    return pose, fix.cov + (sigma_along**2 - UNOBSERVED_VARIANCE) * along


def _sweep(guess: NDArray, radius_xy: float, radius_theta: float,
           step_xy: float = 0.25, step_theta: float = math.radians(2.0)) -> NDArray[np.float64]:
    """The guess turned by every ``step_theta`` within ``radius_theta``, and moved along its
    heading by every ``step_xy`` within ``radius_xy`` (forwards and backwards)."""
    turns = np.arange(step_theta, radius_theta + 1e-9, step_theta)
    turns = np.concatenate(([0.0], turns, -turns))
    moves = np.arange(step_xy, radius_xy + 1e-9, step_xy)
    moves = np.concatenate((moves, -moves))
    turned = np.tile(guess, (len(turns), 1))
    turned[:, 2] = wrap_angle(turned[:, 2] + turns)
    moved = np.tile(guess, (len(moves), 1))
    moved[:, :2] += moves[:, None] * np.array([math.cos(guess[2]), math.sin(guess[2])])
    return np.concatenate((turned, moved))


def _same_pose(a: NDArray, b: NDArray, xy: float = 0.3,
               theta: float = math.radians(5.0)) -> bool:
    return bool(math.hypot(a[0] - b[0], a[1] - b[1]) <= xy
                and abs(wrap_scalar(a[2] - b[2])) <= theta)


def visible_parallel_spacing(theta: NDArray, rho: NDArray, angle_tol: float = math.radians(2.0),
                             min_gap: float = _SAME_WALL_GAP) -> float:
    """The smallest ρ difference between references seen at the same robot-frame θ: the lines
    that nearest-neighbour matching can confuse from here (inf if there are none)."""
    if len(theta) < 2:
        return math.inf
    dth = np.abs(wrap_angle(theta[:, None] - theta[None, :]))
    gap = np.abs(rho[:, None] - rho[None, :])
    # pieces of one wall a few centimetres apart (a map built from scans) are one wall
    close = (dth < angle_tol) & (gap > min_gap)
    return float(gap[close].min()) if close.any() else math.inf


def _closest_parallel_spacing(m: SegmentMap, angle_tol: float = math.radians(2.0)) -> float:
    """The smallest distance between two parallel map lines (how far nearest-neighbour matching
    can be trusted); large when no two lines are parallel.

    Lines sorted by direction (mod π) are compared with their k-th neighbour for k = 1, 2, …
    while some pair is still within ``angle_tol``: memory stays linear in the lines, and time
    grows with the size of the largest family of parallel lines, not with its square of all."""
    a, r = m.line_alpha, m.line_r
    n = len(a)
    if n < 2:
        return math.inf
    folded = np.mod(a, np.pi)
    order = np.argsort(folded)
    # the circle of directions, unrolled once so that lines near 0 and near π are neighbours
    ext = np.concatenate((order, order))
    ext_dir = np.concatenate((folded[order], folded[order] + np.pi))
    best = math.inf
    for k in range(1, n):
        i, j = ext[:n], ext[k:k + n]
        close = ext_dir[k:k + n] - ext_dir[:n] < angle_tol
        if not close.any():
            break
        i, j = i[close], j[close]
        same_sense = np.abs(a[i] - a[j]) < np.pi / 2
        gap = np.abs(np.where(same_sense, r[i] - r[j], r[i] + r[j]))
        gap = gap[gap > 0.05]
        if gap.size:
            best = min(best, float(gap.min()))
    return best

"""The ambiguity manager: when tracking can't be trusted, switch to the paper's global strategy
(ii) — accumulate several views, match the whole set of peaks to the whole map — and back.

States and triggers (:class:`fusion.status.State`)::

    tracking ──(scans without a usable fix: ambiguous, rejected, misfits (fixes that put the
    │           scan off the walls) or none, while the prediction no longer fits the scan
    │           either, that see through the map's walls from the belief; covariance too
    │           large for the line spacing in view; a local re-search's pose after the robot
    │           was carried, or with the position along a corridor unobserved)──▶ collecting
    collecting ──(enough views, spaced by motion)──▶ relocalizing (a global match, spread
    │            over scans: ``match_lookups_per_scan`` of it each)
    relocalizing ──▶ collecting, its poses followed, each by its own filter
                     (:mod:`fusion.hypotheses`), tracking's last belief among them
                 ──(nothing fits, repeatedly)──▶ lost (still collecting)
    collecting ──(a followed pose the scans keep fitting, clearly ahead of the rest)──▶ tracking
    no initial pose ──▶ lost

Where tracking is given up: :meth:`AmbiguityManager.tracking_step`, on the evidence
:class:`~fusion.ambiguity.tracking.TrackingWatch` keeps. Where a pose is taken back:
:meth:`AmbiguityManager.collecting_step`, through
:class:`~fusion.ambiguity.relocalization.Relocalization`.

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

from fusion.ambiguity.fit import ScanFit
from fusion.ambiguity.local_search import LocalSearch
from fusion.ambiguity.relocalization import Decision, Relocalization, reinit_floor
from fusion.ambiguity.tracking import Belief, TrackingWatch
from fusion.decision import TrackingScan, Verdict
from fusion.hypotheses import MakeTracker
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.status import ScanStatus, State
from fusion.visualize import Logger
from houghloc import HoughConfig, ScanCorrection, SegmentMap
from houghloc.geometry import wrap_scalar
from houghloc.global_match import prepare_map
from houghloc.jit import one_blas_thread
from houghloc.matching import gate_threshold

__all__ = ["AmbiguityManager", "Decision", "Transition"]

SUMMARY_TRANSITIONS = 50
"""the latest transitions metrics.json lists (all are counted)"""
LANDMARK_BEARING_TOLERANCE_DEG = 15.0
"""°: 3σ of a recognised landmark's bearing, where the caller gives none"""


@dataclass(frozen=True, slots=True)
class Transition:
    t: float
    old: State
    new: State
    reason: str


@dataclass
class AmbiguityManager:
    """The state machine between tracking and global localization (module docstring).

    Its states' work is done by its parts: while tracking, :class:`TrackingWatch` (the
    evidence for giving tracking up) and :class:`LocalSearch` (a pose near the
    guess after a slip); otherwise :class:`Relocalization` (views, global matches, followed
    hypotheses). What is left here is every transition and what it resets, so that the
    state machine reads in one place (:meth:`_go`)."""

    map: SegmentMap
    config: AmbiguityConfig = field(default_factory=AmbiguityConfig)
    state: State = State.TRACKING
    transitions: list[Transition] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)
    logger: Logger | None = None
    # a filter at a pose with a covariance, for each followed hypothesis (the Localizer's own
    # settings); None: a manager that only tracks (a global match would have nothing to follow
    # its poses with)
    make_tracker: MakeTracker | None = None

    def __post_init__(self) -> None:
        self.fit = ScanFit(self.map, self.config, self.counts)
        self.belief = Belief()
        self.watch = TrackingWatch(self.map, self.config, self.fit, self.belief)
        self._local = LocalSearch(self.map, self.config, self.fit, self.counts)
        self.relocalization = Relocalization(self.map, self.config, self.fit, self.belief,
                                             self.counts, self._go, self.logger,
                                             self.make_tracker)

    def prepare(self, kinds: tuple[str, ...]) -> None:
        """Build the map's look-ups that global matching and the scan fit use for ``kinds``
        (cached on the map)."""
        prepare_map(self.map, self.config.global_match, kinds)

    def start_lost(self, t: float, reason: str) -> None:
        self._go(t, State.LOST, reason)

    def on_odometry(self, t: float, x: float, y: float, theta: float,
                    unmeasured: float = 0.0) -> None:
        """An odometry reading the localizer's filter took: the followed poses take it too."""
        bank = self.relocalization.bank
        if bank is not None:
            bank.on_odometry(t, x, y, theta, unmeasured)

    def correct_odometry(self, t: float, pose: NDArray, since: float, step_cov: NDArray,
                         step_scale: NDArray) -> None:
        """A corrected odometry pose the localizer's filter took: the followed poses take it."""
        bank = self.relocalization.bank
        if bank is not None:
            bank.correct_odometry(t, pose, since, step_cov, step_scale)

    # ------------------------------------------------------------------ tracking
    def re_search(self, scan: TrackingScan, status: ScanStatus, verdict: Verdict,
                  fix: ScanCorrection, odometry: Callable[[], NDArray | None]) -> Decision | None:
        """After a tracking scan's update (``status``): when the scan fits worse than usual (at
        the guess if no fix was accepted, at the fix if one was), the local search near the
        guess (:meth:`local_search`), bounded by the motion since the last accepted fix
        (``odometry()``: the odometry at the scan, asked only then); None when none was
        wanted."""
        guess_fit = verdict.guess_fit
        fix_fit = verdict.fix_fit if status == ScanStatus.ACCEPTED else None
        if guess_fit is None or not self.wants_local_search(guess_fit, fix_fit):
            return None
        # tracking failed and the prediction no longer fits: the odometry slipped, or
        # reported a motion the robot did not make. Look for the pose near it first.
        return self.local_search(scan, fix, max(guess_fit, fix_fit or 0.0), odometry())

    def wants_local_search(self, guess_fit: float | None, fix_fit: float | None = None) -> bool:
        """Is a local re-search on, and does the scan fit worse than usual
        (:meth:`ScanFit.worse_than_usual`)?"""
        if (self.config.local_search_xy is None or guess_fit is None
                or self.state is not State.TRACKING):
            return False
        return self.fit.worse_than_usual(guess_fit, fix_fit)

    @one_blas_thread  # global matching's arrays: see one_blas_thread
    def local_search(self, scan: TrackingScan, fix: ScanCorrection, guess_fit: float,
                     odom: NDArray | None) -> Decision:
        """The pose near the scan's guess that the scan fits (:class:`LocalSearch`; its heading
        reach grows with the guess's covariance), within reach of the odometry ``odom``'s
        motion since the last accepted fix: it re-initialises the filter."""
        t, guess, guess_cov, hough = scan.t, scan.guess, scan.guess_cov, scan.hough
        found = self._local.find(guess, scan.points, fix, scan.kinds, guess_fit, hough,
                                 self.belief.moved_since_trusted(odom), guess_cov)
        if found.pose is None or found.cov is None:
            return Decision(result=found.result)
        shift = found.pose - np.asarray(guess, float)
        if self.logger is not None:
            self.logger.log_state(t, self.state.value, (
                f"local re-search: moved {math.hypot(shift[0], shift[1]):.2f} m, "
                f"{math.degrees(wrap_scalar(shift[2])):.1f}°; {found.fit:.2f} of the points on "
                f"walls (guess {guess_fit:.2f})"))
        cov = 0.5 * (found.cov + found.cov.T) + reinit_floor(self.config)
        carried = scan.scans_broke and self._unexplained(shift, guess_cov, hough)
        if (carried or found.along_kept) and odom is not None:
            # The search explains a motion the odometry did not report, and the neighbourhood
            # searched does not bound it: the robot was carried (``scans_broke``: this scan
            # fitted its predecessor nowhere near the wheels' increment, and the odometry's
            # noise cannot explain the shift found either), or the scan did not observe the
            # position along the corridor in view (the pose found keeps the guess's). The same
            # motion may have carried the robot to a look-alike place beyond the neighbourhood
            # (a door further on). The pose is followed as tracking's belief while a global
            # match, of this view at once, proposes its rivals; it is taken when the scans
            # single it out (mode_probability is 0 until then).
            self.belief.prior = (found.pose.copy(), cov.copy(), np.asarray(odom, float).copy())
            self._go(t, State.COLLECTING, "local re-search: the odometry missed a motion; a "
                     "global match contests the pose found")
            self.relocalization.views.first_match_views = 1
        return Decision(found.pose, cov, found.result)

    @staticmethod
    def _unexplained(shift: NDArray, guess_cov: NDArray | None, hough: HoughConfig) -> bool:
        """Is the local re-search's ``shift`` from the guess beyond what the guess's covariance
        (the odometry's noise since the last fix) holds with the matcher's
        ``gate_probability``: (Δx, Δy, Δθ) P⁻¹ (Δx, Δy, Δθ)ᵀ > χ²₃(p)? Without a covariance
        nothing bounds it."""
        if guess_cov is None:
            return True
        d = np.array((shift[0], shift[1], wrap_scalar(float(shift[2]))))
        try:
            nis = float(d @ np.linalg.solve(guess_cov, d))
        except np.linalg.LinAlgError:
            return True
        return nis > gate_threshold(hough.gate_probability, 3)

    def tracking_step(self, t: float, status: ScanStatus, cov: NDArray,
                      pose: NDArray | None = None, odom: NDArray | None = None,
                      in_view: tuple[NDArray, NDArray] | None = None,
                      guess_fit: float | None = None, points: NDArray | None = None,
                      kinds: tuple[str, ...] = ("wall",)) -> None:
        """After a tracking scan: **where tracking is given up**, for the reason
        :meth:`TrackingWatch.give_up_reason` gives. In short: when the scans without a usable
        fix since the last one contradict the belief ``pose``, having seen
        ``through_wall_scans`` scans' worth of their ``points`` through the map's walls (scans
        whose ``guess_fit`` holds up do not count), or when the position's σ is too large for
        the parallel lines in view (``in_view``)."""
        if self.state is not State.TRACKING:
            return
        reason = self.watch.give_up_reason(status, cov, pose, odom, in_view, guess_fit, points,
                                           kinds)
        if reason is not None:
            self._go(t, State.COLLECTING, reason)

    # ------------------------------------------------------------------ global mode
    @one_blas_thread
    def collecting_step(self, t: float, odom: NDArray, points: NDArray,
                        kinds: tuple[str, ...] = ("wall",),
                        hough: HoughConfig | None = None) -> Decision:
        """**Where a pose is taken back.** Every followed hypothesis takes this scan
        (``hough`` settings) and the bank may name the pose; else the view is accumulated and,
        when there are enough, the set is matched and its poses are followed
        (:meth:`Relocalization.step`)."""
        return self.relocalization.step(t, np.asarray(odom, float), points, kinds, hough)

    def landmark_step(self, t: float, odom: NDArray, position: tuple[float, float],
                      bearing: float, label: str,
                      tolerance: float = math.radians(LANDMARK_BEARING_TOLERANCE_DEG)
                      ) -> Decision:
        """A recognised landmark seen at ``bearing``: followed hypotheses are weighed by it
        (``tolerance`` is its 3σ); when one's weight is enough, it is the pose."""
        return self.relocalization.landmark_step(t, odom, position, bearing, label, tolerance)

    @property
    def followed(self) -> list[tuple[NDArray[np.float64], float]]:
        """Every followed hypothesis's pose and weight, likeliest first (none while tracking)."""
        bank = self.relocalization.bank
        if bank is None:
            return []
        return [(h.pose.copy(), h.weight) for h in sorted(bank.hypotheses, key=lambda h: -h.weight)]

    @property
    def leading_hypothesis(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The pose and covariance of the likeliest followed hypothesis, None if none is."""
        bank = self.relocalization.bank
        if bank is None or not len(bank):
            return None
        return bank.leader.pose, bank.leader.cov

    @property
    def mode_probability(self) -> float:
        """The probability that the reported pose's filter is around the right place at all
        (:mod:`fusion.integrity`): while tracking, 1 less the share of the evidence that gives
        tracking up gathered since the last usable fix; while hypotheses are followed, the
        leader's weight times the chance that its fits pass the bank's test
        (:meth:`HypothesisBank.leader_probability`), 0 before a global match has proposed
        rivals to it or before it was weighed, while collecting views with none, or lost."""
        if self.state is State.TRACKING:
            return 1.0 - self.watch.evidence_against
        bank = self.relocalization.bank
        if bank is None:
            return 0.0  # no hypothesis: nothing is followed
        # read as the bank's verdict reads it: 0 before a rival is proposed (nothing to weigh
        # the leader against), little while its fits say none of the poses followed is right
        return bank.leader_probability(self.relocalization.least_right_fit())

    # ------------------------------------------------------------------ transitions
    def _go(self, t: float, new: State, reason: str) -> None:
        """Every transition, with what it resets; recorded, counted and logged with its
        reason."""
        if new is State.TRACKING:  # a pose taken: the evidence against tracking starts again
            self.watch.fix_found()
        if new is self.state and new is not State.COLLECTING:
            return
        belief = self.belief
        if new is State.COLLECTING and self.state is State.TRACKING:
            self.relocalization.start(t)
        if new is State.LOST:
            belief.prior = None  # no belief to seed the followed poses with
        if new is State.TRACKING or self.state is State.TRACKING:
            self.relocalization.match = None  # a match under way is for the views it started from
        self.transitions.append(Transition(t, self.state, new, reason))
        self.counts[f"{self.state.value}->{new.value}"] += 1
        self.state = new
        if self.logger is not None:
            self.logger.log_state(t, new.value, reason)

    def summary(self) -> dict:
        return {"state": self.state.value, "transitions": len(self.transitions),
                "counts": dict(self.counts),
                "log": [{"t": round(tr.t, 3), "from": tr.old.value, "to": tr.new.value,
                         "reason": tr.reason} for tr in self.transitions[-SUMMARY_TRANSITIONS:]]}

"""Several pose hypotheses tracked at once, each by its own filter, weighted by how the scans fit.

Global set matching (the paper's strategy (ii)) proposes poses from accumulated views; its score
alone cannot tell a right pose from a wrong one in a building whose rooms and corridors repeat
(docs/experiments.md: right poses score 0.29–0.77, wrong ones 0.31–0.65 on seattle). What does
tell them apart is time: a right pose keeps fitting the scans as the robot moves, a wrong one
falls behind within a few scans. So each proposed pose gets its own :class:`PoseTracker` with the
Hough fixes as measurements, and a weight updated by Bayes' rule with every scan::

    w_h ← w_h · L_h / Σ_k w_k · L_k,      L_h = max(Π_c p_c^(n s_hc), ε · max_k L_k)

(:func:`scan_log_likelihood`). Each point of the scan, placed at the hypothesis's pose after its
fix, is of one of three kinds c: on a wall that the robot there sees directly (within the inlier
distance: a likelihood field with a box kernel, cheap), seen *through* a wall, or neither (a
person, a cupboard, a room the map lacks); ``s_hc`` are their shares of the scan. ``p_c`` is how
often a point is of kind c at the right pose, measured at the reference poses of real logs
(``hit_probability``, ``through_probability``): a pose that puts points on walls is likelier, one
from which the robot would have seen through walls much less likely, and clutter, which a right
pose meets too, weighs between them. A wall the scan is seen through onto the walls beyond it may
be glass (or a door the map shows closed): that is one fact about the building, not new evidence
with every scan, so a hypothesis may take it for glass once, at the odds of the prior
``glass_probability``, when its points there outweigh that, and sees through it from then on
(points seen through onto nothing stay evidence against it). The walls tracking saw through
before it was given up are glass already for every pose followed from then on
(:meth:`fusion.ambiguity.fit.ScanFit.learn_glass`): a right pose does not pay for them again,
where a pose tracking never was at could otherwise lose to one that sees nothing at all.
Tracking's belief, carried by
odometry, may be in a room the map lacks, where most points land on nothing: its likelihood allows
for that (``mapped_probability``), so scans that land on nothing are no evidence against it, as
they do not give tracking up; a pose a global match proposed claims that the map shows it. ``n`` is
the number of independent observations a scan is worth (its points on one wall err together, so a
scan of 360 points is worth far fewer), and ε the probability that a scan taken at the right pose
fits the map no better than at a wrong one (furniture moved, a room the map lacks): without it one
scan could weigh 5·10⁴ against a right pose that puts 0.15 of it on walls where a wrong one puts
0.5 (Intel in a map of another run), and no scan should weigh more than 1/ε. Weights are updated
only once the robot has moved about a doorway's width since the last update (as AMCL does,
farther): scans from nearly one place repeat one observation. A pose a later match proposes again
is the pose followed, not new evidence for it. Hypotheses that meet are merged (their weights add),
those whose weight falls below a probability are dropped, and one whose weight reaches the
acceptance probability is the pose, provided its scans fit about as well as tracking's did and see
through walls no more than at a right pose: when no proposed pose is right, the best of them still
gets most of the weight. The second test is read against the map, not against tracking: in a place
the map lacks tracking drifts too, and the fits it accepted there lower its own bar, while the best
look-alike elsewhere in the map still sees through its walls. Tracking's belief when it
was given up is followed too, from the start: a right belief is taken back, a wrong one falls
behind; but no pose is taken before a global match has proposed rivals to it.

References: Arras, Castellanos, Tomatis, Siegwart, "Feature-based multi-hypothesis localization
and tracking using geometric constraints", RAS 44 (2003); Jensfelt & Kristensen, "Active global
localization for a mobile robot using multiple hypothesis tracking", IEEE T-RA 17(5) (2001).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray

from fusion.settings.hypotheses import RECENT_FITS, HypothesisConfig
from fusion.tracker import PoseTracker
from houghloc import HoughConfig, localize_scan
from houghloc.geometry import relative, wrap_scalar
from houghloc.localize import observe_lines
from houghloc.matching import gate_threshold
from houghloc.scan_points import clean_points
from houghloc.segment_map import SegmentMap

MakeTracker = Callable[[NDArray[np.float64], NDArray[np.float64], float], PoseTracker]
"""``(pose, cov, t)``: a filter whose estimate at time t is the pose, given the odometry since"""
GlassShares = Callable[[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.bool_]], int],
                       tuple[NDArray[np.float64], list[NDArray[np.intp]]]]
"""``(poses, points, glass, glass_points)``: the P×3 shares of the points on a wall seen
directly, through a wall and neither at each pose, the pose's ``glass`` walls (per map segment)
seen through onto the walls beyond, and the walls newly taken for glass at each pose: those that
``glass_points`` or more points on walls were seen through
(:meth:`fusion.ambiguity.fit.ScanFit.shares_with_glass`)"""


def scan_log_likelihood(shares: NDArray[np.float64], config: HypothesisConfig,
                        belief: bool = False) -> NDArray[np.float64]:
    """log L at each of P poses from the P×3 ``shares`` s of a scan's points on a wall seen
    directly, seen through a wall, and neither (:meth:`ScanFit.shares`).

    Where the map shows the robot's surroundings (probability m = ``mapped_probability``), the
    kinds of n = ``independent_points`` observations come with probabilities p =
    (``hit_probability``, ``through_probability``, the rest); where it does not (a room the
    map lacks), with q = (``unmapped_hit_probability``, ``unmapped_through_probability``, the
    rest): most points land on nothing. A pose proposed by matching the scan to the map claims
    that the map shows it, L = m Πp_c^(n s_c); the filter's ``belief``, carried by odometry,
    claims nothing, L = m Πp_c^(n s_c) + (1 − m) Πq_c^(n s_c): scans that land where the map
    has nothing are no evidence against it (as they do not give tracking up), scans seen
    through its walls are."""
    s = np.asarray(shares, float)
    n = config.independent_points
    p = np.array([config.hit_probability, config.through_probability,
                  1.0 - config.hit_probability - config.through_probability])
    mapped = math.log(config.mapped_probability) + n * (s @ np.log(p))
    if not belief:
        return mapped
    q = np.array([config.unmapped_hit_probability, config.unmapped_through_probability,
                  1.0 - config.unmapped_hit_probability - config.unmapped_through_probability])
    return np.logaddexp(mapped, math.log(1.0 - config.mapped_probability) + n * (s @ np.log(q)))


def glass_points(config: HypothesisConfig, n_points: int) -> int:
    """The fewest points on walls seen through one wall of a scan of ``n_points`` for which
    taking that wall for glass explains the scan better, prior included: each such point moves
    from seen through (p_t = ``through_probability``) to on a wall seen (p_h =
    ``hit_probability``), worth n / N · log(p_h / p_t) with n = ``independent_points`` of N
    points, and the wall costs log(1 / ``glass_probability``) once."""
    per_point = config.independent_points / max(n_points, 1) * math.log(
        config.hit_probability / config.through_probability)
    return max(1, math.ceil(math.log(1.0 / config.glass_probability) / per_point))


def glass_log_odds(config: HypothesisConfig, on_walls: NDArray[np.int_],
                   off_walls: NDArray[np.int_], n_points: int) -> NDArray[np.float64]:
    """The log odds that a wall the robot saw ``on_walls`` + ``off_walls`` points of a scan of
    ``n_points`` through is glass, ``on_walls`` of them lying on the walls beyond it: behind
    glass they lie on walls as at the right pose (``hit_probability``); behind a wall the
    laser cannot pass, only a wrong pose puts points, and they lie on walls by chance, as in a
    room the map lacks (``unmapped_hit_probability``). Each point is worth n / N of an
    independent observation (n = ``independent_points``), and the prior odds are
    ``glass_probability`` : 1 − ``glass_probability``."""
    p, q = config.hit_probability, config.unmapped_hit_probability
    per_point = config.independent_points / max(n_points, 1)
    g = config.glass_probability
    return (math.log(g / (1.0 - g)) + per_point * (
        np.asarray(on_walls, float) * math.log(p / q)
        + np.asarray(off_walls, float) * math.log((1.0 - p) / (1.0 - q))))


def moved_since(last: NDArray[np.float64] | None, odom: NDArray[np.float64],
                config: HypothesisConfig) -> bool:
    """Has the robot moved ``update_distance`` or turned ``update_angle_deg`` between the
    odometry ``last`` (None: nothing looked at yet) and ``odom``? Scans closer together see the
    same walls from nearly one place: one observation, not several."""
    if last is None:
        return True
    step = relative(last, np.asarray(odom, float))
    return (math.hypot(step[0], step[1]) >= config.update_distance
            or abs(step[2]) >= math.radians(config.update_angle_deg))


@dataclass
class Hypothesis:
    """One followed pose: its filter, its weight, the fits of its latest weighed scans and how
    many it has been weighed on."""

    tracker: PoseTracker
    weight: float
    origin: str  # "tracked" (the belief when tracking was given up) or "global match"
    glass: NDArray[np.bool_]
    """per segment of the map: the walls this pose has taken for glass (its scans saw through
    them onto the walls beyond), seen through from then on"""
    fits: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_FITS))
    throughs: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_FITS))
    """the shares of its latest weighed scans' points seen through walls (glass taken)"""
    updates: int = 0

    @property
    def pose(self) -> NDArray[np.float64]:
        return self.tracker.pose

    @property
    def cov(self) -> NDArray[np.float64]:
        return self.tracker.cov


@dataclass
class BankVerdict:
    """After a scan: the pose taken (None while undecided) and why."""

    pose: NDArray[np.float64] | None = None
    cov: NDArray[np.float64] | None = None
    reason: str = ""


class HypothesisBank:
    """The hypotheses proposed by global matches, followed until one is the pose."""

    def __init__(self, map: SegmentMap, config: HypothesisConfig,
                 make_tracker: MakeTracker,
                 fit: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
                 shares: GlassShares, known_glass: NDArray[np.bool_] | None = None) -> None:
        """``make_tracker(pose, cov, t)``: a filter whose estimate at time t is the pose, with
        the odometry since; ``fit(poses, points)``: the fraction
        of the points (robot frame) on walls at each of the P×3 poses, what the verdict compares
        with tracking's; ``shares``: the shares of the points on a wall seen directly, through
        a wall and neither at each pose, with the walls it takes for glass
        (:data:`GlassShares`), what the weights follow (:func:`scan_log_likelihood`);
        ``known_glass``: per segment of the map, the walls tracking saw through onto the walls
        beyond (shared, it grows while tracking), which a pose followed from then on has taken
        for glass already."""
        self.map = map
        self.config = config
        self._make_tracker = make_tracker
        self._fit = fit
        self._shares = shares
        # walls tracking saw through before (glass is a fact about the building): a pose
        # followed from now on does not pay for them again
        self._known_glass = known_glass
        self._merge_gate = gate_threshold(config.merge_probability, 3)
        self._z_accept = NormalDist().inv_cdf(config.accept_probability)
        self.hypotheses: list[Hypothesis] = []
        self._last_update: NDArray[np.float64] | None = None  # odometry at the last weighing
        # a pose is taken only once global matching has proposed rivals to it: tracking's own
        # belief, alone, would be taken back by the fits it learnt while it was wrong
        self._contested = False

    def __len__(self) -> int:
        return len(self.hypotheses)

    @property
    def contested(self) -> bool:
        """Has a global match proposed rivals to the followed poses (only then can a leader's
        weight say how likely it is)?"""
        return self._contested

    def seed(self, t: float, odom: NDArray[np.float64], poses: list[NDArray[np.float64]],
             covs: list[NDArray[np.float64]], scores: list[float],
             priors: list[float] | None = None, origin: str = "global match") -> None:
        """Follow ``poses`` (at time ``t``, the odometry then ``odom``) from now on, weighted by
        their match ``scores`` times their ``priors`` (how plausible each place is before any
        view: 1 each if not given) to begin with; ``origin`` says where they come from."""
        priors = [1.0] * len(poses) if priors is None else priors
        self._contested |= origin == "global match"
        # poses proposed while others are followed join them as newcomers, the best-scored
        # starting level with the leader times its prior. The prior weighs against a newcomer
        # as it would have at the start: a place far from where tracking was is a kidnap
        # (``kidnap_probability``), however well it scores, and the scans overturn that in a
        # few weighings (each may weigh up to 1/ε) if it is right. A newcomer that is a followed
        # pose is that pose: its score and prior are in its weight already, and adding them
        # again with every match would favour the look-alike nearest the old belief a little
        # more each time, whatever the scans say
        if self.hypotheses:
            scale = max(h.weight for h in self.hypotheses) / max(max(scores), 1e-6)
        else:
            scale = 1.0 / (sum(s * p for s, p in zip(scores, priors, strict=True)) or 1.0)
        followed = list(self.hypotheses)
        for pose, cov, score, prior in list(zip(poses, covs, scores, priors, strict=True))[
                :self.config.max_hypotheses]:
            pose, cov = np.asarray(pose, float), np.asarray(cov, float)
            if any(self._same_pose(pose, cov, h) for h in followed):
                continue
            tracker = self._make_tracker(pose, cov, t)
            glass = (np.zeros(len(self.map.starts), dtype=bool) if self._known_glass is None
                     else self._known_glass.copy())
            self.hypotheses.append(Hypothesis(tracker, scale * max(score * prior, 1e-6), origin,
                                              glass))
        if self._last_update is None:
            self._last_update = np.asarray(odom, float).copy()
        self._merge()
        self._prune()

    def on_odometry(self, t: float, x: float, y: float, theta: float,
                    unmeasured: float = 0.0) -> None:
        """An odometry reading, as the localizer's filter took it: every hypothesis's filter
        takes it too, so that each predicts with the same motion at the same times."""
        for h in self.hypotheses:
            h.tracker.on_odometry(t, x, y, theta, unmeasured)

    def correct_odometry(self, t: float, pose: NDArray[np.float64], since: float,
                         step_cov: NDArray[np.float64], step_scale: NDArray[np.float64]) -> None:
        """A corrected odometry pose the localizer's filter took (scan odometry): the same for
        every hypothesis's filter (:meth:`fusion.tracker.PoseTracker.correct_odometry`)."""
        for h in self.hypotheses:
            h.tracker.correct_odometry(t, pose, since, step_cov, step_scale)

    def step(self, t: float, odom: NDArray[np.float64], points: NDArray[np.float64],
             hough: HoughConfig, least_fit: float | None) -> BankVerdict:
        """One scan: each hypothesis's filter (its odometry came as the localizer's did, see
        :meth:`on_odometry`) is fixed at ``t`` with the scan's lines and weighed by the scan's
        fit there; merge, prune, and take the leader when its
        weight and its fits allow (``least_fit``: the least a right pose fits, if known)."""
        if not self.hypotheses or len(points) == 0:
            return BankVerdict()
        points, _ = clean_points(points)
        # the scan's lines do not depend on the pose they are matched from: extracted once
        observed = observe_lines(points, hough) if len(points) >= hough.peak_min_votes else None
        for h in self.hypotheses:
            guess, guess_cov = h.tracker.pose_at(t) or (h.tracker.pose, h.tracker.cov)
            fix = localize_scan(points, self.map, guess, hough, pose_cov=guess_cov,
                                observed=observed)
            if fix.rank > 0 and not fix.ambiguous:
                h.tracker.apply(t, fix.pose, fix.cov, fix.observable)
        if not moved_since(self._last_update, odom, self.config):
            return BankVerdict()
        self._last_update = np.asarray(odom, float).copy()
        poses = np.array([h.pose for h in self.hypotheses])
        fits = self._fit(poses, points)
        shares, taken = self._shares(poses, points, [h.glass for h in self.hypotheses],
                                     glass_points(self.config, len(points)))
        beliefs = np.array([h.origin == "tracked" for h in self.hypotheses])
        log_l = np.where(beliefs, scan_log_likelihood(shares, self.config, belief=True),
                         scan_log_likelihood(shares, self.config))
        # a wall taken for glass is one fact about the building, paid for once, in full, by
        # the pose that takes it
        glass_cost = math.log(self.config.glass_probability) * np.array([len(w) for w in taken])
        for h, walls in zip(self.hypotheses, taken, strict=True):
            h.glass[walls] = True
        self._weigh(log_l, glass_cost)
        for h, f, through in zip(self.hypotheses, fits, shares[:, 1], strict=True):
            h.fits.append(float(f))
            h.throughs.append(float(through))
            h.updates += 1
        self._merge()
        self._prune()
        return self._verdict(least_fit)

    def weigh_bearing(self, t: float, odom: NDArray[np.float64], position: tuple[float, float],
                      bearing: float, sigma: float, least_fit: float | None) -> BankVerdict:
        """A landmark known to be at ``position`` seen at ``bearing`` (σ ``sigma``) at time
        ``t``: Bayes' rule with each hypothesis's predicted bearing β̂_h,

            L_h = max(exp(−½ ((bearing − β̂_h)/σ)²), ε · max_k L_k)

        (bounded like a scan's likelihood: one misrecognised landmark does not rule a pose
        out); then the leader is taken when its weight and its fits allow."""
        if not self.hypotheses:
            return BankVerdict()
        log_l = []
        for h in self.hypotheses:
            x, y, theta = h.pose
            gap = wrap_scalar(bearing - (math.atan2(position[1] - y, position[0] - x) - theta))
            log_l.append(-0.5 * (gap / sigma) ** 2)
        self._weigh(np.array(log_l))
        self._prune()
        return self._verdict(least_fit)

    def _weigh(self, log_likelihoods: NDArray[np.float64],
               log_prior: NDArray[np.float64] | None = None) -> None:
        """Bayes' rule, w_h ← w_h · π_h · L_h / Σ_k w_k π_k L_k, with each log L_h raised to at
        least log(ε · max_k L_k), ε the ``unexplained_scan_probability``: an observation the
        map does not explain at the right pose happens that often, so none can rule a pose out.
        π = exp(``log_prior``) is what a hypothesis assumed of the map to explain the scan
        (walls taken for glass), outside that bound."""
        log_l = np.asarray(log_likelihoods, float)
        best = float(log_l.max())
        if self.config.unexplained_scan_probability is not None:
            log_l = np.maximum(log_l, best + math.log(self.config.unexplained_scan_probability))
        log_l = log_l - best
        if log_prior is not None:
            log_l = log_l + log_prior
            log_l -= log_l.max()
        weights = np.array([h.weight for h in self.hypotheses]) * np.exp(log_l)
        weights /= weights.sum()
        for h, w in zip(self.hypotheses, weights, strict=True):
            h.weight = float(w)

    def _same_pose(self, pose: NDArray[np.float64], cov: NDArray[np.float64],
                   h: Hypothesis) -> bool:
        """Is ``pose`` (covariance ``cov``) within the merge gate of ``h``: the χ²₃ quantile
        at ``merge_probability`` of their joint covariance?"""
        gap = pose - h.pose
        gap[2] = wrap_scalar(gap[2])
        return float(gap @ np.linalg.solve(cov + h.cov, gap)) <= self._merge_gate

    def _merge(self) -> None:
        """Hypotheses that have converged on one pose become one (the heavier keeps its
        filter; the weights add)."""
        kept: list[Hypothesis] = []
        for h in sorted(self.hypotheses, key=lambda h: -h.weight):
            for k in kept:
                if self._same_pose(h.pose, h.cov, k):
                    k.weight += h.weight
                    break
            else:
                kept.append(h)
        self.hypotheses = kept

    def _prune(self) -> None:
        floor = self.config.prune_probability
        kept = [h for h in self.hypotheses if h.weight >= floor] or self.hypotheses[:1]
        total = sum(h.weight for h in kept)
        for h in kept:
            h.weight /= total
        self.hypotheses = kept

    @property
    def leader(self) -> Hypothesis:
        """The likeliest hypothesis (the bank must not be empty)."""
        return max(self.hypotheses, key=lambda h: h.weight)

    def _fit_margin(self, h: Hypothesis, least_fit: float | None) -> float:
        """How far ``h``'s recent fits pass the verdict's test, in units of their sampling
        noise: x = (m − f)/σ + z, passed while x ≥ 0. m is the mean of its last ``min_scans``
        fits, f = ``least_fit`` the least a right pose fits (tracking's accepted scans; +∞ when
        not known yet), and σ = √(f(1 − f) / (n · min_scans)) the binomial noise of m for a pose
        that fits f, a scan being worth n = ``independent_points`` observations; z is the
        standard normal quantile at ``accept_probability``, so that a right pose's mean falls
        below the bound f − z σ with probability 1 − ``accept_probability``. Tracking's fits
        come from the places it went through; a right pose elsewhere sees other clutter. A
        pose weighed fewer times is read on the fits it has, their noise the larger."""
        if least_fit is None:
            return math.inf
        return self._margin(self._recent(h.fits) - least_fit, least_fit, len(h.fits))

    def _through_margin(self, h: Hypothesis) -> float:
        """How far ``h``'s recent scans pass the verdict's test on the points seen through
        walls, in units of their sampling noise: x = (p − m)/σ + z, passed while x ≥ 0. m is
        the mean share of the points of its last ``min_scans`` scans seen through walls (not
        counting walls it took for glass), p = ``through_probability`` the share at a right
        pose, σ = √(p(1 − p) / (n · scans)) the binomial noise of m, n = ``independent_points``,
        and z as in :meth:`_fit_margin`: a right pose fails it with probability
        1 − ``accept_probability``. Read against the map, not against tracking: in a place
        the map lacks, tracking's own scans saw through walls as its belief drifted, and the
        best of the wrong poses a global match proposes there still sees through its walls
        (Freiburg 079 held out: 0.16–0.20 of each scan, at 0.73 on walls)."""
        if not h.throughs:
            return math.inf
        p = self.config.through_probability
        return self._margin(p - self._recent(h.throughs), p, len(h.throughs))

    def _margin(self, gap: float, share: float, weighed: int) -> float:
        """gap/σ + z: a gap between the mean share of a hypothesis's last ``min_scans`` scans
        (fewer if it was ``weighed`` fewer times) and the ``share`` a right pose shows, in
        units of that mean's binomial noise σ = √(s(1 − s) / (n · scans)), n =
        ``independent_points``, offset by z, the standard normal quantile at
        ``accept_probability`` (the tests of :meth:`_fit_margin` and :meth:`_through_margin`)."""
        c = self.config
        s = min(max(share, 0.0), 1.0)
        scans = max(1, min(weighed, c.min_scans))
        sigma = math.sqrt(s * (1.0 - s) / (c.independent_points * scans))
        if sigma <= 0.0:
            return math.inf if gap >= 0.0 else -math.inf
        return gap / sigma + self._z_accept

    def _recent(self, values: deque[float]) -> float:
        """The mean of the last ``min_scans`` of a hypothesis's ``values`` (its fits, or its
        shares seen through walls), what the verdict tests."""
        return float(np.mean(list(values)[-self.config.min_scans:]))

    def leader_probability(self, least_fit: float | None) -> float:
        """The probability that the leader is the right pose, as the verdict reads the bank:
        its weight among the followed poses, once a global match has proposed rivals to it
        (0 before), times the chances Φ(x) that its fits and its points seen through walls pass
        the verdict's tests (:meth:`_fit_margin`, :meth:`_through_margin`): a weight is a
        share among the poses followed, and when none of them fits as a right pose does (a
        place the map lacks, where the rivals fit worse still), the leader's share of 1 says
        nothing of the robot. A leader not weighed yet
        is 0: its weight is the match's score and the prior's, and after a kidnap the prior
        favours the pose tracking carried, which is wrong; one weighed fewer than
        ``min_scans`` times is read on the fits it has."""
        if not self.hypotheses or not self._contested:
            return 0.0
        leader = self.leader
        if not leader.fits:
            return 0.0
        return (float(leader.weight) * NormalDist().cdf(self._fit_margin(leader, least_fit))
                * NormalDist().cdf(self._through_margin(leader)))

    def _verdict(self, least_fit: float | None) -> BankVerdict:
        leader = self.leader
        c = self.config
        # the best of poses that all fit poorly, or see through walls, is not taken: none of
        # them is right
        if (not self._contested or leader.weight < c.accept_probability
                or leader.updates < c.min_scans or self._fit_margin(leader, least_fit) < 0.0
                or self._through_margin(leader) < 0.0):
            return BankVerdict()
        recent = self._recent(leader.fits)
        return BankVerdict(leader.pose.copy(), leader.cov.copy(),
                           f"{leader.origin} hypothesis of weight {leader.weight:.3f} after "
                           f"{leader.updates} scans (recent fit {recent:.2f}), "
                           f"{len(self.hypotheses)} followed")

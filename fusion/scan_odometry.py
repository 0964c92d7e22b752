"""Wheel odometry corrected by matching each laser scan to the previous one.

Wheels slip in turns and some robots' odometry misreports motion outright (Freiburg 079 never
reports driving backwards). Two consecutive scans of a laser see the same walls and furniture a
fraction of a second apart, so aligning them measures the motion between them to millimetres,
clutter included, where the Hough fixes need walls the map knows. The wheels still count where
the scans cannot: along a featureless corridor the alignment's information matrix is
near-singular and the fusion below keeps the wheels' increment in that direction.

Per scan ``k`` (all increments in the robot frame of scan ``k − 1``)::

    δ_w, Q_w   the wheel increment since scan k − 1 and its noise (the motion model)
    δ_s, Q_s   the point-to-line ICP of scan k onto scan k − 1, started at δ_w
    δ = (Q_w⁻¹ + Q_s⁻¹)⁻¹ (Q_w⁻¹ δ_w + Q_s⁻¹ δ_s)                (information-weighted mean)

and the corrected odometry pose of scan ``k`` is that of scan ``k − 1`` ⊕ δ; later wheel readings
are chained onto it. The filter predicts that step with δ's covariance (Q_w⁻¹ + Q_s⁻¹)⁻¹
(:meth:`fusion.tracker.PoseTracker.correct_odometry`).

Robustly: Q_w is first scaled by d²/χ²₃(0.99) when d² = (δ_s − δ_w)ᵀ (Q_w + Q_s)⁻¹ (δ_s − δ_w)
exceeds that quantile. Wheels that disagree with a good match beyond their joint noise have
slipped or misreport, and would otherwise bias every such step toward their error.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.motion import OdometryMotionModel, increment, interpolate
from fusion.scan_icp import IcpResult, point_to_line_icp
from fusion.settings.scan_odometry import ScanOdometryConfig
from fusion.wheel_noise import WheelNoiseLearner
from houghloc.geometry import compose, wrap_scalar
from houghloc.matching import gate_threshold

# The wheels' noise while they report no motion is zero; this floor (σ = 1 mm, 0.06°) keeps its
# information finite, and still lets the wheels outweigh a match when the robot stands.
_STILL_NOISE = 1e-6 * np.eye(3)
_INTERVALS_KEPT = 32  # wheel intervals whose median is the wheels' usual one
# The variance (m²) given a direction of the match that too few points observe: the match's
# information there vanishes next to the wheels' (whose σ per step is millimetres to centimetres)
_UNOBSERVED = 1e4
# Point-to-line ICP converges on walls from a heading within about half of this: when the wheels
# missed a turn, the match is started from headings this far apart over the turn it could be.
_HEADING_START_SPACING = math.radians(20.0)


THIN_WINDOW = 2.0
"""s: the thin matches' disagreements are summed over this long (a person walking ahead stays
in view about that long; older ones no longer say what moves now)"""
SAME_DIRECTION = math.cos(math.radians(10.0))
"""a weakest direction turned by more than 10° from the last one is another corridor, or the
same seen from a turn: the sum starts again"""


class ThinBias:
    """Thin matches (``IcpResult.support`` below ``min_points``: one object observes the
    weakest direction) that each disagree with the wheels within their joint noise, but all one
    way: a person walking ahead of the robot, followed by the match. Summed over the last
    ``THIN_WINDOW`` seconds along the same weakest direction u, the disagreements Σ uᵀΔ over
    their variances Σ uᵀ(Q_w + Q_s)u are χ²₁ for an object that stands still; beyond the gate
    the object moves, and the wheels are kept along u."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self._items: deque[tuple[float, float, float]] = deque()  # (t, along, variance)
        self._u: NDArray[np.float64] | None = None

    def reset(self) -> None:
        self._items.clear()
        self._u = None

    def moving(self, t: float, u: NDArray[np.float64], along: float, variance: float) -> bool:
        """Add one thin match at t; does the sum say the object moves?"""
        if self._u is not None:
            cosine = float(u @ self._u)
            if abs(cosine) < SAME_DIRECTION:
                self._items.clear()
            elif cosine < 0.0:  # the same direction, its sign flipped
                along, u = -along, -u
        self._u = u
        self._items.append((t, along, variance))
        while self._items and self._items[0][0] < t - THIN_WINDOW:
            self._items.popleft()
        total = sum(a for _, a, _ in self._items)
        spread = sum(v for _, _, v in self._items)
        return total * total > self.limit * spread


@dataclass(frozen=True, slots=True)
class Correction:
    """A proposed corrected odometry pose for a scan; :meth:`ScanOdometry.commit` adopts it."""

    t: float
    pose: NDArray[np.float64]
    since: float  # the time of the reference scan
    step_cov: NDArray[np.float64]  # covariance of the corrected increment since then
    step_scale: NDArray[np.float64]  # its sensitivity to the wheels' scale error, ∂step/∂e
    points: NDArray[np.float64]
    wheels: NDArray[np.float64]  # the wheels' pose at the scan's time, which it corrects


class ScanOdometry:
    """The odometry stream with each scan's increment corrected by scan matching.

    :meth:`on_wheels` maps a wheel reading into the corrected frame (chained onto the last
    corrected scan); :meth:`match` proposes the corrected pose at a scan, and :meth:`commit`
    adopts it once the filter has taken it. A scan that is not matched or not committed leaves
    the previous one as the reference for the next."""

    def __init__(self, config: ScanOdometryConfig, motion: OdometryMotionModel,
                 wheel_noise: WheelNoiseLearner | None = None) -> None:
        self.config = config
        self.motion = motion
        self.wheel_noise = wheel_noise
        """told each good match's gap from the wheels (None: the wheels' noise not learned)"""
        self.matched = 0
        self.unmatched = 0
        self.broke = False
        """the last scan was matched to its predecessor and fitted it nowhere near the wheels'
        increment: the scans stopped following each other (the robot was carried)"""
        self._wheels: NDArray[np.float64] | None = None  # newest wheel reading
        self._wheels_t = math.nan  # its time (NaN: not given)
        self._previous: tuple[float, NDArray[np.float64]] | None = None  # the reading before
        self._newest_unmeasured = 0.0  # seconds the newest reading's motion was not measured
        self._readings = 0  # wheel readings since the previous scan
        self._timed = False  # the newest reading's stamp is later than the one before it
        self._intervals: deque[float] = deque(maxlen=_INTERVALS_KEPT)  # between readings
        self._anchor_wheels: NDArray[np.float64] | None = None  # wheels at the reference scan
        self._anchor: NDArray[np.float64] | None = None  # corrected pose there
        self._points: NDArray[np.float64] | None = None  # the reference scan
        self._time = -math.inf  # and its time
        # the reference scan came while the wheels were late: no reading is at its time, so
        # the wheels' increment from there would span the motion before it too
        self._unread = False
        self._unmeasured = 0.0  # seconds of motion the wheels missed since the reference scan
        floors = (config.floor_xy**2, config.floor_xy**2, math.radians(config.floor_theta_deg)**2)
        self._floor = np.diag(floors)
        self._robust_limit = (math.inf if config.robust_quantile is None
                              else gate_threshold(config.robust_quantile, 3))
        self._thin_limit = (math.inf if config.robust_quantile is None
                            else gate_threshold(config.robust_quantile, 1))
        self._thin = ThinBias(self._thin_limit)

    @property
    def reference_time(self) -> float:
        """The time of the scan the next one is matched to (−∞ before the first)."""
        return self._time

    def on_wheels(self, x: float, y: float, theta: float, unmeasured: float = 0.0,
                  t: float = math.nan) -> tuple[float, float, float]:
        """The corrected odometry pose for a wheel reading taken at t (``unmeasured``: seconds
        before it whose motion the wheels missed, see :class:`fusion.events.Odometry`)."""
        self._timed = t > self._wheels_t
        if self._timed:
            self._intervals.append(t - self._wheels_t)
            if self._wheels is not None:
                self._previous = (self._wheels_t, self._wheels)
        self._wheels_t = t
        self._readings += 1
        self._newest_unmeasured = unmeasured
        self._wheels = np.array((x, y, theta), dtype=float)
        self._unmeasured += unmeasured
        if self._anchor is None:
            self._anchor_wheels, self._anchor = self._wheels, self._wheels.copy()
        return tuple(self._corrected_wheels().tolist())

    def match(self, t: float, points: NDArray[np.float64]) -> Correction | None:
        """The corrected odometry pose at a scan taken at t (the wheels read at t,
        :meth:`_wheels_at`), or None when the scan cannot be matched; the first scan becomes the
        reference. ``points``: finite, robot frame (the Localizer has cleaned them)."""
        late, self._readings = self._wheels_late(t), 0
        self.broke = False
        if self._wheels is None or len(points) < self.config.min_points:
            return None
        if (self._points is None or t - self._time > self.config.max_interval or late
                or self._unread):
            self.skip(t, points, unread=late)
            return None
        assert self._anchor is not None and self._anchor_wheels is not None  # set with _points
        wheels = self._wheels_at(t)
        wheel_step = increment(self._anchor_wheels, wheels)
        icp = self._align(points, wheel_step)
        fused = self._fuse(t, wheel_step, icp)
        if fused is None:
            self.unmatched += 1
            self.broke = True
            self.skip(t, points)
            return None
        self.matched += 1
        step, cov, scale = fused
        return Correction(t, compose(self._anchor, step), self._time, cov, scale, points,
                          wheels)

    def _wheels_at(self, t: float) -> NDArray[np.float64]:
        """The wheels' pose at the scan's time t. A scan falls between two wheel readings, and
        the match measures the motion between the scans' times: the wheels' step must span
        the same interval, or at 0.5 m/s a reading 20 ms older than the scan puts 1 cm of
        disagreement between the two that neither made. The newest reading is carried along
        the arc from the one before it (:func:`fusion.motion.interpolate`), at their speed, to
        t, when the two are regular readings (at most twice the usual interval apart, no
        motion missed) and t is as near the newest (the wheels are not late,
        :meth:`_wheels_late`); else the newest reading stands."""
        assert self._wheels is not None
        if (self._previous is None or not self._intervals or self._newest_unmeasured > 0.0
                or not math.isfinite(t)):
            return self._wheels
        before_t, before = self._previous
        interval, usual = self._wheels_t - before_t, self._longest_interval()
        if not (0.0 < interval <= usual and abs(t - self._wheels_t) <= usual):
            return self._wheels
        return interpolate(before, self._wheels, 1.0 + (t - self._wheels_t) / interval)

    def _wheels_late(self, t: float) -> bool:
        """The wheels have missed a reading before the scan at t: their newest is older than
        twice their usual interval (the median of the last ones), and either none came since
        the previous scan or the newest was timed by its stamp (later than the one before it).
        Readings that repeat one stamp still come, and are not late; but a reading that came
        since the previous scan at its own time says nothing of the time since. Their
        increment would then say the robot stood still since that reading, and the match,
        which along a featureless corridor has only that increment to go by, would be fused
        with it: the first scan of an odometry gap, 80 ms after the last reading, moved 1 cm
        where the robot drove 5, and the filter then held that speed through the gap. Instead
        the scan becomes the reference, and the filter carries the pose past the wheels'
        newest reading by itself (:meth:`fusion.tracker.PoseTracker.pose_at`). The scan after
        it is not matched to it either: the wheels' increment from their reading before the
        late scan spans the motion before that scan too (over an odometry gap of seconds,
        metres against a match of one scan interval)."""
        if len(self._intervals) < _INTERVALS_KEPT // 2 or (self._readings > 0
                                                            and not self._timed):
            return False
        return t - self._wheels_t > self._longest_interval()

    def _longest_interval(self) -> float:
        """s: the longest the wheels may go between readings and still be on time, twice their
        usual interval (the median of the last ones)."""
        return 2.0 * float(np.median(self._intervals))

    def commit(self, correction: Correction) -> None:
        """The filter took the corrected pose: the scan becomes the reference for the next."""
        self._points, self._anchor_wheels, self._anchor = (correction.points, correction.wheels,
                                                           correction.pose)
        self._time, self._unmeasured = correction.t, 0.0

    def skip(self, t: float, points: NDArray[np.float64], unread: bool = False) -> None:
        """The scan was not corrected: it becomes the reference at its uncorrected pose (an older
        reference would drift out of view). ``unread``: the wheels were late for it, so the
        next scan is not matched to it either (:meth:`_wheels_late`)."""
        wheels = self._wheels_at(t)
        self._anchor = self._corrected_wheels(wheels)
        self._points, self._anchor_wheels, self._time = points, wheels, t
        self._unmeasured, self._unread = 0.0, unread

    def _align(self, points: NDArray[np.float64],
               wheel_step: NDArray[np.float64]) -> IcpResult | None:
        """The ICP of the scan onto the reference, started at the wheels' increment; when the
        wheels missed some motion, started from every heading the robot could have turned to
        then as well, and the best-overlapping alignment kept (the nearer turn on a tie)."""
        assert self._points is not None
        reach = self.motion.config.max_turn_rate * self._unmeasured
        count = min(int(reach / _HEADING_START_SPACING), int(math.pi / _HEADING_START_SPACING))
        best: IcpResult | None = None
        for k in sorted(range(-count, count + 1), key=abs):
            start = wheel_step.copy()
            start[2] += k * _HEADING_START_SPACING
            icp = point_to_line_icp(self._points, points, start, self.config)
            if icp is not None and (best is None or icp.overlap > best.overlap):
                best = icp
        return best
    def _corrected_wheels(self, wheels: NDArray[np.float64] | None = None
                          ) -> NDArray[np.float64]:
        """A wheel pose (the newest reading by default) in the corrected frame: chained onto
        the reference scan."""
        assert self._anchor is not None and self._anchor_wheels is not None
        assert self._wheels is not None
        return compose(self._anchor, increment(self._anchor_wheels,
                                               self._wheels if wheels is None else wheels))

    def _turn_limit(self, t: float) -> float:
        """rad: the most a match at t may turn from the wheels' increment since the reference
        scan. The wheels may miss part of a turn (they slip), but not a turn faster than the
        robot turns at all: over the Δt between the scans, at most ``max_turn_rate`` · Δt (Δt
        at least the odometry's ``jump_min_dt``, as stamps jitter), and never more than
        ``max_correction_theta_deg``. A match beyond it aligned two scans that do not follow
        each other: the robot was carried (a kidnap turns it within one scan interval), and in
        a building whose doors repeat, the scan of the other place can still align. Only the
        turn is bounded by time: every wall observes it, while the position along a corridor
        may be what the match does not observe."""
        motion = self.motion.config
        interval = max(t - self._time, motion.jump_min_dt)
        return min(math.radians(self.config.max_correction_theta_deg),
                   motion.max_turn_rate * interval)

    def _fuse(self, t: float, wheel_step: NDArray[np.float64], icp: IcpResult | None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
        """δ = Q (Q_w⁻¹ δ_w + Q_s⁻¹ δ_s) with Q = (Q_w⁻¹ + Q_s⁻¹)⁻¹, the information-weighted
        increment, its covariance and its sensitivity to the wheels' scale error,
        ∂δ/∂e = Q Q_w⁻¹ (δ_w,x, δ_w,y, 0) (the wheels count as far as they are weighted), for
        the scan at time ``t``; None when the match is unusable or too far from the wheels to
        be believed."""
        c = self.config
        if icp is None or icp.overlap < c.min_overlap:
            return None
        matched = icp.delta.copy()
        matched[2] = wheel_step[2] + wrap_scalar(matched[2] - wheel_step[2])
        gap = matched - wheel_step
        # motion the wheels missed widens what they can be corrected by, to where the robot
        # could have gone meanwhile
        limits = self.motion.config
        if (math.hypot(gap[0], gap[1]) > c.max_correction_xy + limits.max_speed * self._unmeasured
                or abs(gap[2]) > self._turn_limit(t) + limits.max_turn_rate * self._unmeasured):
            return None
        wheel_cov = self.motion.noise(wheel_step) + _STILL_NOISE
        if self._unmeasured > 0.0:
            wheel_cov = wheel_cov + self.motion.jump_noise(self._unmeasured)
        scan_cov = icp.cov * c.noise_scale + self._floor
        q, dof = icp.disagreement
        if c.robust_quantile is not None and dof > 0 and q > gate_threshold(c.robust_quantile,
                                                                             dof):
            # The scene's objects disagree on the motion along the match's weakest direction:
            # some of them moved (people walking along a corridor), and the match there is a
            # compromise among their motions. The wheels' increment is kept along it.
            u = np.array((icp.weakest[0], icp.weakest[1], 0.0))
            scan_cov = scan_cov + _UNOBSERVED * np.outer(u, u)
        elif icp.support < c.min_points:
            # Without its strongest object, the scene gives fewer points' worth of evidence
            # than a match needs along the match's weakest direction (a person walking along a
            # featureless corridor, a door frame; IcpResult.support). Where that object agrees
            # with the wheels it refines the step; where it disagrees beyond the joint noise,
            # its own motion explains it as well as a slip of the wheels, and nothing else in
            # the scan decides: the wheels' increment is kept along that direction (and the
            # robust step below does not blame the wheels for it).
            # One match at a time cannot tell an object walking slowly ahead from a standing
            # one: their sum over the last seconds can (ThinBias).
            u = np.array((icp.weakest[0], icp.weakest[1], 0.0))
            along = float(gap @ u)
            variance = float(u @ (wheel_cov + scan_cov) @ u)
            moving = self._thin.moving(t, u[:2], along, variance)
            if along * along > self._thin_limit * variance or moving:
                scan_cov = scan_cov + _UNOBSERVED * np.outer(u, u)
        else:
            self._thin.reset()
            self._learn_noise(wheel_step, gap, scan_cov)
        if c.robust_quantile is not None:
            # the two disagree beyond their joint noise: the wheels slipped or misreport (a good
            # match does not err by decimetres), so their noise is scaled up until they agree
            # at the quantile, and the increment follows the match
            d2 = float(gap @ np.linalg.solve(wheel_cov + scan_cov, gap))
            if d2 > self._robust_limit:
                wheel_cov = wheel_cov * (d2 / self._robust_limit)
        wheel_info = np.linalg.inv(wheel_cov)
        scan_info = np.linalg.inv(scan_cov)
        cov = np.linalg.inv(wheel_info + scan_info)
        cov = 0.5 * (cov + cov.T)
        scale = cov @ wheel_info @ np.array((wheel_step[0], wheel_step[1], 0.0))
        return cov @ (wheel_info @ wheel_step + scan_info @ matched), cov, scale

    def _learn_noise(self, wheel_step: NDArray[np.float64], gap: NDArray[np.float64],
                     scan_cov: NDArray[np.float64]) -> None:
        """A good match (no object moved against the others, several observe its weakest
        direction) tells the wheel-noise learner its gap from the wheels along their direction,
        where it observes that direction at least as well as the default wheels do, and the
        wheels missed no motion."""
        trans = math.hypot(wheel_step[0], wheel_step[1])
        if (self.wheel_noise is None or self._unmeasured > 0.0
                or trans < self.motion.config.heading_min_translation):
            return
        u = np.array((wheel_step[0] / trans, wheel_step[1] / trans, 0.0))
        default = float(u @ self.motion.noise(wheel_step, 1.0) @ u)
        if float(u @ scan_cov @ u) <= default:
            self.wheel_noise.observe(float(gap @ u), default)


_warmed_up = False


def warm_up() -> None:
    """Compile the matching kernels, or load them from the cache, before the first scan (once
    per process): two views of a rectangular room, 5 cm and 1° apart, are aligned."""
    global _warmed_up
    if _warmed_up:
        return
    s = np.linspace(0.0, 1.0, 60, endpoint=False)[:, None]
    corners = np.array([[-2.0, -1.5], [4.0, -1.5], [4.0, 2.5], [-2.0, 2.5]])
    room = np.concatenate([a + s * (b - a) for a, b in zip(corners, np.roll(corners, -1, 0),
                                                             strict=True)])
    moved = (room - (0.05, 0.0)) @ np.array([[1.0, 0.0175], [-0.0175, 1.0]])
    point_to_line_icp(room, moved, np.zeros(3), ScanOdometryConfig())
    _warmed_up = True

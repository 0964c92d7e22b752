"""The wheels' distance scale, learned from pairs of full pose fixes.

Zero-mean odometry noise cannot absorb a scale error. Where the scans observe the pose only
across a corridor (a featureless corridor gives partial fixes), the position along it is dead
reckoning, and wheels that over-report by 3 % drift 0.3 m in 10 m while the filter's random walk
says a few centimetres. The scale belongs to the wheels, not to the place: it is learned where
the scans fix the whole pose and used where they do not.

Two full fixes z_a, z_b (Hough fixes of rank 3 the filter accepted) observe it when the robot
went at least ``baseline`` between them along a nearly straight path: every full fix from the
first to the second heads within ``max_turn_deg`` of the chord z_b − z_a (backwards driving
folded onto forwards). The path is then about as long as

    m = |z_b − z_a| / mean_i cos δ_i,

δ_i those fixes' headings from the chord (a path that leaves its chord by δ is 1/cos δ longer;
the fixes sample it evenly at a steady speed), and the wheels, which report w metres of path
between the readings at the two fixes, observe

    m = s·w + v,

v the fixes' noise along the chord plus the wheels' random noise over the path
(``wheel_noise``² per metre: the motion model's α₃ is wider, as it must cover any robot's
wheels). The estimate's σ (:attr:`WheelScaleLearner.sigma`) is the filter's uncertainty of
the scale: it carries the scale's remaining error as a drift of the path
(:class:`fusion.ekf.PoseEKF`). The wheels' path length is used, not their chord: wheels whose radii
differ report a straight path as an arc, whose chord is shorter, but not its length. The length
is summed over chords of ``_SEGMENT``: summed reading by reading, the readings' own jitter
(millimetres across the path between readings millimetres apart) would lengthen it by per
cents. A chord counts once the next agrees with it (:meth:`WheelScaleLearner._corroborated`),
and the scale is the weighted mean, weights w²/σ_v², of the last ``_CHORDS`` chords' ratios m/w
and the prior that agree with their weighted median, once ``_LEAST_PAIRS`` pairs agreed: robust
like a median, not a Kalman filter's running mean, because a run of chords between fixes wrong
the same way (a stretch where the map is distorted) moved a filter's estimate so far that its
gate then refused every right chord after it. Consecutive chords share no fix, so their noises
are independent. The fixes need not be at the right place: a look-alike place gives the same
chord.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from fusion.settings.wheel_scale import WheelScaleConfig

_PENDING = 16
"""fixes waiting for the wheel reading after them (a few scans' worth: readings come at 5–100 Hz)"""
_SEGMENT = 0.25
"""m: the wheels' path is measured in chords this long: far longer than their readings' jitter,
so it adds nothing, and short enough that an arc of wheels whose radii differ by 10 % (14° per
metre on a 0.4 m base) is 0.02 % longer than its chords"""
_CHORDS = 64
"""chords the scale is the median of: the last 130 m or more of straight path (a tyre's wear
changes its radius far more slowly)"""
_LEAST_PAIRS = 2
"""pairs of agreeing chords before the scale leaves the prior: one pair wrong the same way (a
stretch where the map is distorted) is never used alone; with a second, the median lies between
them (the prior tips it) and only the chords that agree with it are averaged"""
_AGREE = float(chi2.ppf(0.99, 1))
"""two chords agree when their ratios differ by less than this quantile of χ²₁ of their noise"""
_MEDIAN_EFFICIENCY = 1.2533
"""√(π/2): the standard error of a normal sample's median over that of its mean"""
_HEADINGS = 1024
"""full fixes between two ends of a chord at most (a robot that stands still starts afresh)"""
_READINGS = 4096
"""wheel readings kept to interpolate a waiting fix's (minutes at 50 Hz; a fix waits one reading)"""


@dataclass(frozen=True, slots=True)
class _Fix:
    t: float
    pose: NDArray[np.float64]
    cov: NDArray[np.float64]


@dataclass(slots=True)
class _Anchor:
    fix: _Fix
    path: float  # the wheels' path length driven up to the fix
    headings: list[float]  # of the full fixes from this one on


class WheelScaleLearner:
    """Raw wheel readings and accepted full fixes in; the wheels' scale out (``value``).

    A fix waits for the first reading at or after its time, so that the wheels are interpolated
    at it rather than extrapolated. A reading after motion the wheels missed (an odometry gap,
    a jump) breaks the chain: the next fix starts a new pair."""

    def __init__(self, config: WheelScaleConfig, prior: float) -> None:
        """``prior``: the configured scale (``filter.motion.translation_scale``)."""
        assert config.sigma is not None  # the localizer builds none when the scale is fixed
        self.config = config
        self._prior = (prior, 1.0 / config.sigma**2)  # as a ratio and its weight
        self._chords: deque[tuple[float, float]] = deque(maxlen=_CHORDS)  # ratio, weight
        self.value = prior
        """the estimated true distance per metre the wheels report"""
        self.updates = 0
        """chords used"""
        self._wheel_variance = config.wheel_noise**2
        self._readings: deque[tuple[float, float]] = deque(maxlen=_READINGS)  # t, path
        self._path = 0.0
        self._mark: tuple[float, float] | None = None  # where the current chord started
        self._pending: deque[_Fix] = deque(maxlen=_PENDING)
        self._anchor: _Anchor | None = None
        self._waiting: tuple[float, float, float] | None = None  # a chord without a partner yet

    @property
    def sigma(self) -> float:
        """The estimate's nominal standard error: the prior's own while the estimate is the
        prior; then 1/√(Σ weights) of the chords kept and the prior, widened by 1.25 for the
        median that chose which of them are averaged."""
        if self.updates < 2 * _LEAST_PAIRS:
            return 1.0 / math.sqrt(self._prior[1])
        total = self._prior[1] + sum(weight for _, weight in self._chords)
        return _MEDIAN_EFFICIENCY / math.sqrt(total)

    def on_wheels(self, t: float, x: float, y: float, theta: float, broken: bool) -> None:
        """A raw wheel reading (before any calibration); ``broken``: the wheels missed motion
        before it. Waiting fixes up to ``t`` are then used."""
        if broken:
            self.forget()
        if self._mark is None:
            self._mark = (x, y)
        since = math.hypot(x - self._mark[0], y - self._mark[1])
        self._readings.append((t, self._path + since))
        if since >= _SEGMENT:  # a chord of the path done: the next starts here
            self._path += since
            self._mark = (x, y)
        while self._pending and self._pending[0].t <= t:
            self._observe(self._pending.popleft())

    def on_fix(self, t: float, pose: NDArray[np.float64], cov: NDArray[np.float64]) -> None:
        """A full fix the filter accepted, taken at ``t``."""
        self._pending.append(_Fix(t, np.array(pose, dtype=float), np.array(cov, dtype=float)))

    def summary(self) -> dict[str, float | int]:
        """The estimate, its σ and the chords used (``metrics.json``'s ``wheel_scale``)."""
        return {"estimate": round(self.value, 6), "sigma": round(self.sigma, 6),
                "updates": self.updates}

    def forget(self) -> None:
        """Start afresh: the pose jumped (a relocalization) or the wheels missed motion."""
        self._readings.clear()
        self._pending.clear()
        self._anchor = None
        self._waiting = None
        self._path = 0.0
        self._mark = None

    def _observe(self, fix: _Fix) -> None:
        path = self._path_at(fix.t)
        if path is None:
            self._anchor = None
            return
        anchor = self._anchor
        if anchor is None or len(anchor.headings) >= _HEADINGS:
            self._anchor = _Anchor(fix, path, [float(fix.pose[2])])
            return
        anchor.headings.append(float(fix.pose[2]))
        chord = fix.pose[:2] - anchor.fix.pose[:2]
        length = float(math.hypot(*chord))
        if length < self.config.baseline:
            return  # not far enough yet
        self._anchor = _Anchor(fix, path, [float(fix.pose[2])])
        along = math.atan2(chord[1], chord[0])
        # the heading from the chord, driving backwards folded onto forwards: |δ| ≤ 90°
        off = np.abs((np.asarray(anchor.headings) - along + 0.5 * math.pi) % math.pi
                     - 0.5 * math.pi)
        if off.max() > math.radians(self.config.max_turn_deg):
            return  # not straight: its chord is no measure of its length; start again here
        u = chord / length
        measured = length / float(np.cos(off).mean())
        driven = path - anchor.path
        noise = (float(u @ (fix.cov[:2, :2] + anchor.fix.cov[:2, :2]) @ u)
                 + self._wheel_variance * driven)
        self._corroborated(driven, measured, noise)

    def _corroborated(self, driven: float, measured: float, noise: float) -> None:
        """Use a chord once the next chord agrees with it (their ratios m/w within ``_AGREE`` of
        their joint noise), then both. A fix that is wrong by decimetres while the filter's own
        uncertainty is wide enough to accept it (a room the map lacks) makes one chord, or two
        neighbouring ones, disagree with everything else, and the first chords of a run decide
        the median alone. The chord that found no partner is dropped when the next disagrees."""
        waiting, self._waiting = self._waiting, (driven, measured, noise)
        if waiting is None:
            return
        w0, m0, n0 = waiting
        gap = m0 / w0 - measured / driven
        if gap * gap > _AGREE * (n0 / w0**2 + noise / driven**2):
            return  # the newer chord waits for a partner in turn
        self._waiting = None
        self._chords.append((m0 / w0, w0 * w0 / n0))
        self._chords.append((measured / driven, driven * driven / noise))
        self.updates += 2
        if self.updates >= 2 * _LEAST_PAIRS:
            self.value = _robust_mean([self._prior, *self._chords])

    def _path_at(self, t: float) -> float | None:
        """The wheels' path length driven up to ``t``, interpolated between the readings
        around it; None outside the readings kept."""
        readings = self._readings
        if not readings or t < readings[0][0] or t > readings[-1][0]:
            return None
        i = len(readings) - 1
        while i > 0 and readings[i - 1][0] >= t:
            i -= 1
        b = readings[i]
        a = readings[i - 1] if i > 0 else b
        f = 0.0 if b[0] == a[0] else (t - a[0]) / (b[0] - a[0])
        return a[1] + f * (b[1] - a[1])


def _robust_mean(items: list[tuple[float, float]]) -> float:
    """The weighted mean of the (ratio, weight) items that agree with their weighted median
    (within ``_AGREE`` of their own noise, 1/weight): the median finds the majority, and the
    mean of the majority is as precise as all of it (a median of a few noisy chords is as
    noisy as one)."""
    middle = _weighted_median(items)
    kept = [(r, w) for r, w in items if (r - middle) ** 2 * w <= _AGREE]
    return sum(r * w for r, w in kept) / sum(w for _, w in kept)


def _weighted_median(items: list[tuple[float, float]]) -> float:
    """The value below and above which lie at most half the weight of (value, weight) items."""
    ordered = sorted(items)
    half = 0.5 * sum(weight for _, weight in ordered)
    below = 0.0
    for value, weight in ordered:
        below += weight
        if below >= half:
            return value
    return ordered[-1][0]

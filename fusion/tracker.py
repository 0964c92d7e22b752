"""Time ordering and delayed measurements around the pose EKF.

The tracker keeps a short history of nodes, oldest first. Each node is a time with its odometry
pose, the posterior (x, P) at that time, the increment (and its noise) that led to it from the
previous node, and the pose measurements applied there. Odometry readings make nodes; so does a
measurement taken between two readings, at its own time, with the odometry interpolated there.

* A measurement newer than every node is applied at once to the estimate extrapolated to its
  time: the newest odometry's velocity held, the covariance widened by what the base's
  acceleration could change meanwhile (:meth:`PoseTracker._ahead`), so a pose reported while
  the odometry is late (a few seconds without readings) is neither frozen nor confident. It is
  kept as a *provisional* node, and when the next odometry arrives the node gets its real
  (interpolated) odometry and the short tail is re-filtered — so the result is the same as if
  the odometry had been there first.
* A measurement inside the history is applied at its own time, and every node after it is
  re-filtered: the stored increments are predicted again and the stored measurements re-applied
  (re-gated too, as an in-order run would have done). The cost is O(nodes after t).
* A measurement older than the history is dropped and counted.

So applying a measurement late gives the same estimate as applying it on time. Counters report
each measurement's first decision; a re-filter may later flip a gate decision without counting.

Estimates are computed when asked for. An odometry reading only records its increment; the
nodes between two estimates that are needed are bridged by one prediction with the increments
composed (:func:`~fusion.motion.compose_increments`, exact by the chain rule), and re-filtering
marks the later nodes for recomputation. At 50 Hz odometry and 10 Hz scans that is one
prediction per scan instead of five.
"""

from __future__ import annotations

import logging
import math
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass, field
from itertools import islice

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.ekf import PoseEKF, UpdateOutcome
from fusion.motion import OdometryMotionModel, compose_increments, increment, interpolate
from fusion.settings.filter import GATE_PROBABILITY, FilterConfig
from fusion.settings.motion import OdometryMotionConfig
from fusion.status import ScanStatus
from houghloc.geometry import compose, wrap_angle
from houghloc.jit import njit

log = logging.getLogger(__name__)

_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))
_TRIM_BATCH = 8  # nodes added between two trims


@dataclass
class TrackerCounts:
    """What the tracker did, for metrics and the ambiguity manager.

    ``delayed``: measurements applied in the past through the history (accepted or not);
    ``invalid``: inputs rejected as non-finite, or whose innovation covariance was singular.
    """

    predictions: int = 0
    updates: int = 0
    rejected: int = 0
    delayed: int = 0
    dropped: int = 0
    odometry_jumps: int = 0
    odometry_backwards: int = 0
    invalid: int = 0


@dataclass(slots=True)
class _Measurement:
    z: NDArray[np.float64]
    r: NDArray[np.float64]
    basis: NDArray[np.float64] | None


@dataclass(slots=True)
class _Node:
    t: float
    odom: NDArray[np.float64]
    x: NDArray[np.float64] | None  # None: not computed yet (see PoseTracker._estimate)
    p: NDArray[np.float64] | None
    step: NDArray[np.float64]  # increment from the previous node's odometry, robot frame
    step_q: NDArray[np.float64]  # its covariance
    jump: bool = False  # the step replaced an implausible odometry jump by zero motion
    measurements: list[_Measurement] = field(default_factory=list)


def _node_time(node: _Node) -> float:
    return node.t


class PoseTracker:
    """The pose estimate over time: odometry predictions and (possibly late) pose updates.

    One class of about 430 lines, on purpose: every method that adds, re-filters or trims
    nodes must keep the history's invariants (time order, the provisional node, the stale
    marks, the trimmed prefix), and they are checked in one place rather than across parts."""

    def __init__(
        self,
        initial_pose: ArrayLike,
        initial_cov: ArrayLike,
        motion_cfg: OdometryMotionConfig | None = None,
        history_seconds: float = 2.0,
        gate_prob: float | None = GATE_PROBABILITY,
        delayed_updates: bool = True,
    ) -> None:
        if not history_seconds > 0:
            raise ValueError(f"history_seconds must be positive, got {history_seconds}")
        self.motion = OdometryMotionModel(motion_cfg)
        self.history_seconds = float(history_seconds)
        self.delayed_updates = delayed_updates
        self.counts = TrackerCounts()
        x, p = _checked_state(initial_pose, initial_cov)
        self._gate_prob = gate_prob
        self._ekf = PoseEKF(x, p, gate_prob)  # one engine, reused for every step
        self._x, self._p = x, p  # the estimate while no odometry has arrived
        self._nodes: deque[_Node] = deque()
        self._tail = 0  # provisional nodes: measurements newer than the newest odometry
        self._trim_length = 0  # trim when the history has this many nodes
        self._held: tuple[float, float] | None = None  # (t, until): see :meth:`hold`
        self._reading_since = -math.inf  # when the odometry first gave its newest reading
        # after a reset later than the newest reading: that reading (t, odometry). The oldest
        # node's odometry is then unknown until a reading after it brackets it with this one
        self._before: tuple[float, NDArray[np.float64]] | None = None

    @classmethod
    def from_config(cls, config: FilterConfig, initial_pose: ArrayLike,
                    **extra: object) -> PoseTracker:
        """A tracker at ``initial_pose`` with the configured initial covariance, motion model,
        history, gate and delayed-measurement handling (``extra``: a subclass's own settings)."""
        return cls(initial_pose, config.initial_cov, config.motion, config.history_seconds,
                   config.gate_probability, config.delayed_updates, **extra)

    # ----------------------------------------------------------------- reading the estimate
    @property
    def pose(self) -> NDArray[np.float64]:
        """The newest estimate (x, y, θ) in ``map`` (a copy)."""
        return (self._state(-1)[0] if self._nodes else self._x).copy()

    @property
    def cov(self) -> NDArray[np.float64]:
        """The newest covariance P (a copy)."""
        return (self._state(-1)[1] if self._nodes else self._p).copy()

    @property
    def time(self) -> float | None:
        """Time of the newest estimate; None before the first odometry."""
        return self._nodes[-1].t if self._nodes else None

    @property
    def odometry_time(self) -> float | None:
        """Time of the newest odometry reading (provisional nodes after it excluded); None
        before the first one. An estimate later than this assumes no motion since."""
        if self._before is not None:
            return self._before[0]
        return self._nodes[-1 - self._tail].t if self._nodes else None

    def pose_at(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """(x, P) at time t: the node at or before t, predicted with the odometry interpolated
        at t. Newer than the newest node: extrapolated (:meth:`_ahead`). Older than the
        history: None. Before any odometry: the current estimate, whatever t.
        """
        if not self._nodes:
            return self._x.copy(), self._p.copy()
        j = self._index_at(t)
        if j is None:
            return None
        node = self._estimate(j)
        assert node.x is not None and node.p is not None  # _estimate computes them
        if t == node.t:
            return node.x.copy(), node.p.copy()
        if j == len(self._nodes) - 1:
            step, q = self._ahead(node, t)
        else:
            _, step, q = self._split(node, self._nodes[j + 1], t)
        self._load(node)
        self._ekf.predict_odometry(step, q)
        return self._ekf.x.copy(), self._ekf.P.copy()

    # ---------------------------------------------------------------------------- odometry
    def odometry_at(self, t: float) -> NDArray[np.float64] | None:
        """The odometry pose (its own frame) at time t, interpolated inside the history; the
        newest reading for later times; None before any odometry or before the history."""
        j = self._index_at(t) if self._nodes else None
        if j is None:
            return None
        node = self._nodes[j]
        if j == len(self._nodes) - 1 or t == node.t:
            return node.odom.copy()
        return self._split(node, self._nodes[j + 1], t)[0]

    def on_odometry(self, t: float, x: float, y: float, theta: float,
                    unmeasured: float = 0.0) -> None:
        """Predict with the increment since the previous odometry reading (the first one only
        anchors the odometry frame). Backwards timestamps are ignored and counted; a repeated
        reading is a no-op; an implausible increment is replaced by zero motion with the jump
        covariance and counted. ``unmeasured`` seconds of motion the increment misses add the
        jump covariance of that interval: the robot moved somewhere within its limits then.
        """
        if not all(map(math.isfinite, (t, x, y, theta))):
            self._invalid(f"non-finite odometry at t={t}: ({x}, {y}, {theta})")
            return
        odom = np.array([x, y, theta], dtype=float)
        if not self._nodes:
            self._nodes.append(_Node(t, odom, self._x, self._p, _ZERO3, _ZERO33))
            self._reading_since = t
            return
        if self._before is not None and not self._bracket(t, odom):
            return
        lo_index = len(self._nodes) - 1 - self._tail
        lo = self._nodes[lo_index]
        if t < lo.t:
            self.counts.odometry_backwards += 1
            return
        if t == lo.t and (odom == lo.odom).all() and unmeasured <= 0.0:
            return
        dt = t - lo.t
        total = increment(lo.odom, odom)
        # readings that repeat one pose may be a stalled odometry: the motion of the reading
        # that ends the stall happened over the stall too (up to ``max_stall``)
        stalled = min(max(lo.t - self._reading_since, 0.0), self.motion.config.max_stall)
        jump = self.motion.is_jump(total, dt + stalled)
        if odom.tolist() != lo.odom.tolist():  # np.array_equal, without its overhead
            self._reading_since = t
        self.counts.predictions += 1
        self.counts.odometry_jumps += int(jump)
        if self._tail == 0:  # the common case: append and predict
            if jump:
                step, q = _ZERO3, self.motion.jump_noise(dt)
            else:
                step, q = total, self.motion.noise(total)
            if unmeasured > 0.0:
                q = q + self.motion.jump_noise(unmeasured)
            self._nodes.append(_Node(t, odom, None, None, step, q, jump))
        else:
            self._absorb_provisional(lo_index, t, odom, dt, jump, unmeasured)
        self._trim()

    def _bracket(self, t: float, odom: NDArray[np.float64]) -> bool:
        """After a reset later than the newest reading: a reading after the reset's time gives
        the oldest node its odometry, interpolated between the reading before and this one, and
        is then used as any other (True); one before it only replaces the reading before
        (False: nothing to predict yet)."""
        assert self._before is not None
        t_before, odom_before = self._before
        if t < t_before:
            self.counts.odometry_backwards += 1
            return False
        first = self._nodes[0]
        if t <= first.t:
            self._before = (t, odom)
            if odom.tolist() != odom_before.tolist():
                self._reading_since = t
            return False
        self._before = None
        span = increment(odom_before, odom)
        if not self.motion.is_jump(span, t - t_before):  # a jump happens at its end
            first.odom = interpolate(odom_before, odom, (first.t - t_before) / (t - t_before))
        return True

    def correct_odometry(self, t: float, pose: ArrayLike, since: float | None = None,
                         step_cov: ArrayLike | None = None) -> bool:
        """A corrected odometry pose at t (scan matching measured the motion the wheels
        misreported): it replaces the newest reading when taken at its time, or follows it as
        a new reading; later readings must come in the corrected frame. Not a jump, whatever
        its size: the correction is bounded by its own checks.

        ``since``, ``step_cov``: the correction measured the whole motion since the reading at
        ``since``, with this covariance; the readings in between are then merged into one step
        with that noise (unless measurements were taken there: the step keeps the motion
        model's noise). False, and nothing changed, when t is older than the newest reading,
        measurements wait after it, or the pose is not finite."""
        odom = np.array(pose, dtype=float).reshape(3)
        if not (self._nodes and self._tail == 0 and self._before is None
                and np.isfinite(odom).all()):
            return False
        nodes = self._nodes
        newest = nodes[-1]
        if t < newest.t or (t == newest.t and (len(nodes) < 2 or newest.measurements)):
            return False
        if t == newest.t:
            nodes.pop()
        start = -1
        if since is not None and step_cov is not None:
            j = bisect_right(nodes, since, key=_node_time) - 1
            merged = range(j + 1, len(nodes))
            if (j >= 0 and nodes[j].t == since
                    and not any(nodes[i].measurements for i in merged)):
                start = j
        if start >= 0:
            for _ in range(len(nodes) - 1 - start):
                nodes.pop()
            step = increment(nodes[start].odom, odom)
            q = np.array(step_cov, dtype=float).reshape(3, 3)
        else:
            step = increment(nodes[-1].odom, odom)
            q = self.motion.noise(step)
        nodes.append(_Node(t, odom, None, None, step, q))
        self._trim()
        return True

    def _absorb_provisional(
        self, lo_index: int, t: float, odom: NDArray[np.float64], dt: float, jump: bool,
        unmeasured: float = 0.0
    ) -> None:
        """Insert the odometry reading among the provisional nodes: those up to t get their
        odometry interpolated (zero motion across a jump), those after it stay provisional at
        the new reading; then re-filter from the first of them.
        """
        lo = self._nodes[lo_index]
        tail = [self._nodes.pop() for _ in range(self._tail)][::-1]
        before = [n for n in tail if n.t <= t]
        after = [n for n in tail if n.t > t]
        for n in before:
            n.odom = lo.odom if jump else interpolate(lo.odom, odom, (n.t - lo.t) / dt)
        for n in after:
            n.odom = odom
        reading = _Node(t, odom, None, None, _ZERO3, _ZERO33, jump)
        prev = lo
        for n in [*before, reading]:
            if n is reading and jump:
                n.step, n.step_q = _ZERO3, self.motion.jump_noise(dt)
            else:
                n.step = increment(prev.odom, n.odom)
                n.step_q = self.motion.noise(n.step)
            if n is reading and unmeasured > 0.0:
                n.step_q = n.step_q + self.motion.jump_noise(unmeasured)
            self._nodes.append(n)
            prev = n
        self._tail = 0
        for n in after:  # still beyond the odometry: extrapolated from the new reading
            n.step, n.step_q = self._ahead(prev, n.t)
            n.odom = compose(prev.odom, n.step)
            self._nodes.append(n)
            self._tail += 1
            prev = n
        self._mark_stale(lo_index + 1)

    # ------------------------------------------------------------------------- measurements
    def apply(
        self,
        t: float,
        z: ArrayLike,
        r: ArrayLike,
        basis: ArrayLike | None = None,
    ) -> UpdateOutcome:
        """Update with an absolute pose z (map frame, taken at time t) of covariance R (3×3),
        optionally only along the orthonormal columns of ``basis`` (3×k).

        t at or after the newest node: applied now. Inside the history: applied at t, later
        nodes re-filtered (``counts.delayed``), unless ``delayed_updates`` is False, in which
        case it is applied now as if just taken. Older than the history: dropped.
        """
        meas = self._checked_measurement(t, z, r, basis)
        if meas is None:
            return UpdateOutcome(False, 0.0, 0, status=ScanStatus.INVALID)
        if not self._nodes:
            self._ekf.x, self._ekf.P = self._x, self._p
            outcome = self._update(meas)
            self._x, self._p = self._ekf.x, self._ekf.P
            return outcome
        newest = self._nodes[-1]
        if not self.delayed_updates:
            t = max(t, newest.t)
        if t >= newest.t:
            return self._apply_now(t, meas)
        if t < self._nodes[self._oldest()].t:
            self.counts.dropped += 1
            return UpdateOutcome(False, 0.0, 0, status=ScanStatus.DROPPED)
        self.counts.delayed += 1
        j = bisect_right(self._nodes, t, key=_node_time) - 1
        node = self._estimate(j)
        if t == node.t:
            self._load(node)
            outcome = self._attach(node, meas)
            self._mark_stale(j + 1)
            return outcome
        nxt = self._nodes[j + 1]
        odom, step, q = self._split(node, nxt, t)
        if not nxt.jump:  # a jump stays a jump: its zero step and wide noise are kept
            nxt.step = increment(odom, nxt.odom)
            nxt.step_q = self.motion.noise(nxt.step)
        inserted = _Node(t, odom, node.x, node.p, step, q)
        self._propagate(node, inserted)
        outcome = self._attach(inserted, meas)
        self._nodes.insert(j + 1, inserted)
        if j >= len(self._nodes) - 2 - self._tail:  # it landed after the newest odometry
            self._tail += 1
        self._mark_stale(j + 2)
        return outcome

    def _apply_now(self, t: float, meas: _Measurement) -> UpdateOutcome:
        newest = self._nodes[-1]
        if t == newest.t:
            self._load(self._estimate(-1))
            return self._attach(newest, meas)
        # Newer than any odometry: extrapolated; fixed when the odometry arrives.
        self._estimate(-1)
        step, q = self._ahead(newest, t)
        node = _Node(t, compose(newest.odom, step), None, None, step, q)
        self._propagate(newest, node)
        outcome = self._attach(node, meas)
        self._nodes.append(node)
        self._tail += 1
        self._trim()
        return outcome

    def hold(self, t: float, until: float) -> None:
        """Keep the node at t, and the history after it, while the newest node is no later
        than ``until``, however much longer ago than ``history_seconds`` t becomes.

        A scan-odometry correction (:meth:`correct_odometry`) measures the whole motion since
        the previous scan and can replace the readings' noise with its own only while the node
        of that scan is kept. Scans come seconds apart on some robots (a log that records a
        scan only after the robot moved); without the hold the readings in between kept the
        wheels' noise, and the heading's σ grew to tens of degrees that the match had measured
        to a fraction of one. ``until`` bounds the history kept when no scan comes."""
        self._held = (t, until)

    def reset(self, pose: ArrayLike, cov: ArrayLike, t: float | None = None) -> bool:
        """Re-initialise (a relocalisation): the estimate at time ``t`` becomes (pose, cov);
        measurements before it are forgotten, the odometry after it is kept and re-filtered
        from there. Without ``t``, or older than the history: at the newest odometry reading.
        Later than the newest reading (the odometry is late): the reset's node waits for the
        next reading to interpolate its odometry, so motion the pose already has is not added
        again. Counters are kept. An invalid pose or covariance is refused (counted, False)."""
        try:
            x, p = _checked_state(pose, cov)
        except ValueError as error:
            self._invalid(f"reset refused: {error}")
            return False
        if not self._nodes:
            self._x, self._p = x, p
            return True
        self._nodes, self._before = self._restarted(x, p, t)
        self._trim_length = 0
        self._tail = 0
        return True

    def branch(self, pose: ArrayLike, cov: ArrayLike, t: float) -> PoseTracker:
        """A new filter with this one's settings and odometry, whose estimate at time ``t`` is
        (pose, cov) (a followed hypothesis, as :meth:`reset` would place it)."""
        other = PoseTracker(self._x, self._p, self.motion.config, self.history_seconds,
                            self._gate_prob, self.delayed_updates)
        if self._nodes:
            x, p = _checked_state(pose, cov)
            other._nodes, other._before = self._restarted(x, p, t)
            other._reading_since = self._reading_since
        else:
            other._x, other._p = _checked_state(pose, cov)
        return other

    def _restarted(self, x: NDArray[np.float64], p: NDArray[np.float64], t: float | None
                   ) -> tuple[deque[_Node], tuple[float, NDArray[np.float64]] | None]:
        """The history after a reset to (x, P) at t (see :meth:`reset`): the new nodes, and the
        reading before them when t is later than every reading."""
        nodes = self._nodes
        newest = len(nodes) - 1 - self._tail
        if self._before is not None:  # still waiting for a reading after the oldest node
            reading = self._before
        else:
            reading = (nodes[newest].t, nodes[newest].odom)
        if t is None or not math.isfinite(t) or t < nodes[self._oldest()].t:
            t = reading[0]
        if t >= reading[0]:
            first = _Node(t, reading[1], x, p, _ZERO3, _ZERO33)
            return deque([first]), (None if t == reading[0] else reading)
        j = bisect_right(nodes, t, key=_node_time) - 1
        if nodes[j].t == t:
            odom = nodes[j].odom
        else:
            odom = self._split(nodes[j], nodes[j + 1], t)[0]
        kept: deque[_Node] = deque([_Node(t, odom, x, p, _ZERO3, _ZERO33)])
        # the readings after t keep their steps and noise (a scan-odometry correction's own,
        # too), not their measurements; the first is re-split from t, as :meth:`apply` does
        for node in islice(nodes, j + 1, newest + 1):
            kept.append(_Node(node.t, node.odom, None, None, node.step, node.step_q, node.jump))
        first_after = kept[1] if len(kept) > 1 else None
        if first_after is not None and not first_after.jump and nodes[j].t != t:
            first_after.step = increment(odom, first_after.odom)
            first_after.step_q = self.motion.noise(first_after.step)
        return kept, None

    # ------------------------------------------------------------------------------ helpers
    def _split(
        self, node: _Node, nxt: _Node, t: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Odometry at t between two nodes, and the step (and its noise) from ``node`` to it."""
        if nxt.jump:  # no motion can be interpolated across a jump: it all happens at its end
            return node.odom, _ZERO3, _ZERO33
        odom = interpolate(node.odom, nxt.odom, (t - node.t) / (nxt.t - node.t))
        step = increment(node.odom, odom)
        return odom, step, self.motion.noise(step)

    def _ahead(self, prev: _Node, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The step from ``prev``, the newest node, to t, later than every odometry reading,
        and its noise: the newest reading's velocity held, δ = v·(t − t_prev), widened by what
        a bounded acceleration changes meanwhile. T seconds after the reading, the held
        velocity's pose is off by at most ½aT² (a = ``max_acceleration``; the heading with
        ``max_angular_acceleration``), taken as σ; the step from T₀ to T adds the variance
        (½a)²(T⁴ − T₀⁴), so the variances of successive steps sum to that of their span."""
        nodes = self._nodes
        index = len(nodes) - 1 - self._tail
        reading = nodes[index]
        step = self._velocity(index) * (t - prev.t)
        grow = 0.25 * ((t - reading.t) ** 4 - (prev.t - reading.t) ** 4)
        c = self.motion.config
        linear, angular = c.max_acceleration**2 * grow, c.max_angular_acceleration**2 * grow
        return step, self.motion.noise(step) + np.diag((linear, linear, angular))

    def _velocity(self, index: int) -> NDArray[np.float64]:
        """The odometry's velocity (robot frame, per second) at node ``index``: its motion over
        the last ``jump_min_dt`` seconds at least (a shorter span would divide the readings'
        rounding by nearly nothing). Zero across a jump, without such a span, or beyond the
        base's limits (``max_speed``, ``max_turn_rate``): then the stamps do not time the
        readings (several readings share one), and holding that velocity would fling the pose."""
        nodes = self._nodes
        reading = nodes[index]
        c = self.motion.config
        k = index - 1
        while k >= 0 and reading.t - nodes[k].t < c.jump_min_dt:
            k -= 1
        if k < 0 or any(nodes[i].jump for i in range(k + 1, index + 1)):
            return _ZERO3
        velocity = increment(nodes[k].odom, reading.odom) / (reading.t - nodes[k].t)
        if (math.hypot(velocity[0], velocity[1]) > c.max_speed
                or abs(velocity[2]) > c.max_turn_rate):
            return _ZERO3
        return velocity

    def _load(self, node: _Node) -> None:
        # The engine never modifies these arrays in place (filterpy assigns new ones), so the
        # node's arrays can be handed over without copies.
        assert node.x is not None and node.p is not None  # only computed nodes are loaded
        self._ekf.x, self._ekf.P = node.x, node.p

    def _propagate(self, prev: _Node, node: _Node) -> None:
        self._load(prev)
        self._ekf.predict_odometry(node.step, node.step_q)
        node.x, node.p = self._ekf.x, self._ekf.P

    def _attach(self, node: _Node, meas: _Measurement) -> UpdateOutcome:
        """Update the loaded engine at ``node`` with ``meas``, store the result and count it."""
        outcome = self._update(meas)
        if outcome.status != ScanStatus.INVALID:
            node.measurements.append(meas)
        node.x, node.p = self._ekf.x, self._ekf.P
        return outcome

    def _update(self, meas: _Measurement) -> UpdateOutcome:
        outcome = self._ekf.update_pose(meas.z, meas.r, meas.basis)
        if outcome.accepted:
            self.counts.updates += 1
        elif outcome.status == ScanStatus.REJECTED:
            self.counts.rejected += 1
        else:
            self._invalid("singular innovation covariance")
        return outcome

    def _mark_stale(self, start: int) -> None:
        """Mark every node from ``start`` on for recomputation: its stored step is predicted
        again and its measurements re-applied (uncounted: they were counted when they arrived)
        when its estimate is next needed."""
        nodes = self._nodes
        for i in range(start, len(nodes)):
            nodes[i].x = nodes[i].p = None

    def _state(self, j: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(x, P) of node ``j``, computed if it was not yet."""
        node = self._estimate(j)
        assert node.x is not None and node.p is not None  # _estimate computes them
        return node.x, node.p

    def _estimate(self, j: int) -> _Node:
        """Node ``j`` with its estimate computed: from the nearest computed node before it, one
        prediction with the composed increments per stretch, the measurements of the nodes in
        between applied where they were taken (the oldest node is always computed)."""
        nodes = self._nodes
        j %= len(nodes)
        if nodes[j].x is not None:
            return nodes[j]
        start = j - 1
        while nodes[start].x is None:
            start -= 1
        for i in range(start + 1, j + 1):
            node = nodes[i]
            if node.measurements or i == j:
                self._load(nodes[start])
                if i == start + 1:
                    self._ekf.predict_odometry(node.step, node.step_q)
                else:
                    stretch = [nodes[k] for k in range(start + 1, i + 1)]
                    self._ekf.predict_odometry(*compose_increments(
                        np.array([n.step for n in stretch]),
                        np.array([n.step_q for n in stretch])))
                for meas in node.measurements:
                    self._ekf.update_pose(meas.z, meas.r, meas.basis)
                node.x, node.p = self._ekf.x, self._ekf.P
                start = i
        return nodes[j]

    def _index_at(self, t: float) -> int | None:
        """Index of the last node at or before t (the newest for later times); None when t is
        not finite or older than the history. The nodes must not be empty."""
        nodes = self._nodes
        if nodes[-1].t <= t < math.inf:  # the usual case, a scan after the newest odometry
            return len(nodes) - 1
        if not math.isfinite(t) or t < nodes[self._oldest()].t:
            return None
        return bisect_right(nodes, t, key=_node_time) - 1

    def _oldest(self) -> int:
        """Index of the oldest node of the history: the last at or before ``history_seconds``
        before the newest node (older ones wait for trimming, but no longer count)."""
        nodes = self._nodes
        return max(0, bisect_right(nodes, nodes[-1].t - self.history_seconds, key=_node_time) - 1)

    def _trim(self) -> None:
        """Forget nodes no longer needed to cover ``history_seconds`` before the newest node,
        or the held node (:meth:`hold`) if older. The oldest kept node is the newest computed
        one at or before that horizon, so trimming costs no prediction while estimates are
        asked for (every scan asks); if none was asked for over a whole history (odometry
        alone), the node at the horizon is computed. If the odometry stalls for longer than the
        history, the oldest provisional node becomes the anchor for the next reading, so a
        stream of measurements without odometry does not grow the history without bound.
        """
        nodes = self._nodes
        if len(nodes) < self._trim_length:  # a few nodes at a time: each look costs a search
            return
        self._trim_length = len(nodes) + _TRIM_BATCH
        horizon = nodes[-1].t - self.history_seconds
        if len(nodes) < 2 or nodes[1].t > horizon:
            return
        last = self._oldest()
        held = self._held
        if held is not None and nodes[0].t <= held[0] < nodes[last].t and nodes[-1].t <= held[1]:
            last = bisect_right(nodes, held[0], key=_node_time) - 1
        keep = last
        while keep > 0 and nodes[keep].x is None:
            keep -= 1
        if nodes[keep].t < horizon - self.history_seconds:
            self._estimate(last)
            keep = last
        for _ in range(keep):
            nodes.popleft()
        self._tail = min(self._tail, len(nodes) - 1)
        self._trim_length = len(nodes) + _TRIM_BATCH

    def _invalid(self, message: str) -> None:
        self.counts.invalid += 1
        log.warning("pose tracker: %s (ignored, %d so far)", message, self.counts.invalid)

    def _checked_measurement(
        self, t: float, z: ArrayLike, r: ArrayLike, basis: ArrayLike | None
    ) -> _Measurement | None:
        z = np.array(z, dtype=float).reshape(3)
        r = np.array(r, dtype=float).reshape(3, 3)
        if not (math.isfinite(t) and _all_finite(z, r)):
            self._invalid(f"non-finite pose measurement at t={t}")
            return None
        if basis is not None:
            basis = np.array(basis, dtype=float)
            if basis.ndim == 1:
                basis = basis.reshape(3, 1)
            k = basis.shape[1] if basis.ndim == 2 else 0
            if basis.shape[0] != 3 or not 1 <= k <= 3:
                raise ValueError(f"basis must be 3×k with k in 1..3, got shape {basis.shape}")
            if not np.isfinite(basis).all():
                self._invalid(f"non-finite basis of a pose measurement at t={t}")
                return None
            if not _orthonormal(np.ascontiguousarray(basis), 1e-6):
                raise ValueError("basis columns must be orthonormal")
        return _Measurement(z, r, basis)


@njit
def _all_finite(z: NDArray[np.float64], r: NDArray[np.float64]) -> bool:
    """Are the measured pose and its covariance finite (one compiled pass, no temporaries)?"""
    for i in range(3):
        if not math.isfinite(z[i]):
            return False
        for j in range(3):
            if not math.isfinite(r[i, j]):
                return False
    return True


@njit
def _orthonormal(basis: NDArray[np.float64], tolerance: float) -> bool:
    """Is each entry of BᵀB within ``tolerance`` of the identity's? (B is finite.)"""
    k = basis.shape[1]
    for a in range(k):
        for b in range(k):
            dot = 0.0
            for i in range(basis.shape[0]):
                dot += basis[i, a] * basis[i, b]
            if not abs(dot - (1.0 if a == b else 0.0)) <= tolerance:
                return False
    return True


def _checked_state(
    pose: ArrayLike, cov: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    x = np.array(pose, dtype=float).reshape(3)
    p = np.array(cov, dtype=float).reshape(3, 3)
    if not (np.isfinite(x).all() and np.isfinite(p).all()):
        raise ValueError("initial pose and covariance must be finite")
    if not np.allclose(p, p.T) or np.linalg.eigvalsh(p).min() < 0:
        raise ValueError("initial covariance must be symmetric positive semi-definite")
    x[2] = wrap_angle(x[2])
    return x, 0.5 * (p + p.T)


def warm_up() -> None:
    """Compile the filter's kernels, or load them from the cache, before the first scan: a
    tracker is driven a step and given a full and a partial pose measurement."""
    tracker = PoseTracker(np.zeros(3), np.diag([0.01, 0.01, 0.001]))
    tracker.on_odometry(0.0, 0.0, 0.0, 0.0)
    tracker.on_odometry(0.1, 0.1, 0.0, 0.01)
    measured = np.array([0.11, 0.01, 0.012])
    tracker.apply(0.1, measured, np.diag([1e-4, 1e-4, 1e-5]))
    tracker.apply(0.1, measured, np.diag([1e-4, 1e-4, 1e-5]), np.eye(3)[:, 1:])

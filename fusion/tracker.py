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

import math
from bisect import bisect_right

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.ekf import UpdateOutcome
from fusion.motion import OdometryMotionModel, increment, interpolate
from fusion.pose_history import (
    ZERO3,
    ZERO33,
    Measurement,
    Node,
    PoseHistory,
    checked_state,
    node_time,
)
from fusion.settings.filter import GATE_PROBABILITY, FilterConfig
from fusion.settings.motion import OdometryMotionConfig
from fusion.status import ScanStatus
from houghloc.geometry import compose


class PoseTracker(PoseHistory):
    """The pose estimate over time: odometry predictions and (possibly late) pose updates.

    Its inputs — odometry readings, corrections, measurements, resets — add and re-filter the
    nodes of its :class:`~fusion.pose_history.PoseHistory`, whose invariants (time order, the
    provisional nodes, the stale marks, the trimmed prefix) the history's own steps keep."""

    def __init__(
        self,
        initial_pose: ArrayLike,
        initial_cov: ArrayLike,
        motion_cfg: OdometryMotionConfig | None = None,
        history_seconds: float = 2.0,
        gate_prob: float | None = GATE_PROBABILITY,
        delayed_updates: bool = True,
    ) -> None:
        x, p = checked_state(initial_pose, initial_cov)
        super().__init__(x, p, OdometryMotionModel(motion_cfg), history_seconds, gate_prob)
        self.delayed_updates = delayed_updates
        self._gate_prob = gate_prob
        self._x, self._p = x, p  # the estimate while no odometry has arrived
        self._reading_since = -math.inf  # when the odometry first gave its newest reading

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
        self._predict(step, q)
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
            self._nodes.append(Node(t, odom, self._x, self._p, ZERO3, ZERO33))
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
                step, q = ZERO3, self.motion.jump_noise(dt)
            else:
                step, q = total, self.motion.noise(total)
            if unmeasured > 0.0:
                q = q + self.motion.jump_noise(unmeasured)
            self._nodes.append(Node(t, odom, None, None, step, q, jump))
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
                         step_cov: ArrayLike | None = None,
                         step_scale: ArrayLike | None = None) -> bool:
        """A corrected odometry pose at t (scan matching measured the motion the wheels
        misreported): it replaces the newest reading when taken at its time, or follows it as
        a new reading; later readings must come in the corrected frame. Not a jump, whatever
        its size: the correction is bounded by its own checks.

        ``since``, ``step_cov``: the correction measured the whole motion since the reading at
        ``since``, with this covariance (and ``step_scale``, its sensitivity to the wheels'
        scale error: None, that of a wheel step); the readings in between are then merged into
        one step with that noise (unless measurements were taken there: the step keeps the
        motion model's noise). False, and nothing changed, when t is older than the newest reading,
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
            j = bisect_right(nodes, since, key=node_time) - 1
            merged = range(j + 1, len(nodes))
            if (j >= 0 and nodes[j].t == since
                    and not any(nodes[i].measurements for i in merged)):
                start = j
        if start >= 0:
            for _ in range(len(nodes) - 1 - start):
                nodes.pop()
            step = increment(nodes[start].odom, odom)
            q = np.array(step_cov, dtype=float).reshape(3, 3)
            scale = None if step_scale is None else np.array(step_scale, dtype=float).reshape(3)
        else:
            step = increment(nodes[-1].odom, odom)
            q, scale = self.motion.noise(step), None
        nodes.append(Node(t, odom, None, None, step, q, step_scale=scale))
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
        reading = Node(t, odom, None, None, ZERO3, ZERO33, jump)
        prev = lo
        for n in [*before, reading]:
            if n is reading and jump:
                n.step, n.step_q = ZERO3, self.motion.jump_noise(dt)
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
            self._ekf.x, self._ekf.P, self._ekf.d = self._x, self._p, ZERO3
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
        j = bisect_right(self._nodes, t, key=node_time) - 1
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
            nxt.step_q, nxt.step_scale = self.motion.noise(nxt.step), None
        inserted = Node(t, odom, node.x, node.p, step, q, d=node.d)
        self._propagate(node, inserted)
        outcome = self._attach(inserted, meas)
        self._nodes.insert(j + 1, inserted)
        if j >= len(self._nodes) - 2 - self._tail:  # it landed after the newest odometry
            self._tail += 1
        self._mark_stale(j + 2)
        return outcome

    def _apply_now(self, t: float, meas: Measurement) -> UpdateOutcome:
        newest = self._nodes[-1]
        if t == newest.t:
            self._load(self._estimate(-1))
            return self._attach(newest, meas)
        # Newer than any odometry: extrapolated; fixed when the odometry arrives.
        self._estimate(-1)
        step, q = self._ahead(newest, t)
        node = Node(t, compose(newest.odom, step), None, None, step, q)
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
            x, p = checked_state(pose, cov)
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
        other.motion = self.motion  # the same wheels: their scale's uncertainty is shared
        if self._nodes:
            x, p = checked_state(pose, cov)
            other._nodes, other._before = self._restarted(x, p, t)
            other._reading_since = self._reading_since
        else:
            other._x, other._p = checked_state(pose, cov)
        return other


def warm_up() -> None:
    """Compile the filter's kernels, or load them from the cache, before the first scan: a
    tracker is driven a step and given a full and a partial pose measurement."""
    tracker = PoseTracker(np.zeros(3), np.diag([0.01, 0.01, 0.001]))
    tracker.on_odometry(0.0, 0.0, 0.0, 0.0)
    tracker.on_odometry(0.1, 0.1, 0.0, 0.01)
    measured = np.array([0.11, 0.01, 0.012])
    tracker.apply(0.1, measured, np.diag([1e-4, 1e-4, 1e-5]))
    tracker.apply(0.1, measured, np.diag([1e-4, 1e-4, 1e-5]), np.eye(3)[:, 1:])

"""The tracker's history (:mod:`fusion.tracker`): its nodes and the steps that compute, split,
extend and trim them.

Each node is a time with its odometry pose, the posterior (x, P) at that time (or not computed
yet), the increment (and its noise) that led to it from the previous node, and the pose
measurements applied there. The newest ``tail`` nodes are *provisional*: measurements newer than
the newest odometry reading, at poses extrapolated from it. An estimate is computed when asked
for, from the nearest computed node before it (:meth:`PoseHistory._estimate`).
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
from fusion.status import ScanStatus
from houghloc.geometry import wrap_angle
from houghloc.jit import njit

log = logging.getLogger("fusion.tracker")  # the tracker's warnings, wherever they are raised

ZERO3 = np.zeros(3)
ZERO33 = np.zeros((3, 3))
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
class Measurement:
    z: NDArray[np.float64]
    r: NDArray[np.float64]
    basis: NDArray[np.float64] | None


@dataclass(slots=True)
class Node:
    t: float
    odom: NDArray[np.float64]
    x: NDArray[np.float64] | None  # None: not computed yet (see PoseHistory._estimate)
    p: NDArray[np.float64] | None
    step: NDArray[np.float64]  # increment from the previous node's odometry, robot frame
    step_q: NDArray[np.float64]  # its covariance
    jump: bool = False  # the step replaced an implausible odometry jump by zero motion
    measurements: list[Measurement] = field(default_factory=list)
    # with x: the pose's sensitivity to the wheels' scale error (fusion.ekf.PoseEKF.d)
    d: NDArray[np.float64] = field(default_factory=lambda: ZERO3)
    # the step's, ∂step/∂e (robot frame); None: its own translation, as the wheels' step
    step_scale: NDArray[np.float64] | None = None


def node_time(node: Node) -> float:
    return node.t


class PoseHistory:
    """The nodes of a tracker's history, oldest first, and the filter engine that computes
    their estimates; ``history_seconds`` of them are kept (more while a node is held)."""

    def __init__(self, x: NDArray[np.float64], p: NDArray[np.float64],
                 motion: OdometryMotionModel, history_seconds: float,
                 gate_prob: float | None) -> None:
        if not history_seconds > 0:
            raise ValueError(f"history_seconds must be positive, got {history_seconds}")
        self.motion = motion
        self.history_seconds = float(history_seconds)
        self.counts = TrackerCounts()
        self._ekf = PoseEKF(x, p, gate_prob)  # one engine, reused for every step
        self._nodes: deque[Node] = deque()
        self._tail = 0  # provisional nodes: measurements newer than the newest odometry
        self._trim_length = 0  # trim when the history has this many nodes
        self._held: tuple[float, float] | None = None  # (t, until): see PoseTracker.hold
        # after a reset later than the newest reading: that reading (t, odometry). The oldest
        # node's odometry is then unknown until a reading after it brackets it with this one
        self._before: tuple[float, NDArray[np.float64]] | None = None

    def _restarted(self, x: NDArray[np.float64], p: NDArray[np.float64], t: float | None
                   ) -> tuple[deque[Node], tuple[float, NDArray[np.float64]] | None]:
        """The history after a reset to (x, P) at t (see ``PoseTracker.reset``): the new nodes,
        and the reading before them when t is later than every reading."""
        nodes = self._nodes
        newest = len(nodes) - 1 - self._tail
        if self._before is not None:  # still waiting for a reading after the oldest node
            reading = self._before
        else:
            reading = (nodes[newest].t, nodes[newest].odom)
        if t is None or not math.isfinite(t) or t < nodes[self._oldest()].t:
            t = reading[0]
        if t >= reading[0]:
            first = Node(t, reading[1], x, p, ZERO3, ZERO33)
            return deque([first]), (None if t == reading[0] else reading)
        j = bisect_right(nodes, t, key=node_time) - 1
        if nodes[j].t == t:
            odom = nodes[j].odom
        else:
            odom = self._split(nodes[j], nodes[j + 1], t)[0]
        kept: deque[Node] = deque([Node(t, odom, x, p, ZERO3, ZERO33)])
        # the readings after t keep their steps and noise (a scan-odometry correction's own,
        # too), not their measurements; the first is re-split from t, as ``PoseTracker.apply`` does
        for node in islice(nodes, j + 1, newest + 1):
            kept.append(Node(node.t, node.odom, None, None, node.step, node.step_q, node.jump,
                             step_scale=node.step_scale))
        first_after = kept[1] if len(kept) > 1 else None
        if first_after is not None and not first_after.jump and nodes[j].t != t:
            first_after.step = increment(odom, first_after.odom)
            first_after.step_q = self.motion.noise(first_after.step)
            first_after.step_scale = None
        return kept, None

    def _split(
        self, node: Node, nxt: Node, t: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Odometry at t between two nodes, and the step (and its noise) from ``node`` to it."""
        if nxt.jump:  # no motion can be interpolated across a jump: it all happens at its end
            return node.odom, ZERO3, ZERO33
        odom = interpolate(node.odom, nxt.odom, (t - node.t) / (nxt.t - node.t))
        step = increment(node.odom, odom)
        return odom, step, self.motion.noise(step)

    def _ahead(self, prev: Node, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
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
            return ZERO3
        velocity = increment(nodes[k].odom, reading.odom) / (reading.t - nodes[k].t)
        if (math.hypot(velocity[0], velocity[1]) > c.max_speed
                or abs(velocity[2]) > c.max_turn_rate):
            return ZERO3
        return velocity

    def _load(self, node: Node) -> None:
        # The engine never modifies these arrays in place (filterpy assigns new ones), so the
        # node's arrays can be handed over without copies.
        assert node.x is not None and node.p is not None  # only computed nodes are loaded
        self._ekf.x, self._ekf.P, self._ekf.d = node.x, node.p, node.d

    def _store(self, node: Node) -> None:
        """The engine's estimate becomes the node's."""
        node.x, node.p, node.d = self._ekf.x, self._ekf.P, self._ekf.d

    def _predict(self, step: NDArray[np.float64], q: NDArray[np.float64],
                 step_scale: NDArray[np.float64] | None = None) -> None:
        """The loaded engine predicted with one step, uncertain by the wheels' scale too
        (``motion.scale_variance``) as far as it depends on them (``step_scale``)."""
        self._ekf.predict_odometry(step, q, step_scale, self.motion.scale_variance)

    def _propagate(self, prev: Node, node: Node) -> None:
        self._load(prev)
        self._predict(node.step, node.step_q, node.step_scale)
        self._store(node)

    def _attach(self, node: Node, meas: Measurement) -> UpdateOutcome:
        """Update the loaded engine at ``node`` with ``meas``, store the result and count it."""
        outcome = self._update(meas)
        if outcome.status != ScanStatus.INVALID:
            node.measurements.append(meas)
        self._store(node)
        return outcome

    def _update(self, meas: Measurement) -> UpdateOutcome:
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

    def _estimate(self, j: int) -> Node:
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
                    self._predict(node.step, node.step_q, node.step_scale)
                else:
                    stretch = [nodes[k] for k in range(start + 1, i + 1)]
                    self._predict(*compose_increments(
                        np.array([n.step for n in stretch]),
                        np.array([n.step_q for n in stretch]),
                        np.array([_step_scale(n) for n in stretch])))
                for meas in node.measurements:
                    self._ekf.update_pose(meas.z, meas.r, meas.basis)
                self._store(node)
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
        return bisect_right(nodes, t, key=node_time) - 1

    def _oldest(self) -> int:
        """Index of the oldest node of the history: the last at or before ``history_seconds``
        before the newest node (older ones wait for trimming, but no longer count)."""
        nodes = self._nodes
        return max(0, bisect_right(nodes, nodes[-1].t - self.history_seconds, key=node_time) - 1)

    def _trim(self) -> None:
        """Forget nodes no longer needed to cover ``history_seconds`` before the newest node,
        or the held node (``PoseTracker.hold``) if older. The oldest kept node is the newest
        computed one at or before that horizon, so trimming costs no prediction while estimates are
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
            last = bisect_right(nodes, held[0], key=node_time) - 1
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
    ) -> Measurement | None:
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
        return Measurement(z, r, basis)


def _step_scale(node: Node) -> NDArray[np.float64]:
    """∂step/∂e of a node's step (:attr:`Node.step_scale`)."""
    if node.step_scale is not None:
        return node.step_scale
    return np.array([node.step[0], node.step[1], 0.0])


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


def checked_state(
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

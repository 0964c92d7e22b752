"""A stateful property test of the Localizer API: random interleavings of odometry and scans
with late, repeated and jumping stamps and NaN, infinite and huge values.

Invariants after every step: no exception (bad values are dropped and counted, never raised),
a finite pose, a symmetric positive-definite covariance, a history whose length stays
bounded (memory flat however long the run), and an ambiguity manager whose parts agree with
its state. The default suite runs a few thousand steps; the slow suite 10⁵.
"""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from fusion.localizer import Localizer
from fusion.sim.laser import true_ranges
from fusion.status import State
from houghloc import SegmentMap
from tests.conftest import MAPS

OFFICE = SegmentMap.from_yaml(MAPS / "office.yaml")
ANGLES = np.linspace(-math.pi / 2, math.pi / 2, 181)
BAD = [math.nan, math.inf, -math.inf, 1e300, -1e300, 1e7]
MAX_NODES = 2000  # the history keeps ~2 s of odometry at any rate the test can produce

stamp_step = st.one_of(
    st.floats(0.0, 0.1),  # ordinary, and equal stamps (0)
    st.floats(-3.0, 0.0),  # late
    st.sampled_from([25.0, -25.0, 1e6]),  # jumps ahead or back
    st.sampled_from([math.nan, math.inf]),
)
value = st.one_of(st.floats(-0.2, 0.2), st.sampled_from(BAD))


class LocalizerMachine(RuleBasedStateMachine):
    @initialize(seed=st.integers(0, 2**16), known=st.booleans())
    def start(self, seed: int, known: bool) -> None:
        self.rng = np.random.default_rng(seed)
        self.true = np.array([4.0, 6.0, 0.0])
        self.odom = np.zeros(3)
        self.t = 0.0
        self.loc = Localizer(OFFICE, None, self.true if known else None)

    @rule(dt=st.floats(0.0, 0.1), ds=st.floats(0.0, 0.05), dth=st.floats(-0.05, 0.05))
    def drive(self, dt: float, ds: float, dth: float) -> None:
        """An ordinary reading: the robot moved a little."""
        self.t += dt
        self.odom = self.odom + (ds * math.cos(self.odom[2]), ds * math.sin(self.odom[2]), dth)
        heading = self.true[2]
        self.true = self.true + (ds * math.cos(heading), ds * math.sin(heading), dth)
        self.loc.on_odometry(self.t, *self.odom)

    @rule(step=stamp_step, dx=value, dth=value)
    def odd_odometry(self, step: float, dx: float, dth: float) -> None:
        """A reading with an odd stamp or an odd value."""
        self.loc.on_odometry(self.t + step, self.odom[0] + dx, self.odom[1], self.odom[2] + dth)

    @rule(step=st.one_of(st.just(0.0), stamp_step), nans=st.integers(0, 181),
          huge=st.booleans(), empty=st.booleans())
    def scan(self, step: float, nans: int, huge: bool, empty: bool) -> None:
        ranges = np.asarray(true_ranges(OFFICE, self.true, ANGLES, 20.0)[0], dtype=float).copy()
        ranges[self.rng.choice(len(ranges), nans, replace=False)] = np.nan
        if huge:
            ranges[::7] = 1e300
        if empty:
            ranges[:] = np.inf
        estimate = self.loc.on_scan(self.t + step, ranges, ANGLES)
        assert np.isfinite(estimate.pose).all()

    @rule(points=st.integers(0, 50), bad=st.sampled_from(BAD))
    def odd_points(self, points: int, bad: float) -> None:
        pts = self.rng.normal(0.0, 3.0, (points, 2))
        if points:
            pts[0, 0] = bad
        self.loc.on_points(self.t, pts, "laser")

    @invariant()
    def pose_and_covariance_are_sound(self) -> None:
        if not hasattr(self, "loc"):
            return
        pose, cov = self.loc.pose, self.loc.cov
        assert np.isfinite(pose).all(), pose
        assert np.isfinite(cov).all() and np.allclose(cov, cov.T, atol=1e-9 * np.abs(cov).max())
        assert np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() > 0, cov

    @invariant()
    def the_manager_is_where_its_transitions_say(self) -> None:
        """Each transition leaves the state the one before entered, the last one's is the
        state; while tracking no pose is followed and no global match is under way; once lost
        there is no belief to weigh poses against."""
        if not hasattr(self, "loc"):
            return
        manager = self.loc.manager
        steps = manager.transitions
        assert all(later.old is earlier.new for earlier, later in pairwise(steps))
        assert not steps or steps[-1].new is manager.state
        if manager.state is State.TRACKING:
            assert manager.followed == [] and manager.relocalization.match is None
        if manager.state is State.LOST:
            assert manager.belief.prior is None

    @invariant()
    def memory_is_bounded(self) -> None:
        if hasattr(self, "loc"):
            assert len(self.loc.tracker._nodes) <= MAX_NODES


def _run(examples: int, steps: int) -> None:
    test = LocalizerMachine.TestCase
    test.settings = settings(max_examples=examples, stateful_step_count=steps, deadline=None,
                             suppress_health_check=list(HealthCheck))
    test().runTest()


def test_the_localizer_api_survives_random_faults() -> None:
    _run(examples=30, steps=60)


@pytest.mark.slow
def test_the_localizer_api_survives_random_faults_for_100k_steps() -> None:
    _run(examples=1000, steps=100)

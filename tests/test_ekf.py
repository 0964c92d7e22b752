"""The filter layer: odometry motion model, pose EKF, tracker with delayed measurements."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from fusion.ekf import PoseEKF
from fusion.motion import (
    OdometryCalibration,
    OdometryMotionModel,
    compose_increments,
    increment,
    interpolate,
)
from fusion.settings.motion import OdometryMotionConfig
from fusion.tracker import PoseTracker
from houghloc.geometry import compose, positive_definite, relative, within_radius, wrap_angle

# Real odometry frames start anywhere: the CARMEN logs begin here.
ODOM_ORIGIN = np.array([576.5, 0.1, -2.26])
P0 = np.diag([0.05**2, 0.05**2, 0.02**2])
R_SMALL = np.diag([0.01**2, 0.01**2, 0.005**2])


def drive(
    tracker: PoseTracker,
    twist: tuple[float, float],
    seconds: float,
    rate: float = 50.0,
    t0: float = 0.0,
    odom0: np.ndarray = ODOM_ORIGIN,
) -> tuple[float, np.ndarray]:
    """Feed odometry of a constant (v, ω) for ``seconds``; returns the last (t, odometry pose)."""
    v, w = twist
    dt = 1.0 / rate
    step = (
        np.array([v * dt, 0.0, w * dt])
        if abs(w) < 1e-12
        else np.array([v / w * math.sin(w * dt), v / w * (1 - math.cos(w * dt)), w * dt])
    )
    odom, t = np.array(odom0, dtype=float), t0
    tracker.on_odometry(t, *odom)
    for _ in range(round(seconds * rate)):
        t += dt
        odom = compose(odom, step)
        tracker.on_odometry(t, *odom)
    return t, odom


# ------------------------------------------------------------------------------ motion model
def test_standing_still_keeps_covariance_unchanged():
    assert not OdometryMotionModel().noise([0.0, 0.0, 0.0]).any()
    tracker = PoseTracker([1.0, 2.0, 0.3], P0)
    drive(tracker, (0.0, 0.0), seconds=3.0)
    np.testing.assert_array_equal(tracker.cov, P0)
    np.testing.assert_allclose(tracker.pose, [1.0, 2.0, 0.3], atol=1e-12)
    assert tracker.counts.predictions == 150


def test_covariance_grows_with_distance_and_rotation():
    traces = []
    for seconds in (1.0, 2.0, 4.0):
        tracker = PoseTracker([0.0, 0.0, 0.0], P0)
        drive(tracker, (0.5, 0.0), seconds)
        traces.append(np.trace(tracker.cov))
    assert traces[0] > np.trace(P0) and traces[0] < traces[1] < traces[2]
    spinning = PoseTracker([0.0, 0.0, 0.0], P0)
    drive(spinning, (0.0, 1.0), 2.0)
    assert np.all(np.diag(spinning.cov) > np.diag(P0))


def test_noise_does_not_depend_on_the_odometry_rate():
    # One increment of 1 m or fifty of 2 cm: the same accumulated translation variance.
    model = OdometryMotionModel()
    whole = model.noise([1.0, 0.0, 0.0])
    pieces = 50 * model.noise([0.02, 0.0, 0.0])
    np.testing.assert_allclose(whole[0, 0], pieces[0, 0], rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(model.noise([0.0, 0.0, 0.5])) > 0)  # turn on the spot


def test_backward_driving_is_not_a_half_turn():
    model = OdometryMotionModel()
    backward, forward = model.noise([-0.3, 0.0, 0.0]), model.noise([0.3, 0.0, 0.0])
    np.testing.assert_allclose(np.diag(backward), np.diag(forward))
    # Only the sign of the heading-lateral correlation differs (a heading error moves the robot
    # the other way when it reverses).
    np.testing.assert_allclose(np.abs(backward), np.abs(forward))


def test_straight_line_prediction_is_exact_without_noise():
    quiet = OdometryMotionConfig(alpha1=0, alpha2=0, alpha3=0, alpha4=0, floor_xy=0, floor_theta=0)
    start = np.array([1.0, 2.0, 0.5])
    tracker = PoseTracker(start, P0, quiet)
    drive(tracker, (0.8, 0.0), seconds=2.5)
    expected = start + np.array([2.0 * math.cos(0.5), 2.0 * math.sin(0.5), 0.0])
    np.testing.assert_allclose(tracker.pose, expected, atol=1e-9)


def test_calibration_scales_every_increment_in_any_odometry_frame():
    # a square driven with wheels that over-report distance by 4 % and turns by 5 %
    true_steps = [(1.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2)] * 4
    raw = [ODOM_ORIGIN]
    for dx, dy, dth in true_steps:
        raw.append(compose(raw[-1], (dx / 0.96, dy / 0.96, dth / 0.95)))
    calibrate = OdometryCalibration(translation_scale=0.96, rotation_scale=0.95)
    out = np.array([calibrate(*r) for r in raw])
    np.testing.assert_allclose(out[0], ODOM_ORIGIN)  # the first reading anchors the frame
    for k, step in enumerate(true_steps):
        np.testing.assert_allclose(relative(out[k], out[k + 1]), step, atol=1e-9)
    np.testing.assert_allclose(relative(out[0], out[-1]), 0.0, atol=1e-9)  # the square closes
    assert OdometryCalibration().identity and not calibrate.identity


def test_interpolation_follows_the_arc():
    a = np.array([1.0, 2.0, 3.0])
    b = compose(a, [1.0, 0.4, 0.8])
    np.testing.assert_allclose(interpolate(a, b, 0.0), a, atol=1e-12)
    np.testing.assert_allclose(interpolate(a, b, 1.0), b, atol=1e-12)
    # Consistent under subdivision: halfway, then halfway again = three quarters.
    np.testing.assert_allclose(
        interpolate(interpolate(a, b, 0.5), b, 0.5), interpolate(a, b, 0.75), atol=1e-12
    )


# --------------------------------------------------------------------------------------- EKF
@pytest.mark.parametrize(
    "theta, measured", [(math.pi - 0.05, -math.pi + 0.05), (-math.pi + 0.05, math.pi - 0.05)]
)
def test_update_across_the_wrap_moves_the_short_way(theta, measured):
    ekf = PoseEKF([0.0, 0.0, theta], np.diag([0.01, 0.01, 0.01]))
    outcome = ekf.update_pose([0.0, 0.0, measured], np.diag([0.01, 0.01, 0.01]))
    assert outcome.accepted
    assert abs(outcome.innovation[2]) == pytest.approx(0.1)
    # Equal weights: the posterior lies halfway, i.e. on ±π, not near 0.
    assert abs(wrap_angle(ekf.x[2] - math.pi)) < 1e-9
    assert -math.pi <= ekf.x[2] < math.pi


def test_rank_deficient_update_leaves_the_unobserved_direction_alone():
    observed = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).T
    observed[:, 0] /= math.sqrt(2.0)
    hidden = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
    frame = np.column_stack([observed, hidden])
    prior = frame @ np.diag([0.04, 0.01, 0.09]) @ frame.T  # no correlation with `hidden`
    ekf = PoseEKF([1.0, 2.0, 0.3], prior)
    outcome = ekf.update_pose([1.3, 2.1, 0.35], np.diag([0.01, 0.01, 0.001]), basis=observed)
    assert outcome.accepted and outcome.dof == 2
    assert hidden @ ekf.P @ hidden == pytest.approx(0.09, rel=1e-12)
    assert hidden @ ekf.x == pytest.approx(hidden @ [1.0, 2.0, 0.3], abs=1e-12)
    assert observed[:, 0] @ ekf.P @ observed[:, 0] < 0.04  # the observed ones did shrink


def test_nis_gate_rejects_an_outlier_and_accepts_a_consistent_measurement():
    tracker = PoseTracker([0.0, 0.0, 0.0], R_SMALL)
    tracker.on_odometry(0.0, *ODOM_ORIGIN)
    outlier = tracker.apply(0.0, [1.0, 0.0, 0.0], R_SMALL)
    assert not outlier.accepted and outlier.status == "rejected"
    assert outlier.nis > chi2.ppf(0.999, 3)
    np.testing.assert_array_equal(tracker.pose, [0.0, 0.0, 0.0])
    good = tracker.apply(0.0, [0.01, -0.01, 0.005], R_SMALL)
    assert good.accepted and good.dof == 3
    assert tracker.counts.rejected == 1 and tracker.counts.updates == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_covariance_stays_symmetric_positive_definite(seed):
    rng = np.random.default_rng(seed)
    tracker = PoseTracker(rng.normal(size=3), np.diag(rng.uniform(1e-6, 1.0, 3)))
    odom, t = rng.normal(size=3) * 100, 0.0
    tracker.on_odometry(t, *odom)
    for _ in range(60):
        t += rng.uniform(0.001, 0.1)
        odom = compose(odom, rng.normal(0.0, [0.05, 0.01, 0.1]))
        tracker.on_odometry(t, *odom)
        if rng.random() < 0.4:
            a = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 1.0)
            r = a @ a.T + 1e-10 * np.eye(3)
            k = int(rng.integers(1, 4))
            basis = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :k]
            z = tracker.pose + rng.normal(0.0, 0.1, 3)
            tracker.apply(t - rng.uniform(0.0, 0.5), z, r, basis)
        p = tracker.cov
        assert np.isfinite(tracker.pose).all()
        np.testing.assert_array_equal(p, p.T)
        assert np.linalg.eigvalsh(p).min() > 0.0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 12))
def test_one_prediction_with_composed_increments_equals_one_per_increment(seed, m):
    """The tracker bridges readings with one prediction: it must be the same EKF prediction."""
    rng = np.random.default_rng(seed)
    model = OdometryMotionModel()
    steps = rng.normal(0.0, [0.1, 0.03, 0.3], (m, 3))
    covs = np.array([model.noise(step) for step in steps])
    a = rng.normal(0.0, 0.2, (3, 3))
    start, p = rng.normal(0.0, [5.0, 5.0, 3.0]), a @ a.T + 1e-4 * np.eye(3)
    one_by_one, at_once = PoseEKF(start, p), PoseEKF(start, p)
    for step, cov in zip(steps, covs, strict=True):
        one_by_one.predict_odometry(step, cov)
    at_once.predict_odometry(*compose_increments(steps, covs))
    np.testing.assert_allclose(at_once.x[:2], one_by_one.x[:2], rtol=0, atol=1e-12)
    assert abs(wrap_angle(at_once.x[2] - one_by_one.x[2])) < 1e-12
    np.testing.assert_allclose(at_once.P, one_by_one.P, rtol=1e-10, atol=1e-14)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 12))
def test_composed_increments_carry_the_wheels_scale_as_each_step_does(seed, m):
    """With a scale error in the prediction (and steps that depend on the wheels in part, as a
    scan-matched one does), one composed prediction is still the same as m predictions."""
    rng = np.random.default_rng(seed)
    model = OdometryMotionModel()
    steps = rng.normal(0.0, [0.1, 0.03, 0.3], (m, 3))
    covs = np.array([model.noise(step) for step in steps])
    scales = steps * rng.uniform(0.0, 1.0, (m, 3)) * (1.0, 1.0, 0.0)
    a = rng.normal(0.0, 0.2, (3, 3))
    start, p = rng.normal(0.0, [5.0, 5.0, 3.0]), a @ a.T + 1e-2 * np.eye(3)
    one_by_one, at_once = PoseEKF(start, p), PoseEKF(start, p)
    d0 = rng.normal(0.0, 0.5, 3)
    one_by_one.d = at_once.d = d0
    variance = 0.03**2
    for step, cov, scale in zip(steps, covs, scales, strict=True):
        one_by_one.predict_odometry(step, cov, scale, variance)
    at_once.predict_odometry(*compose_increments(steps, covs, scales), variance)
    np.testing.assert_allclose(at_once.d, one_by_one.d, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(at_once.P, one_by_one.P, rtol=1e-10, atol=1e-14)


def test_a_straight_path_grows_the_scale_error_with_its_length():
    """Along a straight path of L metres, a scale error of σ_e moves the pose by σ_e·L: the
    variance along it is the wheels' random walk plus (σ_e L)², not linear in L."""
    sigma = 0.02
    tracker = PoseTracker(np.zeros(3), np.diag([1e-6, 1e-6, 1e-8]))
    tracker.motion.scale_variance = sigma**2
    drive(tracker, (0.5, 0.0), 20.0, odom0=np.zeros(3))  # 10 m east
    random_walk = PoseTracker(np.zeros(3), np.diag([1e-6, 1e-6, 1e-8]))
    drive(random_walk, (0.5, 0.0), 20.0, odom0=np.zeros(3))
    extra = tracker.cov[0, 0] - random_walk.cov[0, 0]
    assert extra == pytest.approx((sigma * 10.0) ** 2, rel=1e-6)
    assert tracker.cov[1, 1] == pytest.approx(random_walk.cov[1, 1], rel=1e-9)  # across: none
    np.testing.assert_allclose(tracker._state(-1)[0], random_walk.pose, atol=1e-12)


def test_a_fix_of_the_whole_pose_ends_the_scale_errors_drift_and_one_across_does_not():
    """Fixed after 10 m, then 1 m further: across the path only, the scale's share of the
    variance along it is (σ_e·11 m)²; fixed whole, (σ_e·1 m)²."""
    sigma, fix = 0.02, np.diag([1e-8, 1e-8, 1e-10])

    def along_variance(basis: np.ndarray | None, scale_variance: float) -> float:
        tracker = PoseTracker(np.zeros(3), np.diag([1e-6, 1e-6, 1e-8]))
        tracker.motion.scale_variance = scale_variance
        t, odom = drive(tracker, (0.5, 0.0), 20.0, odom0=np.zeros(3))
        assert tracker.apply(t, tracker.pose, fix, basis).accepted
        drive(tracker, (0.5, 0.0), 2.0, t0=t, odom0=odom)
        return float(tracker.cov[0, 0])

    for basis, length in ((np.eye(3)[:, 1:], 11.0), (None, 1.0)):
        extra = along_variance(basis, sigma**2) - along_variance(basis, 0.0)
        assert extra == pytest.approx((sigma * length) ** 2, rel=0.01)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_pose_and_the_scale_error_keep_a_joint_covariance(seed):
    """[[P, σ_e² d], [σ_e² dᵀ, σ_e²]] is the covariance of (pose, e) through any predictions
    and updates, full or partial (Schmidt: e itself is never updated)."""
    rng = np.random.default_rng(seed)
    model = OdometryMotionModel()
    variance = rng.uniform(1e-6, 0.01)
    ekf = PoseEKF(rng.normal(size=3), np.diag(rng.uniform(1e-6, 1.0, 3)), gate_prob=None)
    for _ in range(60):
        step = rng.normal(0.0, [0.05, 0.01, 0.1])
        ekf.predict_odometry(step, model.noise(step), step * (rng.uniform(), rng.uniform(), 0.0),
                             variance)
        if rng.random() < 0.4:
            a = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 1.0)
            k = int(rng.integers(1, 4))
            basis = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :k]
            ekf.update_pose(ekf.x + rng.normal(0.0, 0.1, 3), a @ a.T + 1e-10 * np.eye(3), basis)
        joint = np.zeros((4, 4))
        joint[:3, :3], joint[:3, 3], joint[3, :3] = ekf.P, variance * ekf.d, variance * ekf.d
        joint[3, 3] = variance
        assert np.linalg.eigvalsh(joint).min() > -1e-9 * np.abs(joint).max()


@pytest.mark.parametrize("carried", [True, False])
def test_monte_carlo_nees_with_a_wheel_scale_error_along_a_corridor(carried):
    """Wheels whose scale is off by e ~ N(0, σ_e²), fixes across a corridor only: with the
    scale carried the filter's covariance covers the error (NEES in the 95 % band); without it
    the filter is overconfident along the corridor."""
    runs, steps, dt, sigma = 60, 200, 0.1, 0.03
    model = OdometryMotionModel()
    r = np.diag([0.02**2, 0.02**2, 0.01**2])
    across = np.eye(3)[:, 1:]
    rng = np.random.default_rng(7)
    nees = np.zeros(runs)
    for run in range(runs):
        truth = np.zeros(3)
        tracker = PoseTracker(truth + rng.multivariate_normal(np.zeros(3), P0), P0, gate_prob=None)
        tracker.motion.scale_variance = sigma**2 if carried else 0.0
        e_scale = rng.normal(0.0, sigma)
        odom = ODOM_ORIGIN.copy()
        tracker.on_odometry(0.0, *odom)
        for k in range(steps):
            nominal = np.array([0.05, 0.0, 0.0])
            w = rng.multivariate_normal(np.zeros(3), model.noise(nominal))
            truth = compose(truth, nominal * (1.0 + e_scale, 1.0, 1.0) + w)
            odom = compose(odom, nominal)
            tracker.on_odometry((k + 1) * dt, *odom)
            if k % 10 == 9:
                z = truth + rng.multivariate_normal(np.zeros(3), r)
                tracker.apply((k + 1) * dt, z, r, across)
        e = tracker.pose - truth
        e[2] = wrap_angle(e[2])
        nees[run] = e @ np.linalg.solve(tracker.cov, e)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    assert (lo < nees.mean() < hi) == carried


def test_estimates_asked_for_rarely_equal_those_asked_for_at_every_reading():
    rng = np.random.default_rng(8)
    odometry = _odometry_stream(rng)
    measurements = sorted(_measurements(rng, odometry), key=lambda m: m[0])
    eager, lazy = PoseTracker([2.0, 1.0, 0.5], P0), PoseTracker([2.0, 1.0, 0.5], P0)
    pending = list(measurements)
    for t, odom in odometry:
        for tracker in (eager, lazy):
            tracker.on_odometry(t, *odom)
        eager.pose  # noqa: B018 - computes the estimate at every reading
        while pending and pending[0][0] <= t:
            for tracker in (eager, lazy):
                tracker.apply(*pending[0])
            pending.pop(0)
    np.testing.assert_allclose(lazy.pose, eager.pose, rtol=0, atol=1e-9)
    np.testing.assert_allclose(lazy.cov, eager.cov, rtol=0, atol=1e-12)
    assert lazy.counts == eager.counts


# ------------------------------------------------------------------- time and late measurements
def _odometry_stream(rng, seconds=3.0, rate=50.0):
    odom, out = ODOM_ORIGIN.copy(), []
    for i in range(round(seconds * rate) + 1):
        out.append((i / rate, odom.copy()))
        odom = compose(
            odom, [0.02 + rng.normal(0, 0.002), rng.normal(0, 0.001), 0.01 + rng.normal(0, 0.005)]
        )
    return out


def _replay(odometry, measurements, delays, **tracker_args):
    """Feed odometry and measurements ordered by arrival; measurement i arrives delays[i] late."""
    events = [(t, 0, i) for i, (t, _) in enumerate(odometry)]
    events += [(m[0] + d, 1, i) for i, (m, d) in enumerate(zip(measurements, delays, strict=True))]
    tracker = PoseTracker([2.0, 1.0, 0.5], P0, **tracker_args)
    outcomes = {}
    for _, kind, i in sorted(events):
        if kind == 0:
            tracker.on_odometry(odometry[i][0], *odometry[i][1])
        else:
            outcomes[i] = tracker.apply(*measurements[i])
    return tracker, outcomes


def _measurements(rng, odometry, rate=50.0):
    """Pose measurements consistent with the odometry (started at the tracker's initial pose)."""
    r = np.diag([0.03**2, 0.03**2, 0.01**2])
    along_corridor = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).T
    out = []
    for t in (0.2, 0.5, 0.713, 1.0, 1.337, 1.9, 2.21, 2.5):  # on and between odometry stamps
        i = int(t * rate)
        odom = interpolate(odometry[i][1], odometry[i + 1][1], t * rate - i)
        z = compose([2.0, 1.0, 0.5], relative(ODOM_ORIGIN, odom)) + rng.normal(0, 0.03, 3)
        out.append((t, z, r, along_corridor if t in (0.713, 1.9) else None))
    out.append((1.5, np.array([9.0, 9.0, 0.0]), r, None))  # an outlier, rejected either way
    return out


def test_late_measurements_give_the_same_estimate_as_in_order_ones():
    rng = np.random.default_rng(3)
    odometry = _odometry_stream(rng)
    measurements = _measurements(rng, odometry)
    on_time, _ = _replay(odometry, measurements, [0.0] * len(measurements))
    delays = rng.uniform(0.05, 0.6, len(measurements))
    late, outcomes = _replay(odometry, measurements, delays)
    np.testing.assert_allclose(late.pose, on_time.pose, rtol=0, atol=1e-9)
    np.testing.assert_allclose(late.cov, on_time.cov, rtol=0, atol=1e-12)
    for t in (2.6, 2.7371, 2.95):
        for a, b in zip(late.pose_at(t), on_time.pose_at(t), strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    assert late.counts.delayed == len(measurements)
    assert late.counts.updates == on_time.counts.updates == len(measurements) - 1
    assert outcomes[len(measurements) - 1].status == "rejected"


def test_late_measurement_applied_as_if_now_is_worse():
    # The latency experiment: a robot at 1 m/s, exact measurements 0.3 s late.
    errors = {}
    for delayed in (True, False):
        rng = np.random.default_rng(11)
        odometry = _odometry_stream(rng, seconds=4.0)
        truth = {round(t, 6): o for t, o in odometry}
        tracker = PoseTracker(relative(ODOM_ORIGIN, ODOM_ORIGIN), P0, delayed_updates=delayed)
        pending, err = [], []
        for t, odom in odometry:
            tracker.on_odometry(t, *odom)
            if round(t * 50) % 5 == 0:  # a measurement every 0.1 s, taken now, arriving later
                z = relative(ODOM_ORIGIN, truth[round(t, 6)])
                pending.append((t + 0.3, t, z))
            while pending and pending[0][0] <= t + 1e-9:
                _, taken, z = pending.pop(0)
                tracker.apply(taken, z, R_SMALL)
            err.append(np.hypot(*(tracker.pose[:2] - relative(ODOM_ORIGIN, odom)[:2])))
        errors[delayed] = float(np.sqrt(np.mean(np.square(err[50:]))))
    assert errors[True] < 0.5 * errors[False]


def test_measurement_older_than_the_history_is_dropped():
    tracker = PoseTracker([0.0, 0.0, 0.0], P0, history_seconds=0.5)
    drive(tracker, (0.5, 0.0), seconds=2.0)
    before = tracker.pose
    outcome = tracker.apply(1.0, before, R_SMALL)
    assert outcome.status == "dropped" and not outcome.accepted
    assert tracker.counts.dropped == 1
    np.testing.assert_array_equal(tracker.pose, before)
    assert tracker.pose_at(1.0) is None
    assert tracker.pose_at(1.6) is not None


def test_pose_at_interpolates_and_extrapolates_the_held_velocity():
    quiet = OdometryMotionConfig(alpha1=0, alpha2=0, alpha3=0, alpha4=0, floor_xy=0, floor_theta=0,
                                 max_acceleration=0.5, max_angular_acceleration=1.0)
    tracker = PoseTracker([0.0, 0.0, 0.0], P0, quiet)
    t_end, _ = drive(tracker, (1.0, 0.2), seconds=1.0)
    x, _ = tracker.pose_at(0.505)
    assert abs(x[2] - 0.101) < 1e-9  # 0.2 rad/s for 0.505 s
    # beyond the newest reading: 1 m/s and 0.2 rad/s held for T = 2 s, the pose widened by
    # (½aT²)² = 1 m² and (½αT²)² = 4 rad² on top of the newest covariance
    x, p = tracker.pose_at(t_end + 2.0)
    np.testing.assert_allclose(x, compose(tracker.pose, [2.0, 0.0, 0.4]), atol=0.02)
    np.testing.assert_allclose(np.diag(p) - np.diag(tracker.cov), [1.0, 1.0, 4.0], rtol=0.2)
    # a measurement past the odometry chains the extrapolation: half-way, then the rest; when
    # it tells nothing, the mean and the spread along the way are those of one go (sideways
    # the spread is wider: the heading's spread at half-way swings the rest of the way)
    straight = PoseTracker([0.0, 0.0, 0.0], P0, quiet)
    t_end, _ = drive(straight, (1.0, 0.0), seconds=1.0)
    x, p = straight.pose_at(t_end + 2.0)
    straight.apply(t_end + 1.0, straight.pose_at(t_end + 1.0)[0], np.eye(3) * 1e9)
    x_later, p_later = straight.pose_at(t_end + 2.0)
    np.testing.assert_allclose(x_later, x, atol=1e-6)
    np.testing.assert_allclose([p_later[0, 0], p_later[2, 2]], [p[0, 0], p[2, 2]], rtol=1e-3)
    assert p_later[1, 1] > p[1, 1]


def test_measurements_without_odometry_keep_the_history_bounded():
    tracker = PoseTracker([0.0, 0.0, 0.0], P0, history_seconds=1.0)
    t, odom = drive(tracker, (0.5, 0.0), seconds=1.0)
    for k in range(1, 500):  # the odometry stalls; measurements keep coming at 50 Hz
        assert tracker.apply(t + 0.02 * k, tracker.pose, R_SMALL).accepted
    assert len(tracker._nodes) <= 60
    tracker.on_odometry(t + 20.0, *compose(odom, [0.1, 0.0, 0.0]))
    assert tracker.counts.odometry_jumps == 0 and np.isfinite(tracker.pose).all()


# ----------------------------------------------------------------------- odometry hygiene
def test_odometry_jump_is_flagged_and_replaced_by_zero_motion():
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.5, 0.0), seconds=1.0)
    pose, cov = tracker.pose, tracker.cov
    teleported = odom + np.array([5.0, 0.0, 0.0])
    tracker.on_odometry(t + 0.02, *teleported)  # 250 m/s
    assert tracker.counts.odometry_jumps == 1
    np.testing.assert_allclose(tracker.pose, pose, atol=1e-12)
    assert np.all(np.diag(tracker.cov) > np.diag(cov))
    turned = teleported + np.array([0.0, 0.0, 1.0])
    tracker.on_odometry(t + 0.02, *turned)  # same stamp: 1 rad is no turn of jump_min_dt
    assert tracker.counts.odometry_jumps == 2
    # Afterwards the new odometry frame is followed normally.
    tracker.on_odometry(t + 0.04, *turned)
    assert tracker.counts.odometry_jumps == 2


def test_a_turn_lumped_after_a_stalled_odometry_is_motion_not_a_jump():
    """fhw's odometry repeats one reading for 0.3 s, then reports a 75° turn in 0.16 s (8 rad/s,
    beyond twice the 3 rad/s limit). Over the stall too it is 2.6 rad/s: the robot turned, and
    the filter follows. Without the stall the same reading is a jump; after a standstill longer
    than ``max_stall`` a teleport is still one."""
    turn = math.radians(75.0)
    stalled = PoseTracker([0.0, 0.0, 0.0], P0)
    for t in (0.0, 0.16, 0.32):
        stalled.on_odometry(t, 0.0, 0.0, 0.0)
    stalled.on_odometry(0.48, 0.0, 0.0, turn)
    assert stalled.counts.odometry_jumps == 0
    assert stalled.pose[2] == pytest.approx(turn)

    moving = PoseTracker([0.0, 0.0, 0.0], P0)
    for k, t in enumerate((0.0, 0.16, 0.32)):
        moving.on_odometry(t, 0.0, 0.0, 0.05 * k)
    moving.on_odometry(0.48, 0.0, 0.0, 0.1 + turn)
    assert moving.counts.odometry_jumps == 1
    assert moving.pose[2] == pytest.approx(0.1)

    standing = PoseTracker([0.0, 0.0, 0.0], P0)
    for k in range(601):  # ten minutes at rest, then the odometry is reset 10 m away
        standing.on_odometry(k * 1.0, 0.0, 0.0, 0.0)
    standing.on_odometry(600.16, 10.0, 0.0, 0.0)
    assert standing.counts.odometry_jumps == 1
    np.testing.assert_allclose(standing.pose, 0.0, atol=1e-12)


def test_unmeasured_motion_spreads_the_estimate_over_the_robots_reach():
    """A reading that says its increment misses 3 s of motion (a hole in a log) keeps the
    estimate where the wheels say, spread by the jump covariance of those 3 s; the same reading
    without it is the plain, confident prediction."""
    told, untold = PoseTracker([0.0, 0.0, 0.0], P0), PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(told, (0.5, 0.0), seconds=1.0)
    drive(untold, (0.5, 0.0), seconds=1.0)
    step = compose(odom, [0.05, 0.0, 0.0])
    told.on_odometry(t + 3.0, *step, unmeasured=3.0)
    untold.on_odometry(t + 3.0, *step)
    np.testing.assert_allclose(told.pose, untold.pose)
    np.testing.assert_allclose(told.cov, untold.cov + told.motion.jump_noise(3.0), atol=1e-12)
    assert math.sqrt(told.cov[2, 2]) > math.pi  # any heading
    told.on_odometry(t + 3.0, *step, unmeasured=0.0)  # a repeat without news is a no-op
    assert told.counts.predictions == untold.counts.predictions


def test_readings_with_equal_stamps_keep_their_motion():
    """Coarse or repeated stamps (logs printed with %g, 0.1 s clocks): the motion of readings
    that share a stamp is composed, not taken for a jump."""
    exact = PoseTracker([0.0, 0.0, 0.0], P0)
    coarse = PoseTracker([0.0, 0.0, 0.0], P0)
    for k in range(101):
        odom = (0.005 * k, 0.0, 0.002 * k)
        exact.on_odometry(0.01 * k, *odom)
        coarse.on_odometry(0.1 * (k // 10), *odom)  # ten readings per stamp
    assert coarse.counts.odometry_jumps == 0
    np.testing.assert_allclose(coarse.pose, exact.pose, atol=1e-12)


def test_backwards_duplicate_and_non_finite_inputs():
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.5, 0.0), seconds=0.5)
    pose, predictions = tracker.pose, tracker.counts.predictions
    tracker.on_odometry(t, *odom)  # duplicate
    tracker.on_odometry(t - 0.1, *(odom + 1.0))  # backwards
    tracker.on_odometry(t + 0.02, math.nan, 0.0, 0.0)
    assert tracker.counts.predictions == predictions
    assert tracker.counts.odometry_backwards == 1 and tracker.counts.invalid == 1
    bad = [
        tracker.apply(t, [math.nan, 0, 0], R_SMALL),
        tracker.apply(t, pose, np.full((3, 3), math.inf)),
        tracker.apply(t, pose, R_SMALL, np.array([[math.nan], [0.0], [1.0]])),
    ]
    assert all(o.status == "invalid" for o in bad)
    assert tracker.counts.invalid == 4
    with pytest.raises(ValueError, match="orthonormal"):
        tracker.apply(t, pose, R_SMALL, np.array([[1.0, 0.5], [0.0, 1.0], [0.0, 0.0]]))
    np.testing.assert_array_equal(tracker.pose, pose)


def test_reset_replaces_the_estimate_and_forgets_the_past():
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.5, 0.0), seconds=1.0)
    tracker.reset([5.0, 5.0, 1.0], np.eye(3) * 0.1)
    np.testing.assert_array_equal(tracker.pose, [5.0, 5.0, 1.0])
    assert tracker.apply(t - 0.5, [5.0, 5.0, 1.0], R_SMALL).status == "dropped"
    tracker.on_odometry(t + 0.02, *compose(odom, [0.01, 0.0, 0.0]))
    np.testing.assert_allclose(tracker.pose, compose([5.0, 5.0, 1.0], [0.01, 0, 0]), atol=1e-12)


def test_a_reset_while_the_odometry_is_late_does_not_count_its_motion_twice():
    """The robot turns at 1 rad/s; the odometry stops for 3 s. A relocalization at 2.5 s into
    the gap sets the pose there, turned by the 2.5 rad the robot made. When the odometry comes
    back at 3 s with the whole gap's turn, only the half second after the reset is added
    (before: all 3 rad on top of the reset pose, 2.5 rad off)."""
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.0, 1.0), seconds=1.0)
    assert tracker.reset([1.0, 2.0, 1.0 + 2.5], P0 * 0.01, t + 2.5)
    assert tracker.odometry_time == t  # the newest reading is still the one before the gap
    tracker.on_odometry(t + 3.0, *compose(odom, [0.0, 0.0, 3.0]))
    assert wrap_angle(tracker.pose[2] - (1.0 + 3.0)) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(tracker.pose[:2], [1.0, 2.0], atol=1e-9)


def test_a_reset_in_the_past_keeps_the_odometry_since():
    """A relocalization found on a scan 0.4 s older than the newest reading sets the pose at
    the scan's time: the 0.2 m driven since are added (before: lost)."""
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, _ = drive(tracker, (0.5, 0.0), seconds=1.0)
    tracker.apply(t - 0.1, [0.45, 0.0, 0.0], R_SMALL)  # a measurement after it is forgotten
    assert tracker.reset([5.0, 5.0, math.pi / 2], P0 * 0.01, t - 0.4)
    np.testing.assert_allclose(tracker.pose, [5.0, 5.2, math.pi / 2], atol=1e-9)
    assert tracker.apply(t - 0.5, [5.0, 5.0, 1.0], R_SMALL).status == "dropped"


def test_a_reset_in_the_past_keeps_a_matched_steps_noise():
    """Scan odometry measured the last 0.2 s to 0.1° (its own step covariance); a reset 0.3 s
    back re-filters the odometry since with that noise, not the wheels' wider one."""
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.5, 1.0), seconds=1.0)
    since = tracker._nodes[-11].t  # the reading 0.2 s before (the scan the match is from)
    matched = compose(odom, [0.0, 0.0, 0.0])
    tight = np.diag([1e-8, 1e-8, math.radians(0.1) ** 2])
    assert tracker.correct_odometry(t, matched, since, tight)
    assert tracker.reset([1.0, 1.0, 0.0], np.diag([1e-4, 1e-4, 1e-6]), t - 0.3)
    wheels = PoseTracker([0.0, 0.0, 0.0], P0)
    drive(wheels, (0.5, 1.0), seconds=1.0)
    wheels.reset([1.0, 1.0, 0.0], np.diag([1e-4, 1e-4, 1e-6]), t - 0.3)
    assert tracker.cov[2, 2] < 0.7 * wheels.cov[2, 2]


def test_a_branch_is_the_filter_a_reset_would_give():
    """A followed hypothesis branched off the filter at a time predicts as the filter reset to
    it there would, reading for reading, and leaves the filter as it was."""
    tracker = PoseTracker([0.0, 0.0, 0.0], P0)
    t, odom = drive(tracker, (0.5, 0.3), seconds=1.0)
    before = tracker.pose
    branch = tracker.branch([3.0, 1.0, 0.5], P0, t - 0.3)
    reset = PoseTracker([0.0, 0.0, 0.0], P0)
    drive(reset, (0.5, 0.3), seconds=1.0)
    reset.reset([3.0, 1.0, 0.5], P0, t - 0.3)
    np.testing.assert_array_equal(tracker.pose, before)
    for k in range(1, 6):
        reading = compose(odom, [0.01 * k, 0.0, 0.006 * k])
        branch.on_odometry(t + 0.02 * k, *reading)
        reset.on_odometry(t + 0.02 * k, *reading)
        np.testing.assert_allclose(branch.pose, reset.pose, atol=1e-12)
        np.testing.assert_allclose(branch.cov, reset.cov, atol=1e-12)


# ------------------------------------------------------------------------------- consistency
def test_monte_carlo_nees_is_inside_the_95_percent_band():
    """Odometry reports a nominal increment δ; the true motion is δ + w, w ~ N(0, Q(δ)) — the
    model's own statement about the robot — and pose measurements are drawn from R.
    """
    runs, steps, dt = 50, 150, 0.1
    model = OdometryMotionModel()
    r = np.diag([0.05**2, 0.05**2, 0.03**2])
    rng = np.random.default_rng(2024)
    nees = np.zeros((runs, steps))
    for run in range(runs):
        truth = np.array([1.0, 1.0, 0.0])
        tracker = PoseTracker(truth + rng.multivariate_normal(np.zeros(3), P0), P0, gate_prob=None)
        odom = ODOM_ORIGIN.copy()
        tracker.on_odometry(0.0, *odom)
        for k in range(steps):
            nominal = np.array([0.05, 0.0, 0.03 * math.sin(k / 15)])  # 0.5 m/s, weaving
            w = rng.multivariate_normal(np.zeros(3), model.noise(nominal))
            truth = compose(truth, nominal + w)
            odom = compose(odom, nominal)
            tracker.on_odometry((k + 1) * dt, *odom)
            if k % 10 == 9:
                tracker.apply((k + 1) * dt, truth + rng.multivariate_normal(np.zeros(3), r), r)
            e = tracker.pose - truth
            e[2] = wrap_angle(e[2])
            nees[run, k] = e @ np.linalg.solve(tracker.cov, e)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    average = nees.mean(axis=0)  # over runs, per time step
    assert lo < average.mean() < hi
    # Per step the band holds 95 % of the time; successive steps are correlated, so allow some.
    assert np.mean((average > lo) & (average < hi)) > 0.75


def test_increment_is_frame_independent():
    a, b = np.array([0.0, 0.0, 0.0]), np.array([0.3, 0.1, 0.2])
    np.testing.assert_allclose(
        increment(compose(ODOM_ORIGIN, a), compose(ODOM_ORIGIN, b)), increment(a, b), atol=1e-12
    )


@settings(max_examples=300, deadline=None)
@given(k=st.integers(1, 3), seed=st.integers(0, 2**32 - 1),
       signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=3, max_size=3))
def test_positive_definite_agrees_with_cholesky(k, seed, signs) -> None:
    """Sylvester's criterion says what a Cholesky factorisation says, for symmetric matrices
    whose eigenvalues (of either sign) are not within rounding of zero."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(k, k)))
    scale = 10.0 ** rng.uniform(-6, 2, k)
    m = (q * (np.array(signs[:k]) * scale)) @ q.T
    m = 0.5 * (m + m.T)
    try:
        np.linalg.cholesky(m)
        expected = True
    except np.linalg.LinAlgError:
        expected = False
    assert positive_definite(m) is expected
    assert not positive_definite(np.full((k, k), np.nan))


@settings(max_examples=500, deadline=None)
@given(st.floats(), st.floats(), st.floats(0.0, 1e6), st.booleans(), st.floats(-1e-9, 1e-9))
@example(0.6, 0.8, 1.0, False, 0.0)  # a radius of exactly the hypotenuse
@example(3e-200, 4e-200, 5e-200, False, 0.0)  # squares that underflow
@example(1206152892812347.0, 1206152892812347.0, 0.0, True, 0.0)  # the two hypots differ
@example(2.6547026634909027e-161, 2.6547026634909027e-161, 0.0, True, 0.0)  # subnormal squares
def test_within_radius_is_hypots_comparison(dx: float, dy: float, radius: float,
                                            on_circle: bool, nudge: float) -> None:
    """The squared prefilter answers as ``hypot(dx, dy) <= radius`` does, to the last bit:
    anywhere, and within a relative 1e-9 of the circle (``on_circle``). The hypot is the C
    library's, which NumPy and the compiled kernels call (``np.hypot``); Python's
    ``math.hypot`` has its own algorithm and may differ from it in the last bit."""
    with np.errstate(over="ignore"):  # an infinite length is an answer here, not an accident
        length = float(np.hypot(dx, dy))
    if on_circle and math.isfinite(length):
        radius = length * (1.0 + nudge)
    assert within_radius(dx, dy, radius) is (length <= radius)

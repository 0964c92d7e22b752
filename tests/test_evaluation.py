"""Metrics on hand-made trajectories whose errors are known exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from fusion.evaluation import (
    ATE,
    RPE,
    Alignment,
    DeltaUnit,
    LostFraction,
    RelationError,
    Trajectory,
    align_se2,
    associate,
    chi2_band,
    nees,
    summary_table,
    window_means,
)
from fusion.io.relations import Relations
from houghloc.geometry import compose, inverse, relative, wrap_angle


def loop(n=200, dt=0.1) -> Trajectory:
    """A robot driving a circle of radius 5 m."""
    t = np.arange(n) * dt
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    poses = np.column_stack((5 * np.cos(a), 5 * np.sin(a), a + np.pi / 2))
    return Trajectory(t, poses)


pose = st.tuples(
    st.floats(-100, 100), st.floats(-100, 100), st.floats(-np.pi, np.pi, exclude_max=True)
)


@settings(max_examples=50, deadline=None)
@given(pose, pose)
def test_batched_pose_algebra_matches_geometry(a, b):
    """The batched and the single-pose forms agree; headings as angles (−π and π are one)."""

    def same(batched, single):
        batched, single = np.asarray(batched, float), np.asarray(single, float)
        np.testing.assert_allclose(batched[:2], single[:2], atol=1e-9)
        assert abs(wrap_angle(batched[2] - single[2])) <= 1e-9

    same(compose([a], [b])[0], compose(a, b))
    same(inverse([a])[0], inverse(a))
    same(relative([a], [b])[0], relative(a, b))


def test_associate_nearest_within_tolerance_one_to_one():
    est_t = np.array([0.0, 0.095, 0.101, 0.5, 0.31])
    ref_t = np.array([0.3, 0.1, 0.0])
    match = associate(est_t, ref_t, max_dt=0.02)
    # 0.095 and 0.101 both want 0.1: the closer in time wins; 0.5 has nothing within 0.02.
    pairs = list(zip(match.est_index.tolist(), match.ref_index.tolist(), strict=True))
    assert pairs == [(0, 2), (2, 1), (4, 0)]
    assert match.as_dict()["estimated"] == 5


def test_ate_known_offset_gives_known_rmse():
    ref = loop()
    est = Trajectory(ref.t + 0.005, ref.poses + np.array([0.3, -0.4, np.radians(2.0)]))
    result = ATE().compute(est, ref)
    assert result.association.matched == len(ref)
    assert result.position["rmse"] == pytest.approx(0.5)
    assert result.position["max"] == pytest.approx(0.5)
    assert result.heading_deg["rmse"] == pytest.approx(2.0)
    assert result.as_dict()["position_rmse_m"] == pytest.approx(0.5)


def test_ate_heading_error_wraps():
    ref = Trajectory([0.0], [[0.0, 0.0, np.pi - 0.01]])
    est = Trajectory([0.0], [[0.0, 0.0, -np.pi + 0.01]])
    assert ATE().compute(est, ref).heading_deg["max"] == pytest.approx(np.degrees(0.02))


def test_se2_alignment_recovers_a_known_rigid_transform():
    ref = loop()
    transform = np.array([12.0, -3.0, 0.7])
    # The odometry lives in its own frame: est = transform⁻¹ ⊕ ref.
    est = Trajectory(ref.t, compose(inverse(transform), ref.poses))
    assert ATE().compute(est, ref).position["rmse"] > 5.0
    aligned = ATE(alignment=Alignment.SE2).compute(est, ref)
    np.testing.assert_allclose(aligned.transform, transform, atol=1e-9)
    assert aligned.position["max"] < 1e-9 and aligned.heading_deg["max"] < 1e-9
    np.testing.assert_allclose(align_se2(est.poses, ref.poses), transform, atol=1e-9)


def test_alignment_needs_two_distinct_positions():
    with pytest.raises(ValueError, match="≥ 2"):
        align_se2([[0.0, 0.0, 0.0]], [[1.0, 1.0, 0.0]])


def test_rpe_zero_for_a_rigidly_moved_path_and_known_for_a_scaled_one():
    ref = loop()
    moved = Trajectory(ref.t, compose([3.0, 4.0, 1.0], ref.poses))
    rpe = RPE(delta=1.0, unit=DeltaUnit.SECONDS).compute(moved, ref)
    assert rpe.count == len(ref) - 10
    assert rpe.translation["max"] < 1e-9 and rpe.rotation_deg["max"] < 1e-9
    # A straight path with 10 % too long steps: each 1-frame relative motion is 10 % too long.
    t = np.arange(20.0)
    straight = Trajectory(t, np.column_stack((t, np.zeros(20), np.zeros(20))))
    scaled = Trajectory(t, np.column_stack((1.1 * t, np.zeros(20), np.zeros(20))))
    rpe = RPE(delta=1, unit=DeltaUnit.FRAMES).compute(scaled, straight)
    assert rpe.count == 19
    np.testing.assert_allclose(rpe.translation_errors, 0.1)
    rpe = RPE(delta=5.0, unit=DeltaUnit.METERS).compute(scaled, straight)
    np.testing.assert_allclose(rpe.translation_errors, 0.5)


def test_lost_fraction_counts_position_or_heading_beyond_thresholds():
    ref = loop(100)
    poses = ref.poses.copy()
    poses[:25, 0] += 0.5  # 25 beyond 0.3 m
    poses[25:40, 2] += np.radians(6.0)  # 15 beyond 5°
    poses[40:60, 0] += 0.2  # 20 within both thresholds
    lost = LostFraction().compute(Trajectory(ref.t, poses), ref)
    assert lost.count == 40 and lost.fraction == pytest.approx(0.4)
    assert LostFraction(max_position=0.1).compute(Trajectory(ref.t, poses), ref).count == 60


def test_relation_errors_exact_on_synthetic_data():
    ref = loop()
    i1 = np.arange(0, 180, 3)
    i2 = i1 + 7
    truth_motion = relative(ref.poses[i1], ref.poses[i2])
    # Perturb every reference relation by a known error; the estimate is the true path.
    error = np.array([0.03, -0.04, np.radians(1.5)])
    relations = Relations(ref.t[i1], ref.t[i2], compose(truth_motion, error))
    result = RelationError().compute(ref, relations)
    assert result.count == len(i1) and result.missing == 0
    # ⊖(m ⊕ e) ⊕ m = ⊖e: the translation error is |R(−e_θ) e_xy| = 0.05, rotation 1.5°.
    np.testing.assert_allclose(result.translation_errors, 0.05, atol=1e-12)
    np.testing.assert_allclose(np.degrees(result.rotation_errors), 1.5, atol=1e-9)
    assert result.as_dict()["translation_mean_m"] == pytest.approx(0.05)
    assert result.translation["std"] == pytest.approx(0.0, abs=1e-12)
    # Relations whose times have no estimate within tolerance are counted, not guessed.
    shifted = Relations(relations.t1 + 0.05, relations.t2, relations.delta)
    assert RelationError(max_dt=0.02).compute(ref, shifted).missing == len(i1)


def test_nees_mean_and_band():
    rng = np.random.default_rng(0)
    n, cov = 4000, np.diag([0.04, 0.09, 0.01])
    errors = rng.multivariate_normal(np.zeros(3), cov, size=n)
    result = nees(errors, np.broadcast_to(cov, (n, 3, 3)))
    assert result.mean == pytest.approx(3.0, rel=0.05)
    lo, hi = result.band
    np.testing.assert_allclose([lo, hi], chi2.ppf([0.025, 0.975], 3 * n) / n)
    assert result.consistent
    # Overconfident covariances (4× too small) are flagged.
    assert not nees(errors, np.broadcast_to(cov / 4, (n, 3, 3))).consistent


def test_nees_wraps_the_angle_and_matches_the_formula():
    e = np.array([[0.1, -0.2, 2 * np.pi - 0.1]])
    p = np.array([[[0.04, 0.01, 0.0], [0.01, 0.09, 0.0], [0.0, 0.0, 0.01]]])
    wrapped = np.array([0.1, -0.2, -0.1])
    expected = wrapped @ np.linalg.inv(p[0]) @ wrapped
    assert nees(e, p).values[0] == pytest.approx(expected)
    assert chi2_band(1, 2) == pytest.approx(tuple(chi2.ppf([0.025, 0.975], 2)))


def test_summary_table_formats_rows():
    table = summary_table(
        [{"log": "intel", "rmse_m": 0.123456, "scans": 910}, {"log": "aces", "rmse_m": 1.5}]
    )
    lines = table.splitlines()
    assert lines[0].split() == ["log", "rmse_m", "scans"]
    assert "0.1235" in lines[2] and lines[3].split() == ["aces", "1.5"]
    assert summary_table([[1, 2.0]], headers=["a", "b"]).splitlines()[2].split() == ["1", "2"]


@settings(max_examples=60, deadline=None)
@given(gaps=st.lists(st.floats(0.01, 3.0), min_size=1, max_size=60),
       values=st.lists(st.floats(0.0, 1.0), min_size=60, max_size=60))
def test_window_means_equal_the_brute_force_means(gaps, values):
    """Each full window's mean, by prefix sums, equals the mean of the values whose time lies
    in [t_i, t_i + 10 s); a log shorter than a window has one, its whole mean."""
    t = np.cumsum([0.0, *gaps])
    v = np.array(values[:len(t)])
    got = window_means(t, v, 10.0)
    full = [i for i in range(len(t)) if t[i] + 10.0 <= t[-1]]
    if not full:
        assert got == pytest.approx([v.mean()])
    else:
        want = [v[(t >= t[i]) & (t < t[i] + 10.0)].mean() for i in full]
        assert got == pytest.approx(want)

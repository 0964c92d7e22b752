"""Voting, peaks and refinement: against a naive reference, at the wrap, at the noise floor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from houghloc import HoughConfig, observe_lines
from houghloc.peaks import find_peaks
from houghloc.refine import _by_line_then_along, _distinct, refine_lines
from houghloc.transform import make_grid, vote

CFG = HoughConfig()


def line_points(theta: float, rho: float, s0: float, s1: float, n: int, sigma: float = 0.0,
                rng: np.random.Generator | None = None) -> np.ndarray:
    normal = np.array([math.cos(theta), math.sin(theta)])
    along = np.array([-normal[1], normal[0]])
    s = np.linspace(s0, s1, n)
    noise = (rng.normal(0, sigma, n) if rng is not None else np.zeros(n))
    return rho * normal + s[:, None] * along + (noise)[:, None] * normal


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


@pytest.mark.parametrize(("config", "reach"), [
    (CFG, 9.0),  # every point within ρ_max
    (CFG, 30.0),  # points beyond ρ_max, whose far votes must be dropped
    (HoughConfig(theta_step_deg=7.0, rho_step=0.25, rho_max=6.0, rho_margin_cells=3), 8.0),
])
def test_vote_matches_naive_double_loop(config: HoughConfig, reach: float) -> None:
    grid = make_grid(config)
    assert grid.n_theta % 2 == 0  # θ + π is a row: the half-circle voting relies on it
    pts = np.random.default_rng(3).uniform(-reach, reach, (60, 2))
    naive = np.zeros((grid.n_theta, grid.n_rho), dtype=int)
    for x, y in pts:
        for i, th in enumerate(grid.thetas):
            j = math.floor((x * math.cos(th) + y * math.sin(th) - grid.rho_min) / grid.rho_step)
            if 0 <= j < grid.n_rho:
                naive[i, j] += 1
    np.testing.assert_array_equal(vote(pts, grid), naive)


@pytest.mark.parametrize("bad", [(math.nan, 1.0), (math.inf, 0.0), (-math.inf, 2.0),
                                 (math.nan, math.nan), (1e200, 1e200), (1e30, 0.0)])
@pytest.mark.parametrize("spread", [0.05, 3.0, 30.0])
def test_a_non_finite_or_absurd_point_casts_no_vote(bad, spread) -> None:
    """A point that is not finite, or far beyond ρ_max, leaves the accumulator as the other
    points make it, whatever their reach (votes kept to the cells they can reach)."""
    grid = make_grid(CFG)
    pts = np.random.default_rng(5).uniform(-spread, spread, (40, 2))
    np.testing.assert_array_equal(vote(np.vstack((pts[:20], [bad], pts[20:])), grid),
                                  vote(pts, grid))
    assert len(observe_lines(np.vstack((pts, [bad])), CFG)[2]) == len(observe_lines(pts, CFG)[2])


@settings(max_examples=40, deadline=None)
@given(gap=st.floats(0.2, 3.0), n_left=st.integers(5, 40), n_right=st.integers(1, 40))
def test_a_line_splits_exactly_at_gaps_wider_than_piece_gap(gap, n_left, n_right) -> None:
    """Two collinear runs of points 5 cm apart, separated by ``gap``: one piece if the gap is at
    most ``piece_gap``, else two, and a run with fewer than ``min_piece_points`` is dropped."""
    config = HoughConfig(min_line_length=0.0)
    assume(abs(gap - config.piece_gap) > 1e-6)  # at the threshold itself rounding decides
    s = np.concatenate((np.arange(n_left) * 0.05, (n_left - 1) * 0.05 + gap
                        + np.arange(n_right) * 0.05))
    pts = np.column_stack((s - 1.0, np.full(len(s), 2.0)))  # the line y = 2
    lines = refine_lines(pts, np.array([np.pi / 2]), np.array([2.0]), config)
    assert len(lines) == 1
    split = gap > config.piece_gap + 1e-9
    kept = n_left + (n_right if not split or n_right >= config.min_piece_points else 0)
    if split and n_left < config.min_piece_points:
        kept -= n_left
    assert int(lines.n[0]) == kept


@settings(max_examples=60, deadline=None)
@given(theta=st.floats(0.0, 2 * math.pi, exclude_max=True), rho=st.floats(0.4, 8.0),
       s0=st.floats(-4.0, 0.0), length=st.floats(1.0, 4.0))
@example(theta=3.5234375, rho=0.40625, s0=-3.375, length=1.0)  # peaks as its twin
def test_a_line_is_found_and_refined_exactly(theta, rho, s0, length) -> None:
    pts = line_points(theta, rho, s0, s0 + length, 80)
    grid, acc, lines = observe_lines(pts, CFG)
    assert len(lines) == 1
    # the grid peak is as close to the truth as the grid can tell (cyclic in θ): a short piece
    # fills one or two ρ cells over a range of θ as wide as asin(2δρ / length). A short line
    # near the sensor may peak as its twin (θ + π, −ρ) in the cells below ρ = 0: the same line.
    peaks = find_peaks(acc, len(pts), CFG)
    th0, _rh0 = grid.cell_center(peaks.i_theta[0], peaks.i_rho[0])
    spread = math.asin(min(1.0, 2 * grid.rho_step / length))
    assert min(angle_diff(th0, theta), angle_diff(th0, theta + math.pi)) <= (
        1.5 * grid.theta_step + spread)
    # ... and the refinement recovers the line itself, far below the grid
    assert angle_diff(lines.theta[0], theta) < 1e-7
    assert abs(lines.rho[0] - rho) < 1e-7


def test_peaks_wrap_around_theta() -> None:
    """A peak straddling θ = 0 and θ = 2π is one peak, not two (cyclic suppression)."""
    grid = make_grid(CFG)
    acc = np.zeros((grid.n_theta, grid.n_rho), dtype=np.int64)
    acc[0, 50] = 40
    acc[grid.n_theta - 1, 50] = 39  # the same line, just across the wrap
    acc[grid.n_theta - 2, 50] = 5
    peaks = find_peaks(acc, 100, CFG)
    assert list(zip(peaks.i_theta.tolist(), peaks.i_rho.tolist(), strict=True)) == [(0, 50)]


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_theta=st.integers(8, 24), n_rho=st.integers(1, 40),
       w=st.integers(1, 3), h=st.integers(1, 3), threshold=st.integers(2, 6),
       empty=st.integers(0, 40), limit=st.integers(1, 40))
def test_peaks_follow_their_definition(seed, n_theta, n_rho, w, h, threshold, empty,
                                       limit) -> None:
    """Every cell at or above the threshold that no cell of its window (±w rows, wrapping
    around θ; ±h columns, cut at the ends) exceeds, strongest first, in row order among equals,
    the first ``limit``; with columns of low counts beside the votes, as a scan leaves beyond its
    farthest point."""
    rng = np.random.default_rng(seed)
    acc = rng.integers(0, 8, (n_theta, n_rho)).astype(np.int32)
    acc[:, : min(empty, n_rho) // 2] = rng.integers(0, threshold, (n_theta, min(empty, n_rho) // 2))
    acc[:, n_rho - min(empty, n_rho) // 3:] = 0
    config = HoughConfig(nms_theta_cells=w, nms_rho_cells=h, peak_min_votes=threshold,
                         peak_fraction=0.01)
    expected = []
    for i in range(n_theta):
        for j in range(n_rho):
            rows = [(i + d) % n_theta for d in range(-w, w + 1)]
            window = acc[rows][:, max(j - h, 0): j + h + 1]
            if acc[i, j] >= threshold and acc[i, j] >= window.max():
                expected.append((-int(acc[i, j]), i, j))
    expected = sorted(expected, key=lambda e: e[0])[:limit]  # stable: row order among equals
    peaks = find_peaks(acc, 1, config, limit=limit)
    assert list(zip(peaks.i_theta.tolist(), peaks.i_rho.tolist(), strict=True)) == [
        (i, j) for _, i, j in expected]
    assert peaks.votes.tolist() == [-v for v, _, _ in expected]


def test_line_with_normal_at_the_wrap_is_one_precise_line() -> None:
    rng = np.random.default_rng(0)
    for theta in (math.radians(0.7), math.radians(359.3), 0.0):
        pts = line_points(theta, 3.0, -2.0, 2.0, 120, 0.01, rng)
        _, _, lines = observe_lines(pts, CFG)
        assert len(lines) == 1
        assert angle_diff(lines.theta[0], theta) < math.radians(0.3)
        assert abs(lines.rho[0] - 3.0) < 0.01


def test_line_through_the_sensor() -> None:
    """A painted line under the robot (ρ ≈ 0): found once, in either representation."""
    pts = line_points(math.radians(80), 0.02, -2.0, 2.0, 100, 0.005, np.random.default_rng(1))
    _, _, lines = observe_lines(pts, CFG)
    assert len(lines) == 1
    assert abs(lines.rho[0]) < 0.03
    assert min(angle_diff(lines.theta[0], math.radians(80)),
               angle_diff(lines.theta[0], math.radians(260))) < math.radians(0.5)


def test_refinement_reaches_the_noise_floor_with_an_honest_covariance() -> None:
    """σ = 1 cm, 150 points over 4 m: errors far below the 3° × 10 cm grid, NEES ≈ 2 dof.
    A synthetic line is exact: no floor for a map's model error on its covariance."""
    exact = CFG.model_copy(update={"line_rho_floor": 0.0, "line_theta_floor_deg": 0.0})
    rng = np.random.default_rng(42)
    grid = make_grid(CFG)
    nees, errs = [], []
    for _ in range(300):
        theta, rho = rng.uniform(0, 2 * math.pi), rng.uniform(1.0, 6.0)
        pts = line_points(theta, rho, -2.0, 2.0, 150, 0.01, rng)
        acc = vote(pts, grid)
        pk = find_peaks(acc, len(pts), CFG)
        th0, rh0 = grid.cell_center(pk.i_theta[:1], pk.i_rho[:1])
        lines = refine_lines(pts, th0, rh0, exact)
        e = np.array([(lines.theta[0] - theta + math.pi) % (2 * math.pi) - math.pi,
                      lines.rho[0] - rho])
        nees.append(e @ np.linalg.solve(lines.cov[0], e))
        errs.append(np.abs(e))
    errs = np.array(errs)
    # Cramér–Rao: σθ = σ/sqrt(Σ s²) ≈ 0.01/sqrt(150·4²/12) ≈ 0.04°, σρ ≈ 0.01/sqrt(150) ≈ 0.8 mm
    assert np.degrees(np.median(errs[:, 0])) < 0.05
    assert np.median(errs[:, 1]) < 0.0015
    # the covariance tells the truth
    assert 1.4 < np.mean(nees) < 2.6, np.mean(nees)


def test_clutter_alone_gives_no_line() -> None:
    pts = np.random.default_rng(5).uniform(-6, 6, (400, 2))
    _, _, lines = observe_lines(pts, CFG)
    assert len(lines) <= 1  # 400 random points: at most a chance alignment, never a wall


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**16), k=st.integers(1, 6), n=st.integers(0, 300),
       arrival=st.sampled_from(["scan", "reversed", "shuffled", "ties"]))
def test_points_are_ordered_by_line_then_along_it(seed, k, n, arrival) -> None:
    """The order that splits lines into pieces sorts by line, then along the line, however the
    points arrive: in a scan's order give or take the noise, reversed, shuffled, or with ties."""
    rng = np.random.default_rng(seed)
    lab = np.repeat(rng.integers(0, k, n // 8 + 1), 8)[:n].astype(np.intp)  # runs, as in a scan
    along = np.linspace(-5.0, 5.0, n) + rng.normal(0.0, 0.02, n)
    if arrival == "reversed":
        along = along[::-1].copy()
    elif arrival == "shuffled":
        along = rng.permutation(along)
    elif arrival == "ties":
        along = np.round(along, 0)
    order = _by_line_then_along(lab, along, k)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    keys = np.column_stack((lab[order], along[order]))
    later = (np.diff(keys[:, 0]) > 0) | ((np.diff(keys[:, 0]) == 0) & (np.diff(keys[:, 1]) >= 0))
    assert later.all()


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**16), k=st.integers(1, 32), n=st.integers(1, 200),
       plateau=st.booleans())
def test_distinct_peaks_follow_their_definition(seed, k, n, plateau) -> None:
    """A peak is dropped when a stronger one shares more than half of the smaller's inliers or
    lies within half a cell of it: the definition, with every pair's shared count tabulated."""
    rng = np.random.default_rng(seed)
    inliers = rng.random((k, n)) < rng.uniform(0.05, 0.9)
    theta, rho = rng.uniform(0.0, 2 * math.pi, k), rng.uniform(0.0, 5.0, k)
    if plateau:  # one wall's spread of peaks: alike inliers, nearby cells
        inliers = inliers[:1] ^ (rng.random((k, n)) < rng.uniform(0.0, 0.5))
        theta, rho = theta[0] + rng.normal(0.0, 0.03, k), rho[0] + rng.normal(0.0, 0.05, k)
    weight = inliers.sum(axis=1).astype(float)
    shared = inliers.astype(int) @ inliers.T.astype(int)
    expected = weight > 0
    for i in range(k):
        for j in range(k):
            if weight[j] > weight[i] or (weight[j] == weight[i] and j < i):
                near = (math.cos(theta[i] - theta[j]) > math.cos(0.5 * CFG.theta_step)
                        and abs(rho[i] - rho[j]) < 0.5 * CFG.rho_step)
                if near or shared[i, j] > 0.5 * min(weight[i], weight[j]):
                    expected[i] = False
                    break
    kept = _distinct(np.ascontiguousarray(inliers), weight, theta, rho, CFG.theta_step,
                     CFG.rho_step)
    np.testing.assert_array_equal(kept, expected)

"""Global set matching (docs/method.md §6): poses found without a guess, symmetry reported,
bad input."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from houghloc import SegmentMap, observe_lines
from houghloc.geometry import TWO_PI, mod_two_pi, relative, transform_points, wrap_angle
from houghloc.global_match import GlobalMatchConfig, global_match
from houghloc.hypothesis_scores import END_GRAZE, cluster, seen_directly
from houghloc.map_lookup import angle_index, inside_map, map_box, wall_distance
from houghloc.match_result import GlobalResult
from houghloc.neighbourhood import Neighbourhood
from houghloc.pose_hypotheses import (
    observed_pairs,
    pair_hypotheses,
    vote_cells,
)
from houghloc.refine import Lines
from tests.conftest import MAPS

HOUGH = GlobalMatchConfig().hough  # extraction settings for accumulated views


# ---------------------------------------------------------------------------- simulation
def laser_scan(m: SegmentMap, pose: np.ndarray, rng: np.random.Generator, n_beams: int = 181,
               fov: float = np.pi, sigma: float = 0.01, max_range: float = 10.0) -> np.ndarray:
    """Robot-frame points of the first wall hit by each beam (all beams × walls at once)."""
    rel = np.linspace(-fov / 2, fov / 2, n_beams)
    d = np.column_stack((np.cos(rel + pose[2]), np.sin(rel + pose[2])))
    walls = np.flatnonzero(m.is_wall)
    w = m.starts[walls] - pose[:2]
    e = m.ends[walls] - m.starts[walls]
    with np.errstate(divide="ignore", invalid="ignore"):
        den = d[:, :1] * e[:, 1] - d[:, 1:] * e[:, 0]
        t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / den
        u = (w[:, 0] * d[:, 1:] - w[:, 1] * d[:, :1]) / den
    r = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf).min(axis=1)
    keep = r < max_range
    r = r[keep] + rng.normal(0.0, sigma, keep.sum())
    return np.column_stack((r * np.cos(rel[keep]), r * np.sin(rel[keep])))


def accumulated_views(m: SegmentMap, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """360° of points: four 180° scans from poses a few cm and quarter turns apart, brought into
    the frame of ``pose`` with their (exact) relative poses, as odometry would over a short turn."""
    views = []
    for k in range(4):
        view = pose + np.array([*rng.normal(0.0, 0.05, 2), k * np.pi / 2 + rng.normal(0, 0.05)])
        views.append(transform_points(relative(pose, view), laser_scan(m, view, rng)))
    return np.concatenate(views)


def free_pose(m: SegmentMap, rng: np.random.Generator) -> np.ndarray:
    """A random pose in free space: ≥ 0.4 m from walls, inside the building (most beams return)
    and not inside furniture (median range ≥ 1 m)."""
    walls = wall_distance(m, ("wall",), 0.05)
    lo, hi = m.starts.min(axis=0), m.starts.max(axis=0)
    while True:
        x, y = rng.uniform(lo, hi)
        if walls.lookup(np.array(x), np.array(y)) < 0.4:
            continue
        pose = np.array([x, y, rng.uniform(-np.pi, np.pi)])
        ranges = np.hypot(*laser_scan(m, pose, rng, 72, 2 * np.pi, 0.0, 30.0).T)
        if len(ranges) >= 70 and np.median(ranges) >= 1.0:
            return pose


def run(m: SegmentMap, points: np.ndarray, config: GlobalMatchConfig | None = None
        ) -> GlobalResult:
    _, _, lines = observe_lines(points, HOUGH)
    return global_match(lines, points, m, config or GlobalMatchConfig())


def close(pose: np.ndarray, truth: np.ndarray, xy: float = 0.10, deg: float = 2.0) -> bool:
    return bool(np.hypot(*(pose[:2] - truth[:2])) <= xy
                and abs(wrap_angle(pose[2] - truth[2])) <= np.radians(deg))


def empty_lines() -> Lines:
    x = np.linspace(0.0, 3.0, 50)
    lines = observe_lines(np.column_stack((x, np.ones_like(x))), HOUGH)[2]
    return lines.subset(np.empty(0, dtype=np.intp))


@pytest.fixture(scope="module")
def office_large() -> SegmentMap:
    return SegmentMap.from_yaml(MAPS / "office-large.yaml")


# ---------------------------------------------------------------------------- success rate
@pytest.mark.parametrize("map_name", ["office.yaml", "office-large.yaml"])
def test_best_hypothesis_is_the_true_pose(map_name: str) -> None:
    m = SegmentMap.from_yaml(MAPS / map_name)
    rng = np.random.default_rng(2024)
    trials, hits = 20, 0
    for _ in range(trials):
        truth = free_pose(m, rng)
        result = run(m, accumulated_views(m, truth, rng))
        hits += result.best is not None and close(result.best.pose, truth)
    assert hits / trials >= 0.95, f"{hits}/{trials} within 10 cm / 2°"


def test_hypothesis_carries_an_honest_covariance(office_large: SegmentMap) -> None:
    rng = np.random.default_rng(5)
    truth = np.array([21.66, 2.7, -0.58])
    best = run(office_large, accumulated_views(office_large, truth, rng)).best
    assert best is not None and close(best.pose, truth)
    assert best.cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(best.cov) > 0)
    err = best.pose - truth
    err[2] = wrap_angle(err[2])
    # the error is a plausible draw from the covariance
    assert err @ np.linalg.solve(best.cov, err) < 30.0  # χ²(3): measured NEES ≈ 2 on average
    assert best.n_lines_explained >= 2 and len(best.matches) >= 2
    assert best.matches.shape[1] == 2 and 0.0 < best.score <= 1.0


def test_hypotheses_are_distinct_and_best_first(office_large: SegmentMap) -> None:
    rng = np.random.default_rng(11)
    result = run(office_large, accumulated_views(office_large, free_pose(office_large, rng), rng))
    scores = [h.score for h in result.hypotheses]
    assert scores == sorted(scores, reverse=True)
    poses = np.array([h.pose for h in result.hypotheses])
    for i in range(len(poses)):
        for j in range(i):
            apart = (np.hypot(*(poses[i, :2] - poses[j, :2])) > 0.3
                     or abs(wrap_angle(poses[i, 2] - poses[j, 2])) > np.radians(5))
            assert apart


# ---------------------------------------------------------------------------- symmetry
def test_symmetric_field_reports_both_mirror_poses(robocup: SegmentMap) -> None:
    rng = np.random.default_rng(3)
    for truth in (np.array([1.4, -1.15, -2.88]), np.array([-2.0, 0.8, 0.6])):
        result = run(robocup, accumulated_views(robocup, truth, rng))
        mirror = np.array([-truth[0], -truth[1], wrap_angle(truth[2] + np.pi)])
        assert result.ambiguous, result.reason
        found = [h for h in result.hypotheses if close(h.pose, truth)]
        found_mirror = [h for h in result.hypotheses if close(h.pose, mirror)]
        assert found and found_mirror
        assert abs(found[0].score - found_mirror[0].score) <= GlobalMatchConfig().tie_margin
        assert "keep collecting" in result.reason


def test_neighbourhood_keeps_only_the_poses_near_it(robocup: SegmentMap) -> None:
    """A local re-search: of the two mirror poses, only the one inside the neighbourhood is
    hypothesised, so it is no longer a tie; a neighbourhood away from both finds nothing."""
    rng = np.random.default_rng(3)
    truth = np.array([1.4, -1.15, -2.88])
    points = accumulated_views(robocup, truth, rng)
    _, _, lines = observe_lines(points, HOUGH)
    guess = truth + np.array([0.4, -0.3, np.radians(12.0)])
    near = Neighbourhood(guess, 1.0, np.radians(20.0))
    result = global_match(lines, points, robocup, GlobalMatchConfig(), near=near)
    assert result.best is not None and close(result.best.pose, truth)
    assert not result.ambiguous
    assert all(np.hypot(*(h.pose[:2] - guess[:2])) < 1.3 for h in result.hypotheses)
    away = Neighbourhood(np.array([0.0, 2.5, 0.0]), 0.3, np.radians(5.0))
    assert global_match(lines, points, robocup, GlobalMatchConfig(), near=away).best is None


def pairs_in_view(m: SegmentMap, seed: int):
    """A pose, the lines of the views accumulated there, their pairs, the map's angle index and
    the settings: the inputs of :func:`pair_hypotheses`."""
    rng = np.random.default_rng(seed)
    truth = free_pose(m, rng)
    _, _, lines = observe_lines(accumulated_views(m, truth, rng), HOUGH)
    config = GlobalMatchConfig()
    pair_i, pair_k = observed_pairs(lines, config)
    index = angle_index(m, ("wall",), config.min_pair_angle, config.angle_tol_max + 1e-9)
    return truth, lines, pair_i, pair_k, index, config


@pytest.mark.parametrize("seed", range(4))
def test_neighbourhood_cut_keeps_exactly_the_poses_inside_it(office_large: SegmentMap,
                                                              seed: int) -> None:
    """The heading and position cuts made before poses are solved are only shortcuts: the poses
    are those of the whole map's hypotheses that lie in the neighbourhood, in the same order."""
    truth, lines, pair_i, pair_k, index, config = pairs_in_view(office_large, seed)
    everywhere = pair_hypotheses(lines, pair_i, pair_k, index, config)
    # neighbourhoods whose heading edge, or whose rim, passes through the hypotheses near the
    # truth
    for turn, radius in zip(np.radians([8.0, 19.0, 19.8, 20.0, 20.2, -19.9, 0.0, 3.0, -5.0]),
                            [1.0] * 6 + [0.05, 0.33, 3.0], strict=True):
        near = Neighbourhood(truth + np.array([0.3, -0.2, turn]), radius, np.radians(20.0))
        inside = everywhere[near.contains(everywhere)]
        cut = pair_hypotheses(lines, pair_i, pair_k, index, config, near)
        assert len(inside) < len(everywhere)
        np.testing.assert_array_equal(cut, inside)


# ---------------------------------------------------------------------------- not enough
def test_one_wall_gives_no_hypothesis_and_says_why(office: SegmentMap) -> None:
    rng = np.random.default_rng(0)
    x = np.linspace(-3.0, 3.0, 300)
    points = np.column_stack((x, np.full_like(x, 2.0) + rng.normal(0, 0.01, x.size)))
    result = run(office, points)
    assert result.hypotheses == [] and not result.ambiguous
    assert "non-parallel" in result.reason


def test_corridor_of_parallel_walls_gives_no_hypothesis(office: SegmentMap) -> None:
    x = np.linspace(-4.0, 4.0, 200)
    points = np.concatenate((np.column_stack((x, np.full_like(x, 1.0))),
                             np.column_stack((x, np.full_like(x, -1.0)))))
    result = run(office, points)
    assert result.hypotheses == [] and "non-parallel" in result.reason


@pytest.mark.parametrize("points", [np.empty((0, 2)), [], np.full((5, 2), np.nan)])
def test_no_points_is_an_empty_result(office: SegmentMap, points) -> None:
    result = global_match(empty_lines(), points, office)
    assert result.hypotheses == [] and result.reason == "no points"


def test_no_lines_or_bad_points_is_an_empty_result(office: SegmentMap) -> None:
    pts = np.random.default_rng(0).uniform(-5, 5, (100, 2))
    assert global_match(empty_lines(), pts, office).reason == "no observed lines"
    assert global_match(None, pts, office).reason == "no observed lines"
    assert "N×2" in global_match(empty_lines(), np.zeros((4, 3)), office).reason
    assert "kinds" in global_match(empty_lines(), pts, office, kinds=("line",)).reason
    assert "N×2" in global_match(empty_lines(), "not points", office).reason


def test_non_finite_points_are_dropped_with_their_line_rows(office_large: SegmentMap) -> None:
    rng = np.random.default_rng(5)
    truth = np.array([21.66, 2.7, -0.58])
    points = accumulated_views(office_large, truth, rng)
    _, _, lines = observe_lines(points, HOUGH)
    points[::50] = np.nan  # e.g. no-return beams that slipped through
    best = global_match(lines, points, office_large).best
    assert best is not None and close(best.pose, truth)
    assert "extracted from" in global_match(lines, points[:-1], office_large).reason


def test_points_off_the_map_give_no_hypothesis(office: SegmentMap) -> None:
    # a small square room (2 m) that fits nowhere in the office with its walls on real segments
    rng = np.random.default_rng(1)
    s = np.linspace(-1.0, 1.0, 80)
    room = np.concatenate([np.column_stack((s, np.full_like(s, c))) for c in (-1.0, 1.0)]
                          + [np.column_stack((np.full_like(s, c), s)) for c in (-1.0, 1.0)])
    room += rng.normal(0, 0.01, room.shape)
    cfg = GlobalMatchConfig(min_line_coverage=0.95, min_lines_explained=4)
    result = run(office, room, cfg)
    assert result.hypotheses == [] and result.reason


# ---------------------------------------------------------------------------- parts
def test_angle_index_is_sorted_and_cached(office_large: SegmentMap) -> None:
    cfg = GlobalMatchConfig()
    index = angle_index(office_large, ("wall",), cfg.min_pair_angle, cfg.angle_tol_max)
    assert np.all(np.diff(index.delta) >= 0)
    assert index is angle_index(office_large, ("wall",), cfg.min_pair_angle, cfg.angle_tol_max)
    # N⁻¹ really inverts [[cos β_a, sin β_a], [cos β_b, sin β_b]]
    n = np.stack((np.column_stack((np.cos(index.beta_a), np.sin(index.beta_a))),
                  np.column_stack((np.cos(index.beta_b), np.sin(index.beta_b)))), axis=1)
    assert np.allclose(index.n_inv @ n, np.eye(2), atol=1e-9)
    assert np.all(np.abs(np.sin(index.beta_b - index.beta_a)) >= np.sin(cfg.min_pair_angle) - 1e-12)


def test_wall_distance_grid(office: SegmentMap) -> None:
    walls = wall_distance(office, ("wall",), 0.05)
    # on the south wall, 1 m north of it, and off the map
    d = walls.lookup(np.array([10.0, 10.0, -50.0]), np.array([0.0, 1.0, 0.0]))
    assert d[0] <= 0.05 and abs(d[1] - 1.0) <= 0.06 and np.isinf(d[2])


def test_points_seen_through_a_wall_are_flagged(office: SegmentMap) -> None:
    pose = np.array([2.0, 6.0, 0.0])  # in the corridor (y = 5 .. 7)
    points = np.array([[0.0, 1.0],  # on the corridor's north wall: visible
                       [0.0, 3.0]])  # 2 m beyond it: seen through the wall
    assert seen_directly(pose, points, office, ("wall",), 10.0, 0.25).tolist() == [True, False]


def test_config_is_validated() -> None:
    with pytest.raises(ValidationError):
        GlobalMatchConfig(min_pair_angle_deg=0.0)
    with pytest.raises(ValidationError):
        GlobalMatchConfig(unknown=1)


# ---------------------------------------------------------------------------- in stages
def corridor_view(office: SegmentMap, true: np.ndarray) -> np.ndarray:
    """Robot-frame points of the corridor's two walls only (heading 0), door gaps included:
    a view that only the slide places."""
    along = np.arange(-4.0, 4.0, 0.03)
    world = np.concatenate([np.column_stack((true[0] + along, np.full_like(along, y)))
                            for y in (5.0, 7.0)])
    a, e = office.starts, office.ends - office.starts
    u = np.clip(((world[:, None] - a) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
    gap = np.hypot(*(a + u[..., None] * e - world[:, None]).transpose(2, 0, 1)).min(axis=1)
    return world[gap < 1e-6] - true[:2]


@pytest.mark.parametrize("view", ["rooms", "corridor"])
@pytest.mark.parametrize("budget", [1, 300_000])
def test_a_match_in_stages_finds_what_a_whole_one_does(office: SegmentMap, view: str,
                                                       budget: int) -> None:
    """The budget decides when the result comes, never what it is: the same hypotheses as
    the whole match, bit for bit, over more calls the smaller it is; every call but the last
    reports at least the budget's work, and the calls' reported work adds up to the same."""
    from houghloc.global_match import advance, global_match_stages

    rng = np.random.default_rng(5)
    if view == "corridor":  # pairs, then the slide's stages
        points = corridor_view(office, np.array([5.5, 6.2, 0.0]))
    else:
        points = accumulated_views(office, free_pose(office, rng), rng)
    _, _, lines = observe_lines(points, HOUGH)
    whole = global_match(lines, points, office)
    assert whole.hypotheses, whole.reason
    every: list[int] = []  # the cost of each stage, from a run of them all
    tapped = _tap(global_match_stages(lines, points, office), every)
    assert [h.pose.tolist() for h in tapped.hypotheses] == [h.pose.tolist()
                                                            for h in whole.hypotheses]
    stages = global_match_stages(lines, points, office)
    calls, work = 0, 0
    while True:
        calls += 1
        counter: list[int] = []
        result = advance(_counted(stages, counter), budget)
        work += sum(counter)
        if result is not None:
            break
        assert sum(counter) >= budget
    assert [h.pose.tolist() for h in result.hypotheses] == [h.pose.tolist()
                                                            for h in whole.hypotheses]
    assert [h.score for h in result.hypotheses] == [h.score for h in whole.hypotheses]
    assert result.reason == whole.reason and result.ambiguous == whole.ambiguous
    assert work == sum(every) and min(every) > 0
    if budget == 1:  # a stage per call, and one that ends the match
        assert calls == len(every) + 1 >= 4
    if view == "corridor":
        assert any(h.slid for h in result.hypotheses)


def _counted(stages, counter: list):
    """The stages, each yielded cost also appended to ``counter``; the result passed on."""
    while True:
        try:
            cost = next(stages)
        except StopIteration as done:
            return done.value
        counter.append(cost)
        yield cost


def _tap(stages, counter: list) -> GlobalResult:
    """Run every stage, appending each one's cost to ``counter``; the result."""
    wrapped = _counted(stages, counter)
    while True:
        try:
            next(wrapped)
        except StopIteration as done:
            return done.value


def test_segment_spans_cover_what_the_segments_cover(office: SegmentMap) -> None:
    """The fraction of an interval along an oriented map line that its segments cover, against
    a fine sampling of the interval (both orientations of every line)."""
    from houghloc.map_lookup import SegmentSpans, map_lines_of_kinds

    mlines = map_lines_of_kinds(office, ("wall",))
    spans = SegmentSpans(office, mlines, ("wall",), 0.0)
    rng = np.random.default_rng(0)
    rows = rng.integers(0, 2 * len(mlines), 300)
    s0 = rng.uniform(-25.0, 25.0, 300)
    s1 = s0 + rng.uniform(0.5, 8.0, 300)
    got = spans.coverage(rows, s0, s1)
    for row, a, b, g in zip(rows, s0, s1, got, strict=True):
        line = mlines[row % len(mlines)]
        segs = np.flatnonzero((office.line_of_segment == line) & office.is_wall)
        lo, hi = office.seg_s0[segs], office.seg_s1[segs]
        if row >= len(mlines):  # turned by π: along-coordinates reversed
            lo, hi = -hi, -lo
        s = np.linspace(a, b, 4001)
        inside = ((s[:, None] >= lo) & (s[:, None] <= hi)).any(axis=1).mean()
        assert g == pytest.approx(inside, abs=2e-3)


@settings(max_examples=3000, deadline=None)
@given(st.one_of(st.floats(-30.0, 30.0), st.floats(allow_nan=True, allow_infinity=True)))
@example(0.0)
@example(-0.0)
@example(TWO_PI)
@example(-TWO_PI)
@example(2 * TWO_PI)
@example(math.nextafter(TWO_PI, 0.0))
@example(math.nextafter(2 * TWO_PI, 0.0))
@example(math.nextafter(-TWO_PI, 0.0))
@example(-1e-300)
@example(5e-324)
def test_the_candidate_loops_modulo_is_pythons_bit_for_bit(u: float) -> None:
    """The local search's candidate loop wraps angles without ``fmod`` where it can; the result
    must be the floor modulo's to the last bit (and sign of zero), or hypotheses would move."""
    mine, python = mod_two_pi(u), u % TWO_PI
    assert struct.pack("<d", mine) == struct.pack("<d", python) or (
        math.isnan(mine) and math.isnan(python)), (u, mine, python)


# ---------------------------------------------------------------------------- compiled steps
@pytest.mark.parametrize("seed", range(3))
def test_the_box_cut_keeps_exactly_the_poses_inside_the_map(office_large: SegmentMap,
                                                            seed: int) -> None:
    """Cutting to the map's box while the poses are solved keeps what cutting after would."""
    _, lines, pair_i, pair_k, index, config = pairs_in_view(office_large, seed)
    everywhere = pair_hypotheses(lines, pair_i, pair_k, index, config)
    inside = everywhere[inside_map(everywhere, office_large, ("wall",), 0.5)]
    assert 0 < len(inside) < len(everywhere)
    cut = pair_hypotheses(lines, pair_i, pair_k, index, config,
                          box=map_box(office_large, ("wall",), 0.5))
    np.testing.assert_array_equal(cut, inside)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 400), st.sampled_from([0.05, 0.25, 3.0]),
       st.sampled_from([1e-3, 0.5, 20.0]))
def test_votes_count_each_cell_once_and_rank_ties_by_cell(seed: int, n: int, cell: float,
                                                          spread: float) -> None:
    """Every pose is counted in its (x, y, θ) cell; the most-voted cells come first, each
    once, with its members' mean pose (θ a circular mean)."""
    rng = np.random.default_rng(seed)
    # few distinct poses, repeated, so that cells hold several and votes tie
    distinct = np.column_stack((rng.uniform(-spread, spread, (n, 2)), rng.uniform(-7, 7, n)))
    poses = distinct[rng.integers(0, n, n)]
    config = GlobalMatchConfig(vote_cell_xy=cell, max_cells_cheap=max(1, n // 3))
    cells, votes = vote_cells(poses, config)
    bins = np.column_stack((np.floor(poses[:, :2] / cell),
                            np.floor(np.mod(poses[:, 2], TWO_PI) / config.vote_cell_theta)))
    _, inverse, counts = np.unique(bins, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    np.testing.assert_array_equal(votes, np.sort(counts)[::-1][: config.max_cells_cheap])
    # each occupied cell's mean pose, θ a circular mean (sums per cell, all cells at once)
    def per_cell(values: np.ndarray) -> np.ndarray:
        return np.bincount(inverse, weights=values, minlength=len(counts))

    means = np.column_stack((per_cell(poses[:, 0]) / counts, per_cell(poses[:, 1]) / counts,
                             np.arctan2(per_cell(np.sin(poses[:, 2])),
                                        per_cell(np.cos(poses[:, 2])))))
    found: set[int] = set()
    for cell_pose, vote in zip(cells, votes, strict=True):
        same = np.flatnonzero((counts == vote)
                              & np.isclose(means[:, :2], cell_pose[:2], atol=1e-9).all(axis=1)
                              & (np.abs(wrap_angle(means[:, 2] - cell_pose[2])) < 1e-9))
        assert len(same) and not found & set(same.tolist()), (cell_pose, vote)
        found.add(int(same[0]))


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.3, 0.5, 0.6, 0.75, 1.0]),
       st.integers(2, 7))
def test_a_row_on_walls_is_decided_as_its_full_count_would(office: SegmentMap, seed: int,
                                                           coverage: float, samples: int
                                                           ) -> None:
    """The look-ups a row skips once its answer is known never change the answer."""
    walls = wall_distance(office, ("wall",), 0.05)
    rng = np.random.default_rng(seed)
    poses = np.column_stack((rng.uniform(0, 20, 50), rng.uniform(0, 15, 50),
                             rng.uniform(-np.pi, np.pi, 50)))
    x, y = rng.uniform(-6, 6, (2, 5, samples))
    on = walls.at(poses, x, y) <= 0.12
    expected = on.mean(axis=2) >= coverage
    np.testing.assert_array_equal(walls.rows_on_walls(poses, x, y, 0.12, coverage), expected)


@settings(max_examples=300, deadline=None)
@given(st.floats(-50, 50), st.floats(-50, 50), st.floats(-20, 20), st.floats(0, 5),
       st.floats(0, 4))
def test_neighbourhood_contains_what_its_radii_say(x: float, y: float, theta: float,
                                                   radius_xy: float, radius_theta: float
                                                   ) -> None:
    near = Neighbourhood(np.array([1.0, -2.0, 0.5]), radius_xy, radius_theta)
    pose = np.array([[x, y, theta]])
    inside = (math.hypot(x - 1.0, y + 2.0) <= radius_xy
              and abs(float(wrap_angle(theta - 0.5))) <= radius_theta)
    margin = 1e-9  # the boundary itself is rounding's to decide
    if abs(math.hypot(x - 1.0, y + 2.0) - radius_xy) > margin and abs(
            abs(float(wrap_angle(theta - 0.5))) - radius_theta) > margin:
        assert bool(near.contains(pose)[0]) == inside


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 120), st.sampled_from([0.05, 0.5, 3.0]),
       st.sampled_from([0.5, 5.0, 60.0]))
def test_clusters_are_the_greedy_suppressions_of_the_best_poses(seed: int, n: int, spread: float,
                                                                 radius_deg: float) -> None:
    """Each kept pose is the best still free, and it frees no pose outside its radii."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack((rng.uniform(-spread, spread, (n, 2)), rng.uniform(-7, 7, n)))
    scores = rng.integers(0, 4, n).astype(float)  # ties: the earlier pose ranks first
    config = GlobalMatchConfig(cluster_xy=0.3, cluster_theta_deg=radius_deg)
    free, expected = np.ones(n, bool), []
    for j in np.argsort(-scores, kind="stable"):
        if free[j]:
            expected.append(int(j))
            free &= ~((np.hypot(*(poses[:, :2] - poses[j, :2]).T) <= config.cluster_xy)
                      & (np.abs(wrap_angle(poses[:, 2] - poses[j, 2])) <= config.cluster_theta))
    assert cluster(poses, scores, config) == expected


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-3, 23), st.floats(-3, 18), st.floats(-4, 4))
def test_points_seen_through_walls_by_bearing_are_those_seen_by_every_wall(
        office_large: SegmentMap, seed: int, x: float, y: float, theta: float) -> None:
    """Trying only the walls a point's bearing crosses gives what trying every wall does,
    from anywhere (beside a wall, on one, off the map)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-15, 15, (200, 2))
    points[:5] = 0.0  # at the robot
    near = np.flatnonzero(office_large.is_wall)
    starts, ends = office_large.starts[near], office_large.ends[near]
    c, s = math.cos(theta), math.sin(theta)
    expected = np.ones(len(points), bool)
    for i, (px, py) in enumerate(points):
        dx, dy = x + c * px - s * py - x, y + s * px + c * py - y
        t_max = 1.0 - 0.25 / max(math.hypot(dx, dy), 1e-9)
        for (p0x, p0y), (p1x, p1y) in zip(starts, ends, strict=True):
            wx, wy, ex, ey = p0x - x, p0y - y, p1x - p0x, p1y - p0y
            den = dx * ey - dy * ex
            if abs(den) <= 1e-12:
                continue
            t, u = (wx * ey - wy * ex) / den, (wx * dy - wy * dx) / den
            graze = END_GRAZE / max(math.hypot(ex, ey), END_GRAZE)
            if 1e-6 < t < t_max and graze < u < 1.0 - graze:
                expected[i] = False
                break
    pose = np.array([x, y, theta])
    np.testing.assert_array_equal(
        seen_directly(pose, points, office_large, ("wall",), 100.0, 0.25), expected)

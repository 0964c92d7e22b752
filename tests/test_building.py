"""The generated buildings (fusion.sim.building): a valid floor plan and tour for every seed,
the robot's faults as drawn, glass the laser sees through, and a sweep over seeds."""

from __future__ import annotations

import csv
import itertools
import json
import math

import numpy as np
import pytest

from fusion.bench.generated import outside_allowance, recovery_times
from fusion.bench.spec import SpecError, load_spec
from fusion.bench.sweep import run_sweep
from fusion.integrity import LOCALIZED_HEADING_DEG, LOCALIZED_POSITION
from fusion.sim import scenario_preset, simulate
from fusion.sim.building import (
    MIN_DOOR,
    ROUTE_CLEARANCE,
    WHEEL_SCALE_ERROR,
    building_scenario,
    draw_plan,
)
from fusion.sim.raycast import segment_segment_distance
from fusion.sim.world import wall_segments
from houghloc.geometry import wrap_angle
from houghloc.segment_map import SegmentMap


@pytest.fixture(autouse=True)
def _maps_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("HOUGHLOC_BUILDINGS", str(tmp_path / "buildings"))


@pytest.mark.parametrize("seed", range(12))
def test_every_leg_of_the_tour_keeps_its_clearance(seed):
    plan = draw_plan(np.random.default_rng(seed))
    m = plan.segment_map("b")
    ws, we = wall_segments(m)
    tour = np.asarray(plan.tour)
    legs = np.column_stack((tour, np.roll(tour, -1, axis=0)))  # the tour is a loop
    d = segment_segment_distance(legs[:, :2], legs[:, 2:], ws, we)
    assert d.min() >= ROUTE_CLEARANCE - 1e-9, (seed, d.min())
    assert set(plan.glass) <= set(m.ids)


def test_a_seed_draws_one_building_and_another_seed_another(tmp_path):
    a, b = building_scenario(3), building_scenario(3)
    assert a == b
    c = building_scenario(4)
    ma, mc = SegmentMap.from_yaml(a.map), SegmentMap.from_yaml(c.map)
    assert len(ma) != len(mc) or not np.allclose(ma.starts, mc.starts)
    assert scenario_preset("building", seed=3) == a


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_the_faults_are_drawn_within_their_bounds(seed):
    cfg = building_scenario(seed)
    odo = cfg.odometry
    assert abs(odo.left_scale_error) <= WHEEL_SCALE_ERROR
    assert abs(odo.right_scale_error) <= WHEEL_SCALE_ERROR
    assert 0.0 <= odo.turn_slip <= 0.05
    assert len(cfg.odometry_gaps) == 1 and 1.0 <= cfg.odometry_gaps[0].duration <= 4.0
    assert len(cfg.kidnaps) == 1
    k = cfg.kidnaps[0]
    assert 2.0 <= math.hypot(k.dx, k.dy) <= 4.0 and 20.0 <= abs(k.dtheta_deg) <= 45.0


def test_a_run_has_its_gap_its_kidnap_and_glass_the_laser_sees_through():
    seed = next(s for s in range(40) if building_scenario(s).transparent)
    cfg = building_scenario(seed)
    run = simulate(cfg)
    # no odometry record inside the gap, and the records around it carry the motion
    gap = cfg.odometry_gaps[0]
    events = [e for e in run.events() if type(e).__name__ == "Odometry"]
    t = np.array([e.t for e in events])
    inside = (t >= gap.t) & (t < gap.t + gap.duration)
    assert not inside.any()
    assert np.diff(t).max() == pytest.approx(gap.duration, abs=2.0 / cfg.odom_rate)
    # the kidnap moved the true pose between two records
    k = int(np.flatnonzero(run.kidnapped)[0])
    jump = run.odom_truth[k + 1] - run.odom_truth[k]
    assert math.hypot(jump[0], jump[1]) > 1.9
    # no beam ever ends on a glass wall
    glass = np.flatnonzero(np.isin(run.map.ids, cfg.transparent))
    assert not np.isin(run.scan_labels, glass).any()
    # the wheels: each record's increment is the truth's, scaled within the drawn errors
    assert np.all(np.isfinite(run.odom_pose))


def test_turn_slip_makes_the_wheels_over_report_turns():
    from fusion.sim.config import OdometryConfig
    from fusion.sim.odometry import measured_motion

    motion = np.array([[0.0, 0.01]] * 100 + [[0.01, 0.0]] * 100)  # a spin, then straight
    clean = OdometryConfig(left_scale_error=0.0, right_scale_error=0.0, wheel_noise=0.0)
    slip = clean.model_copy(update={"turn_slip": 0.04})
    a = measured_motion(motion, clean, np.random.default_rng(0))
    b = measured_motion(motion, slip, np.random.default_rng(0))
    assert b[:100, 1].sum() == pytest.approx(1.04 * a[:100, 1].sum())
    assert np.array_equal(a[100:], b[100:])  # driving straight, no slip


def test_the_doors_are_wide_enough_for_the_robot():
    for seed in range(8):
        plan = draw_plan(np.random.default_rng(seed))
        # every gap in the corridor's side walls is a door at least MIN_DOOR wide
        for prefix, y in (("scor", 0.0), ("ncor", None)):
            xs = sorted((min(a[0], b[0]), max(a[0], b[0])) for i, a, b in plan.walls
                        if i.startswith(prefix))
            gaps = [x1 - x0 for (_, x0), (x1, _) in itertools.pairwise(xs)]
            assert all(g >= MIN_DOOR - 1e-9 for g in gaps), (seed, prefix, gaps, y)


def test_recovery_is_right_and_staying_right():
    t = np.arange(0.0, 30.0, 0.1)
    lost = (t >= 10.0) & (t < 13.0)
    lost |= (t >= 14.0) & (t < 14.5)  # right at 13 s, but not for 5 s
    assert recovery_times(t, lost, [10.0]) == [pytest.approx(4.5)]
    # right for the last 2.9 s only: to the end of the run counts as staying right
    assert recovery_times(t, (t >= 10.0) & (t < 27.05), [10.0]) == [pytest.approx(17.1)]
    assert recovery_times(t, np.zeros_like(t, dtype=bool), [10.0]) == [0.0]
    assert recovery_times(t, np.ones_like(t, dtype=bool), [10.0]) == [math.inf]
    keep = outside_allowance(t, [10.0])
    assert keep.sum() == len(t) - 50


def test_a_spec_of_generated_runs_names_each_seed(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_text("generated:\n  - {scenario: building, seeds: [3, 5], duration: 30}\n")
    spec = load_spec(path)
    assert [r.name for r in spec.runs] == ["building-3", "building-4", "building-5"]
    assert all(r.duration == 30 for r in spec.runs)
    path.write_text("generated:\n  - {scenario: building, seeds: [5, 3]}\n")
    with pytest.raises(SpecError, match="first <= last"):
        load_spec(path)
    path.write_text("runs:\n  - {name: x, scenario: building, log: a.log}\n")
    with pytest.raises(SpecError, match="brings its own log"):
        load_spec(path)


def test_a_sweep_of_generated_buildings_scores_integrity_and_recovery(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_text("generated:\n  - {scenario: building, seeds: [0, 1], duration: 60}\n"
                    "methods: [houghloc, odometry]\n")
    outcome = run_sweep(load_spec(path), tmp_path / "out", workers=2, progress=False)
    assert outcome.failed == 0 and outcome.ran == 4
    rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))
    for r in rows:
        assert r["status"] == "ok", r
        assert int(r["scans"]) == 601
        assert float(r["lost_outside_kidnap_frac"]) >= 0.0
    mine = [r for r in rows if r["method"] == "houghloc"]
    for r in mine:
        assert 0.0 <= float(r["brier"]) <= 1.0
        assert float(r["confident_wrong_frac"]) <= float(r["lost_frac"])
        bins = json.loads(r["reliability"])  # poses, right, Σ probability per bin
        assert sum(n for n, _, _ in bins) == int(r["scans"])
        assert all(0 <= right <= n and 0.0 <= total <= n for n, right, total in bins)
    # dead reckoning does not report how sure it is
    assert all(r["brier"] == "" for r in rows if r["method"] == "odometry")
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "## Integrity" in summary and "## Generated runs: goals" in summary
    assert "## Reliability of the reported probability" in summary


@pytest.mark.parametrize("seed", range(6))
def test_a_generated_run_simulates(seed):
    run = simulate(building_scenario(seed))  # the path is checked against the walls there
    assert len(run.scan_t) == 2401


@pytest.mark.slow
def test_every_benchmark_seed_simulates():
    """The 100 benchmark seeds and CI's 50: a building, a tour and a kidnap whose way back is
    clear (simulate checks the path), and a kidnap on all but a few."""
    seeds = [*range(100), *range(1000, 1050)]
    kidnapped = 0
    for seed in seeds:
        cfg = building_scenario(seed)
        kidnapped += bool(cfg.kidnaps)
        simulate(cfg)
    assert kidnapped >= 0.95 * len(seeds)


def test_a_kidnap_along_a_corridor_is_not_tracked_at_a_look_alike_door():
    """Seed 18: carried 3.7 m along the main corridor and turned 24°. The local re-search puts
    the heading right but cannot see the position along the corridor; its pose is contested by
    a global match, so the robot is found within 10 s (it tracked the guess's position along
    the corridor for 47 s when the re-search's pose was taken as it was), and is not reported
    localized where it is lost meanwhile."""
    from fusion.bench.generated import recovery_times
    from fusion.integrity import integrity_scores

    kidnap, t, off, turned, probability = _until_after_the_kidnap(18, 15.0)
    lost = _lost(off, turned)
    assert recovery_times(t, lost, [kidnap.t])[0] <= 10.0
    after = t >= kidnap.t
    scores = integrity_scores(probability[after], ~lost[after])
    assert scores["confident_wrong"] <= 0.02


def _until_after_the_kidnap(seed: int, seconds: float):
    """A generated building localized with the defaults until ``seconds`` after its kidnap:
    the kidnap, the scans' times, their position (m) and heading (°) errors, and the
    probabilities reported."""
    from fusion.config import LocalizerConfig
    from fusion.run_log import run_log
    from fusion.sim.poses import interpolate_poses

    cfg = building_scenario(seed)
    kidnap = cfg.kidnaps[0]
    run = simulate(cfg)
    events = (e for e in run.events() if e.t <= kidnap.t + seconds)
    done = run_log(events, run.map, LocalizerConfig(), initial_pose=run.scan_truth[0])
    t = done.result.t
    off, turned = _errors(done.result.poses, interpolate_poses(t, run.odom_t, run.odom_truth))
    return kidnap, t, off, turned, done.result.localized_probability


def _errors(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's position (m) and heading (°) error against the truth."""
    off = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    return off, np.degrees(np.abs(wrap_angle(poses[:, 2] - truth[:, 2])))


def _lost(off: np.ndarray, turned: np.ndarray) -> np.ndarray:
    """Beyond the benchmark's bound: more than 0.3 m or 5° off."""
    return (off > LOCALIZED_POSITION) | (turned > LOCALIZED_HEADING_DEG)


def test_a_kidnap_by_one_door_is_contested_though_the_doors_are_in_view():
    """Seed 44: carried 3.73 m along the main corridor, one door spacing, and turned 21.5°. The
    local re-search sees the doors, so it observes the position along the corridor: at the
    look-alike door the guess was at. No odometry noise explains the 21.5° it finds, so its
    pose is contested by a global match of that view, which has the right door among its
    rivals. Taken as it was, the look-alike door was tracked, reported localized, for 97 s
    (40 % of the run confidently wrong); now the robot is found within 2 s (measured 1.1 s)
    and no pose is reported localized while wrong."""
    from fusion.bench.generated import recovery_times
    from fusion.integrity import is_localized

    kidnap, t, off, turned, probability = _until_after_the_kidnap(44, 20.0)
    lost = _lost(off, turned)
    assert recovery_times(t, lost, [kidnap.t])[0] <= 2.0
    after = t >= kidnap.t
    assert not (lost[after] & is_localized(probability[after])).any()
    assert not lost[t >= kidnap.t + 2.0].any()


@pytest.mark.slow
def test_the_poses_the_bank_takes_are_as_often_wrong_as_its_weights_say(monkeypatch):
    """Over the 50 development seeds, every pose the hypothesis bank takes is compared with the
    truth. A pose taken at weight w is wrong with probability 1 − w, so the wrong ones number
    about E = Σ(1 − w), a sum of independent rare events: at most E + 3√E of them. When scans
    every 0.1 m each weighed as a new view and a re-proposed pose gained weight with every
    match, 5 of 65 poses taken were wrong where the weights promised 1.2."""
    from fusion.config import LocalizerConfig
    from fusion.hypotheses import HypothesisBank
    from fusion.run_log import run_log
    from fusion.sim.poses import interpolate_poses

    taken: list[tuple[float, float, np.ndarray]] = []
    step = HypothesisBank.step

    def recorded_step(bank, t, *args):
        verdict = step(bank, t, *args)
        if verdict.pose is not None:
            taken.append((t, bank.leader.weight, verdict.pose))
        return verdict

    monkeypatch.setattr(HypothesisBank, "step", recorded_step)
    promised, wrong, count = 0.0, 0, 0
    for seed in range(50):
        run = simulate(building_scenario(seed))
        taken.clear()
        run_log(run.events(), run.map, LocalizerConfig(), initial_pose=run.scan_truth[0])
        if taken:
            t, weights, poses = (np.array(column) for column in zip(*taken, strict=True))
            wrong += int(_lost(*_errors(poses, interpolate_poses(t, run.odom_t,
                                                                 run.odom_truth))).sum())
            promised += float(np.sum(1.0 - weights))
            count += len(taken)
    assert count >= 40  # a kidnap in every seed: most are relocalized through the bank
    assert wrong <= promised + 3.0 * math.sqrt(promised), (wrong, promised, count)


@pytest.mark.slow
def test_held_out_buildings(tmp_path):
    """Seeds 1000–1049, never tuned on, run here only: the defaults' figures may not fall back
    below what they were when these guards were set (measured: median ATE 1.9 cm and lost
    0.0 % outside the kidnaps' 5 s, confident-wrong 0.0 % (median; mean 0.006 %, 0.036 %
    before a scan's probability held its own evidence; 49 of 50 seeds at most 0.1 %),
    41 of 50 kidnaps recovered within 5 s, 33 before the glass tracking saw was known to the
    poses followed after a kidnap; docs/benchmark.md#generated-buildings). The goals are
    further: 0.1 % on every seed, 95 % of the kidnaps. (Their cost, 7 ms a scan at worst, is
    the benchmark's to print.)"""
    import statistics

    from tests.conftest import REPO

    spec = load_spec(REPO / "benchmarks" / "buildings-ci.yaml")
    spec = spec.model_copy(update={"methods": [m for m in spec.methods if m == "houghloc"]})
    outcome = run_sweep(spec, tmp_path / "out", workers=2, progress=False)
    assert outcome.failed == 0 and outcome.ran == 50
    rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))

    def column(name):
        return [float(r[name]) for r in rows if r[name] != ""]

    assert statistics.median(column("ate_outside_kidnap_m")) <= 0.05  # 1.9 cm measured
    assert statistics.median(column("lost_outside_kidnap_frac")) <= 0.01  # 0.0 %
    assert statistics.median(column("confident_wrong_frac")) <= 0.002  # 0.0 %
    assert statistics.mean(column("confident_wrong_frac")) <= 0.0002  # 0.006 %
    assert sum(v <= 0.001 for v in column("confident_wrong_frac")) >= 46  # 49
    assert sum(v <= 5.0 for v in column("recovery_s")) >= 37  # 41


def test_through_an_odometry_gap_the_pose_moves_on_or_says_it_is_lost():
    """Seed 80 loses its odometry records for 2.4 s at 54.9 s while it drives at 0.5 m/s. The
    scans keep coming: the filter carries the pose past the wheels' newest reading at their
    last velocity, widened by what the base's acceleration could change. Holding the pose
    still there (the wheels' silence read as standing still) left it behind by the whole
    1.2 m, reported localized."""
    from fusion.config import LocalizerConfig
    from fusion.integrity import is_localized
    from fusion.run_log import run_log
    from fusion.sim.poses import interpolate_poses

    cfg = building_scenario(80)
    gap = cfg.odometry_gaps[0]
    assert 54.0 < gap.t < 56.0 and gap.duration > 2.0
    run = simulate(cfg)
    events = (e for e in run.events() if e.t <= gap.t + gap.duration + 2.0)
    done = run_log(events, run.map, LocalizerConfig(), initial_pose=run.scan_truth[0])
    t, poses = done.result.t, done.result.poses
    truth = interpolate_poses(t, run.odom_t, run.odom_truth)
    inside = np.flatnonzero((t >= gap.t) & (t < gap.t + gap.duration))
    moved = np.hypot(*(poses[inside[-1], :2] - poses[inside[0], :2]))
    truly = np.hypot(*(truth[inside[-1], :2] - truth[inside[0], :2]))
    assert truly > 1.0 and abs(moved - truly) < 0.2
    off, _ = _errors(poses, truth)
    localized = is_localized(done.result.localized_probability)
    assert not (localized[inside] & (off[inside] > LOCALIZED_POSITION)).any()


def test_lost_poses_are_placed_where_they_were_lost():
    """Seed 0: corridor x 0–19.4 m (y 0–1.9 m), rooms beyond it, the hall east of it, the gap
    at 40.9 s for 3.6 s, the kidnap at 122.2 s. A pose is placed by the run's events first, by
    where the robot truly is then; lost poses after a kidnap count as such until the robot is
    right for good."""
    from fusion.bench.where import main, places

    t = np.array([10.0, 11.0, 12.0, 13.0, 42.0, 45.0, 123.0, 130.0, 140.0, 150.0])
    truth = np.array([[-5.0, 1.0, 0.0], [8.0, 1.0, 0.0], [8.0, 3.5, 0.0], [22.0, 0.0, 0.0],
                      [8.0, 1.0, 0.0], [8.0, 1.0, 0.0], [8.0, 1.0, 0.0], [8.0, 1.0, 0.0],
                      [8.0, 1.0, 0.0], [8.0, 1.0, 0.0]])
    lost = np.array([True] * 8 + [False, False])
    where = places(0, t, truth, lost)
    assert list(where) == ["featureless corridor", "main corridor", "rooms", "hall",
                           "odometry gap", "odometry gap", "kidnap allowance", "after a kidnap",
                           "main corridor", "main corridor"]
    assert main(["/nonexistent"]) == 2


def test_after_a_kidnap_the_pose_is_not_reported_localized_while_tracking_holds_on():
    """Seed 1 is carried mid-run; tracking holds on to the old place for a dozen scans until its
    scans have seen four scans' worth of points through the map's walls. The probability reads
    that same evidence as it gathers: from the first scan that sees through walls the pose is
    no longer reported localized. Before, every one of those scans was reported localized while
    metres off (10 scans; now at most 1)."""
    from fusion.integrity import is_localized

    kidnap, t, off, _, probability = _until_after_the_kidnap(1, 10.0)
    wrong = off > LOCALIZED_POSITION
    localized = is_localized(probability)
    after = t >= kidnap.t
    assert wrong[after].sum() >= 10  # the kidnap is not found at once
    assert (localized & wrong & after).sum() <= 1
    # before it, most poses are reported localized (measured 77 %: a featureless corridor and
    # an odometry gap take the rest), and none wrongly
    assert localized[~after].mean() > 0.7 and not (localized & wrong & ~after).any()

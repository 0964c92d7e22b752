"""The ambiguity manager: parallel lines, kidnaps, global start, symmetric maps."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
import yaml
from hypothesis import example, given
from hypothesis import strategies as st

from fusion import Localizer, LocalizerConfig
from fusion.ambiguity.manager import AmbiguityManager
from fusion.ambiguity.spacing import visible_parallel_spacing
from fusion.decision import TrackingScan
from fusion.events import Odometry, PointSet, Scan
from fusion.integrity import is_localized
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.sim import (
    CameraConfig,
    Kidnap,
    RouteConfig,
    SimulationError,
    camera_points,
    scenario_preset,
    simulate,
)
from fusion.sim.routes import OFFICE_LOOP
from fusion.sim.run import interpolate_poses
from fusion.status import State
from houghloc import HoughConfig, SegmentMap, localize_scan
from houghloc.geometry import ranges_to_points
from tests.conftest import REPO

CAMERA = REPO / "fusion" / "configs" / "robocup-camera.yaml"
OFFICE = REPO / "fusion" / "configs" / "office-laser.yaml"

def with_ambiguity(path=OFFICE, **ambiguity: object) -> LocalizerConfig:
    """The scenario's configuration with ``ambiguity`` changes."""
    base = LocalizerConfig.from_yaml(path)
    return base.model_copy(update={"ambiguity": base.ambiguity.model_copy(update=ambiguity)})


def drive(run, loc: Localizer, on_odometry=None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Replay a simulated run; return scan times, (position, heading°) errors and statuses."""
    times, errors, statuses = [], [], []
    for ev in run.events():
        if isinstance(ev, Odometry):
            loc.on_odometry(ev.t, ev.x, ev.y, ev.theta)
            if on_odometry:
                on_odometry(ev.t, loc)
            continue
        if isinstance(ev, Scan):
            est = loc.on_scan(ev.t, ev.ranges, ev.angles)
        elif isinstance(ev, PointSet):
            est = loc.on_points(ev.t, ev.points, ev.sensor)
        else:
            continue
        truth = interpolate_poses(np.array([ev.t]), run.odom_t, run.odom_truth)[0]
        times.append(ev.t)
        errors.append((math.hypot(*(est.pose[:2] - truth[:2])),
                       abs(math.degrees(math.remainder(est.pose[2] - truth[2], 2 * math.pi)))))
        statuses.append(est.status)
    return np.array(times), np.array(errors), statuses


def settled_after(times, errors, start: float, pos: float = 0.10, deg: float = 2.0):
    """Seconds after ``start`` from which the estimate stays within (pos, deg); None if never."""
    good = (errors[:, 0] < pos) & (errors[:, 1] < deg)
    for i in np.flatnonzero(times >= start):
        if good[i:].all():
            return times[i] - start
    return None


def test_nearest_neighbour_locks_onto_the_wrong_field_line_tracking_reports_it(robocup):
    """The camera sees the centre line 1 m ahead; the guess is 2 m off along x with σ 1.5 m,
    more than half the 3.25 m between the painted lines."""
    cfg = LocalizerConfig.from_yaml(CAMERA).sensors["camera"].hough
    true = np.array([-1.0, 0.5, 0.0])
    frame = camera_points(robocup, true, np.random.default_rng(0), CameraConfig(false_points=0))
    guess = true + [2.0, 0.0, 0.0]
    prior = np.diag([1.5**2, 1.5**2, math.radians(3) ** 2])
    plain = localize_scan(frame.points, robocup, guess,
                          cfg.model_copy(update={"nearest_neighbour_only": True}), prior)
    assert not plain.ambiguous and plain.rank >= 2  # confident ...
    assert abs(plain.pose[0] - true[0]) == pytest.approx(3.25, abs=0.05)  # ... and a line off
    ours = localize_scan(frame.points, robocup, guess, cfg, prior)
    assert ours.ambiguous and "fits 2 map lines" in ours.reason


def test_manager_leaves_parallel_lines_for_set_matching_without_a_wrong_pose():
    """Mid-run the filter is put 2 m off with σ = 2 m, more than half the spacing of the painted
    lines in view: with ``max_position_sigma_fraction`` the manager leaves tracking at once and
    matches accumulated views as a set. On the symmetric field with a camera's few lines in
    view, the poses followed do not single out the right one before the run ends (15 s later)
    and none is reported localized: "lost" is the right answer. (The retired rules, which broke
    such ties by the filter's last belief, took the right pose here within 3 s:
    docs/experiments.md, "Ties retired".)"""
    run = simulate(scenario_preset("robocup-camera", seed=3, duration=30))
    config = with_ambiguity(CAMERA, max_position_sigma_fraction=0.5)
    loc = Localizer(run.map, config, run.odom_truth[0])
    wrong_and_sure: list[float] = []
    corrupted = False
    for ev in run.events():
        if isinstance(ev, Odometry):
            loc.on_odometry(ev.t, ev.x, ev.y, ev.theta)
            if not corrupted and ev.t >= 15.0:
                loc.tracker.reset(loc.tracker.pose + [2.0, 0.0, 0.0],
                                  np.diag([2.0**2, 2.0**2, math.radians(3) ** 2]))
                corrupted = True
            continue
        if not isinstance(ev, PointSet):
            continue
        est = loc.on_points(ev.t, ev.points, ev.sensor)
        truth = interpolate_poses(np.array([ev.t]), run.odom_t, run.odom_truth)[0]
        if math.hypot(*(est.pose[:2] - truth[:2])) > 0.3 and is_localized(
                est.localized_probability):
            wrong_and_sure.append(ev.t)
    reasons = [tr.reason for tr in loc.manager.transitions]
    assert any("between parallel lines in view" in r for r in reasons), reasons
    assert any(tr.new is State.RELOCALIZING for tr in loc.manager.transitions)
    assert wrong_and_sure == []
    assert loc.manager.followed


def kidnap_run(seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        angle, t_kidnap = rng.uniform(0, 2 * math.pi), rng.uniform(20, 40)
        cfg = scenario_preset("office-laser", seed=seed, duration=t_kidnap + 15)
        kidnap = Kidnap(t=t_kidnap, dx=3 * math.cos(angle), dy=3 * math.sin(angle),
                        dtheta_deg=35 * rng.choice([-1, 1]))
        try:
            return simulate(cfg.model_copy(update={"kidnaps": [kidnap]})), t_kidnap
        except SimulationError:  # the spot 3 m away is inside a wall: try another direction
            continue
    raise AssertionError("no feasible kidnap")


def kidnap_trial(seed: int, config: LocalizerConfig | None = None
                 ) -> tuple[float | None, int, Localizer, list[str]]:
    """Recovery seconds after the kidnap (None: never), the number of scans whose fix was used
    although the pose was wrong, the localizer and the statuses."""
    run, t_kidnap = kidnap_run(seed)
    loc = Localizer(run.map, config or LocalizerConfig.from_yaml(OFFICE), run.odom_truth[0])
    times, errors, statuses = drive(run, loc)
    wrong = (errors[:, 0] >= 0.10) | (errors[:, 1] >= 2.0)
    confident_wrong = sum(1 for w, s in zip(wrong, statuses, strict=True) if w and s == "accepted")
    return settled_after(times, errors, t_kidnap), confident_wrong, loc, statuses


def test_kidnapped_robot_is_detected_and_recovered():
    recovered, confident_wrong, _, _ = kidnap_trial(seed=3)
    assert recovered is not None and recovered <= 5.0
    assert confident_wrong == 0


# Kidnaps (3 m, 35°) that land where the office repeats itself, each with what makes it hard.
# Measured with the defaults: recovered 1.6, 3.0, 3.2 and 3.3 s after the kidnap.
LOOK_ALIKE_KIDNAPS = {
    10: "put down in a room, one wall in view: its single-line fixes steer the heading wherever "
        "the odometry drifts while every innovation stays small",
    1: "near the corridor's west end, halfway between the last belief and the look-alike "
       "place 7 m further east",
    27: "near a room's corner: the first global matches propose look-alike corners elsewhere",
    12: "in the corridor 0.2 m from a wall, facing along it: no room's wall in view for 5 s",
}


@pytest.mark.parametrize("seed", list(LOOK_ALIKE_KIDNAPS))
def test_kidnaps_into_look_alike_places_are_recovered_without_a_wrong_fix(seed):
    recovered, confident_wrong, loc, _ = kidnap_trial(seed)
    assert confident_wrong == 0, LOOK_ALIKE_KIDNAPS[seed]
    assert recovered is not None and recovered <= 5.0, (recovered, LOOK_ALIKE_KIDNAPS[seed])
    reasons = [tr.reason for tr in loc.manager.transitions]
    assert any(r.startswith("following") for r in reasons), reasons


def test_misfit_is_relative_to_recent_fixes(office):
    """A fix is compared with the fixes before it, so a cluttered place (few points on walls at
    any pose) does not make every fix a misfit; a fix that puts the scan off the walls is one."""
    from fusion.ambiguity.manager import AmbiguityManager

    manager = AmbiguityManager(office)
    pose = np.array([5.0, 6.0, 0.0])
    wall_points = np.column_stack((np.linspace(-4, 0, 60), np.full(60, 1.0)))  # y = 7 wall
    clutter = np.column_stack((np.linspace(-1, 1, 40), np.full(40, 0.5)))  # off every wall
    scan = np.concatenate((wall_points, clutter))  # 60 % on walls
    assert manager.fit.fraction(pose, scan) == pytest.approx(0.6)
    assert all(manager.fit.fix_fits(pose, scan) for _ in range(10))
    assert manager.fit.fix_fits(pose + [0.0, 0.3, 0.0], scan) is False  # 0 % on walls
    assert manager.fit.fix_fits(pose + [0.3, 0.0, 0.0], scan)  # along the wall: still 60 %
    assert manager.counts["misfits"] == 1


def test_fit_judges_fixes_the_matcher_cannot(office):
    """With the fit rules on: a fix that moves the scan off walls the guess had it on is a misfit
    (however well it passed the gates), one the matcher could not vouch for is used when it puts
    clearly more points on walls than the guess, and a scan whose guess still fits as well as the
    accepted ones did does not count as a failure."""

    config = AmbiguityConfig(max_fit_loss=0.1, min_fit_gain=0.03, hold_fit_ratio=0.9,
                             misfit_ratio=0.0, max_scans_without_fix=3)
    manager = AmbiguityManager(office, config)
    pose = np.array([5.0, 6.0, 0.0])
    scan = np.column_stack((np.linspace(-4, 0, 60), np.full(60, 1.0)))  # the y = 7 wall
    on_wall = manager.fit.fraction(pose, scan)
    off_wall = pose + [0.0, 0.3, 0.0]
    assert on_wall == pytest.approx(1.0) and manager.fit.fraction(off_wall, scan) == 0.0
    assert manager.fit.fix_fits(pose, scan, guess_fit=on_wall)
    assert manager.fit.fix_fits(off_wall, scan, guess_fit=on_wall) is False
    assert manager.fit.fix_fits(off_wall, scan, guess_fit=0.0)  # nothing lost: not judged
    assert manager.fit.fix_gains(pose, scan, ("wall",), guess_fit=0.0)
    assert not manager.fit.fix_gains(pose, scan, ("wall",), guess_fit=0.98)  # no clear gain
    assert manager.counts["fit_losses"] == 1 and manager.counts["fixes_by_fit"] == 1

    cov = np.diag([0.01, 0.01, 0.001])
    for k in range(5):
        manager.tracking_step(float(k), "accepted", cov, guess_fit=0.8)
    for k in range(10):  # the guess keeps the scan on the walls: not lost
        manager.tracking_step(5.0 + k, "ambiguous", cov, guess_fit=0.75)
    assert manager.state is State.TRACKING
    for k in range(3):  # it no longer does: three failures and the manager gives up tracking
        manager.tracking_step(15.0 + k, "ambiguous", cov, guess_fit=0.5)
    assert manager.state is State.COLLECTING


@pytest.mark.parametrize("slip", [(0.0, 0.0, 12.0), (0.0, 0.0, -16.0), (0.29, 0.09, 14.0)])
def test_local_search_recovers_a_motion_the_robot_did_not_make(office, slip):
    """The odometry reports a turn of 12-16° that the robot did not make (a wheel slip in a turn
    on the spot), with or without a short drive: far outside the filter's gates, so no fix
    matches. The scan's lines matched near the dead-reckoned pose find the robot again on that
    scan; without the local re-search no fix is found again."""
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    def replay(local: bool) -> tuple[list[str], float]:
        config = with_ambiguity(local_search_xy=1.0 if local else None)
        truth = np.array([5.0, 6.0, 0.3])
        loc = Localizer(office, config, initial_pose=truth)
        rng = np.random.default_rng(1)
        statuses = []
        for k in range(14):
            reported = truth + (np.array([slip[0], slip[1], math.radians(slip[2])])
                                if k >= 8 else 0.0)
            loc.on_odometry(0.2 * k, *reported)
            scan = laser_scan(office, truth, rng, LaserConfig(max_range=10.0))
            statuses.append(loc.on_scan(0.2 * k, scan.ranges, scan.angles).status)
        error = loc.pose - truth
        return statuses, max(math.hypot(error[0], error[1]),
                             abs(math.degrees(math.remainder(error[2], 2 * math.pi))) / 100)

    statuses, error = replay(local=True)
    assert statuses[:8] == ["accepted"] * 8
    assert statuses[8] == "re-searched" and statuses[9:] == ["accepted"] * 5
    assert error < 0.05
    statuses, error = replay(local=False)
    assert "re-searched" not in statuses and "accepted" not in statuses[8:]
    assert error > 0.1


@pytest.mark.parametrize("reach", [2.0, None])
def test_local_search_keeps_within_reach_of_the_odometry(office, reach):
    """Right after accepted fixes the scans come from 0.6 m further along while the odometry
    reports the robot standing still: no slip explains that. The re-search finds the pose
    (with the reach unlimited it re-initialises there) but refuses it as out of reach of the
    motion since the last fix (0.25 m + 2 × 0 m)."""
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    ambiguity = {"hold_fit_ratio": 0.9, "max_scans_without_fix": 50, "local_search_xy": 1.0,
                 "local_reach_per_metre": reach}
    config = LocalizerConfig.from_dict({"sensors": {"laser": {"max_range": 10.0}},
                                        "ambiguity": ambiguity})
    start = np.array([5.0, 6.0, 0.3])
    loc = Localizer(office, config, initial_pose=start)
    rng = np.random.default_rng(1)
    statuses = []
    for k in range(12):
        truth = start + (np.array([0.6 * math.cos(0.3), 0.6 * math.sin(0.3), 0.0])
                         if k >= 8 else 0.0)
        loc.on_odometry(0.2 * k, *start)
        scan = laser_scan(office, truth, rng, LaserConfig(max_range=10.0))
        statuses.append(loc.on_scan(0.2 * k, scan.ranges, scan.angles).status)
    assert statuses[:8] == ["accepted"] * 8
    searches = loc.manager.counts["local_searches"]
    if reach is None:
        assert statuses[8] == "re-searched"
        assert math.hypot(*(loc.pose - truth)[:2]) < 0.05
    else:
        assert searches >= 4 and "re-searched" not in statuses
        assert loc.manager.counts["local_out_of_reach"] == searches
        assert math.hypot(*(loc.pose - start)[:2]) < 0.05


@pytest.mark.parametrize("sigma_deg, found", [(1.0, False), (20.0, True)])
def test_local_search_turns_as_far_as_the_guess_is_uncertain(office, sigma_deg, found):
    """A fast spin the odometry half missed leaves the guess 50° off the robot's heading. With
    the heading σ the motion model grew in such a spin (20°), the re-search reaches that far
    (3.9 σ at the matcher's gate probability) and finds the robot; with σ = 1° it keeps to its
    least range (±20°) and finds nothing there that fits."""
    from fusion.ambiguity.local_search import _heading_reach
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    assert _heading_reach(0.35, None, 0.9999) == 0.35
    assert _heading_reach(0.35, np.diag([1.0, 1.0, 0.0025]), 0.9999) == 0.35
    assert _heading_reach(0.35, np.diag([1.0, 1.0, 0.04]), 0.9999) == pytest.approx(0.2 * 3.8906,
                                                                                   rel=1e-4)
    assert _heading_reach(0.35, np.diag([1.0, 1.0, 100.0]), 0.9999) == math.pi

    manager = AmbiguityManager(office, AmbiguityConfig(local_search_xy=1.0, hold_fit_ratio=0.9))
    truth = np.array([5.0, 6.0, 0.3])
    scan = laser_scan(office, truth, np.random.default_rng(3), LaserConfig(max_range=10.0))
    points = ranges_to_points(scan.ranges, scan.angles, 10.0, 0.0)
    for k in range(5):  # tracking fitted this well before the spin
        assert manager.fit.fix_fits(truth, points, guess_fit=0.9)
        manager.tracking_step(float(k), "accepted", np.diag([0.01, 0.01, 0.001]), guess_fit=0.9)
    guess = truth + [0.05, -0.05, math.radians(50.0)]
    guess_cov = np.diag([0.1**2, 0.1**2, math.radians(sigma_deg) ** 2])
    fix = localize_scan(points, office, guess, HoughConfig(), pose_cov=guess_cov)
    guess_fit = manager.fit.fraction(guess, points)
    scan = TrackingScan(5.0, points, "laser", HoughConfig(), 2, guess, guess_cov)
    decision = manager.local_search(scan, fix, guess_fit, None)
    if found:
        assert decision.reset_pose is not None
        error = decision.reset_pose - truth
        assert math.hypot(error[0], error[1]) < 0.05 and abs(math.degrees(error[2])) < 1.0
    else:
        assert decision.reset_pose is None


def test_local_search_is_wanted_when_the_scan_fits_worse_than_usual(office):
    """At the guess when no fix was used; at the fix when one was: two lines matched to the
    wrong walls after a slip pass the gates and still leave the scan off the walls."""

    manager = AmbiguityManager(office, AmbiguityConfig(local_search_xy=1.0, hold_fit_ratio=0.9))
    pose = np.array([5.0, 6.0, 0.0])
    scan = np.column_stack((np.linspace(-4, 0, 60), np.full(60, 1.0)))  # all on the y = 7 wall
    cov = np.diag([0.01, 0.01, 0.001])
    assert not manager.wants_local_search(0.1)  # no recent fits to compare with yet
    for k in range(5):
        assert manager.fit.fix_fits(pose, scan, guess_fit=0.9)
        manager.tracking_step(float(k), "accepted", cov, guess_fit=0.9)
    assert manager.wants_local_search(0.5) and not manager.wants_local_search(0.85)
    assert manager.wants_local_search(0.95, fix_fit=0.6)
    assert not manager.wants_local_search(0.5, fix_fit=0.95)
    manager.config = manager.config.model_copy(update={"local_search_xy": None})
    assert not manager.wants_local_search(0.1)


def test_local_search_candidate_in_a_corridor_keeps_the_guess_along_it(office):
    """Tracked from a start moved along a corridor (only its two walls in view), a fix observes
    the heading and the position across it: the candidate takes those and keeps the guess's
    position along the corridor, with a finite uncertainty there, so starts along the corridor
    do not become rivals of each other, and says it kept it. An ambiguous or empty fix is no
    candidate."""
    from fusion.ambiguity.local_search import _polished

    true = np.array([5.5, 6.2, 0.0])
    along = np.arange(-4.0, 4.0, 0.03)
    points = np.concatenate([np.column_stack((along, np.full_like(along, y - true[1])))
                             for y in (5.0, 7.0)])
    guess = true + np.array([0.3, 0.06, math.radians(3.0)])
    prior = np.diag([0.1**2, 0.1**2, math.radians(2.0) ** 2])
    for start_x in (0.0, 0.5, -0.5):
        start = guess + np.array([start_x, 0.0, 0.0])
        fix = localize_scan(points, office, start, HoughConfig(), pose_cov=prior)
        assert fix.rank == 2 and not fix.ambiguous, fix.reason
        polished = _polished(fix, guess)
        assert polished is not None
        pose, cov, along_kept = polished
        assert along_kept  # the manager has a global match contest it
        assert pose[0] == pytest.approx(guess[0], abs=1e-6)
        assert abs(pose[1] - true[1]) < 0.02 and abs(pose[2] - true[2]) < math.radians(0.5)
        assert cov[0, 0] == pytest.approx(0.09, rel=0.01) and np.linalg.eigvalsh(cov).max() < 1
    empty = localize_scan(points[:5], office, guess, HoughConfig(), pose_cov=prior)
    assert _polished(empty, guess) is None


def test_look_alike_rooms_told_apart_by_the_displacement_prior():
    """Put down in the south room that repeats 7 m further east (same door, same walls in
    view): both rooms are followed and fit the scans equally well; the one 3 m from the last
    belief is likelier by the displacement prior (``kidnap_prior_sigma``) than the one 9 m
    away, and is taken within 2.6 s. Without the prior the two stay level until the cabinet
    comes into view, 8.3 s after the kidnap."""
    recovered, confident_wrong, _, _ = kidnap_trial(seed=4)
    assert recovered is not None and recovered <= 3.0 and confident_wrong == 0
    later, confident_wrong, _, _ = kidnap_trial(seed=4,
                                                config=with_ambiguity(kidnap_prior_sigma=None))
    assert confident_wrong == 0
    assert later is None or later > 5.0


@pytest.mark.slow
def test_kidnap_twenty_seeds():
    trials = [kidnap_trial(seed)[:2] for seed in range(20)]
    ok = [r is not None and r <= 5.0 for r, _ in trials]
    assert sum(ok) >= 19, trials
    assert all(c == 0 for _, c in trials)  # a confident wrong pose never lasts


@pytest.mark.slow
def test_kidnap_fresh_seeds():
    """The office kidnap (3 m, 35°) on two hundred seeds drawn anew on every run: recovered
    within 5 s in at least 95 % (190). Over 720 seeds (2000-2399 and 320 drawn at random) 709
    were, 98.5 %: at that rate this fails on about 0.03 % of runs, and at a true 97 % on about
    4 %, so a slip of the rate is caught before it is large. The unrecovered seeds are listed
    in the message, to replay a failure with ``kidnap_trial(seed)``."""
    seeds = [int(s) for s in np.random.default_rng().integers(0, 2**31, 200)]
    trials = {seed: kidnap_trial(seed)[0] for seed in seeds}
    missed = {seed: r for seed, r in trials.items() if r is None or r > 5.0}
    assert len(missed) <= 10, (
        f"{len(missed)} of {len(seeds)} kidnaps not recovered within 5 s "
        f"(seed: recovery time, None if never): "
        + ", ".join(f"{seed}: {r}" for seed, r in missed.items()))


def global_start_trial(seed: int, manager_out: list | None = None,
                       config: LocalizerConfig | None = None) -> float | None:
    rng = np.random.default_rng(100 + seed)
    k = int(rng.integers(len(OFFICE_LOOP)))
    waypoints = [tuple(w) for w in [*OFFICE_LOOP[k:], *OFFICE_LOOP[:k]]]
    cfg = scenario_preset("office-laser", seed=seed, duration=25)
    run = simulate(cfg.model_copy(update={"route": RouteConfig(kind="waypoints",
                                                                 waypoints=waypoints)}))
    loc = Localizer(run.map, config or LocalizerConfig.from_yaml(OFFICE), initial_pose=None)
    assert loc.manager.state is State.LOST
    times, errors, _ = drive(run, loc)
    if manager_out is not None:
        manager_out.append(loc.manager)
    return settled_after(times, errors, times[0])


def test_global_start_without_an_initial_pose():
    managers: list = []
    settle = global_start_trial(seed=0, manager_out=managers)
    assert settle is not None and settle <= 10.0
    taken = [tr for tr in managers[0].transitions if tr.new is State.TRACKING]
    assert taken and taken[0].reason.startswith("relocalized"), managers[0].transitions


@pytest.mark.slow
def test_global_start_twenty_random_starts():
    """The office's rooms repeat every 7 m: from no pose at all, the followed hypotheses are
    right within a second on 15 of 20 starts, but where look-alike places fit the scans as
    well as the right one the likeliest changes hands until one fits better (measured: 17
    within 10 s, 19 within the 25 s run)."""
    settles = [global_start_trial(seed) for seed in range(20)]
    assert sum(s is not None and s <= 10.0 for s in settles) >= 17, settles
    assert sum(s is not None and s < 25.0 for s in settles) >= 19, settles


def test_symmetric_field_reports_both_mirror_hypotheses():
    """Started without a pose on the RoboCup field, a laser sees only walls: the pose and its
    180° mirror explain the scans equally well. Both are followed, as likely as each other, and
    none is picked."""
    run = simulate(scenario_preset("robocup-laser", seed=2, duration=4))
    loc = Localizer(run.map, None, initial_pose=None)
    _, _, statuses = drive(run, loc)
    assert loc.manager.state is not State.TRACKING
    followed = loc.manager.followed
    assert len(followed) == 2, [tr.reason for tr in loc.manager.transitions]
    assert followed[0][1] == pytest.approx(0.5, abs=0.1)
    a, b = (pose for pose, _ in followed)
    assert abs(math.remainder(a[2] - b[2], 2 * math.pi)) == pytest.approx(math.pi, abs=0.1)
    assert np.allclose(a[:2], -b[:2], atol=0.2)  # mirrored through the centre of the field
    assert "accepted" not in statuses


def test_goal_colours_break_the_mirror_tie():
    """The same start with the goals' colours seen by a camera: once a goal comes into view the
    mirror hypothesis predicts it behind the robot, is dropped, and tracking starts at the true
    pose."""
    from fusion.io import merge_by_time
    from fusion.sim import landmark_sightings

    run = simulate(scenario_preset("robocup-laser", seed=2, duration=20))
    loc = Localizer(run.map, None, initial_pose=None)

    class WithGoals:  # the run's events with the goal sightings merged in
        def __getattr__(self, name):
            return getattr(run, name)

        def events(self):
            return merge_by_time([run.events(), landmark_sightings(run, seed=2)])

    from fusion.events import Landmark

    times, errors, goal_seen = [], [], []  # goal_seen: sightings while poses are followed
    for ev in WithGoals().events():
        if isinstance(ev, Landmark):
            if loc.manager.followed:
                goal_seen.append(ev.t)
            loc.on_landmark(ev.t, ev.label, ev.bearing)
        elif isinstance(ev, Odometry):
            loc.on_odometry(ev.t, ev.x, ev.y, ev.theta)
        elif isinstance(ev, Scan):
            est = loc.on_scan(ev.t, ev.ranges, ev.angles)
            truth = interpolate_poses(np.array([ev.t]), run.odom_t, run.odom_truth)[0]
            times.append(ev.t)
            errors.append((math.hypot(*(est.pose[:2] - truth[:2])),
                           abs(math.degrees(math.remainder(est.pose[2] - truth[2], 2 * math.pi)))))
    reasons = [tr.reason for tr in loc.manager.transitions]
    assert any("following 2 hypotheses" in r for r in reasons), reasons  # the mirror pair
    # the goal decides: the pose is taken when it is first seen, or on a scan just after it
    # (its weight raised past the bar by the sighting)
    taken = [tr.t for tr in loc.manager.transitions if tr.reason.startswith("relocalized")]
    assert taken and goal_seen and 0.0 <= taken[0] - goal_seen[0] <= 0.25, (taken, goal_seen)
    settle = settled_after(np.array(times), np.array(errors), times[0])
    assert settle is not None and settle < 15.0


def test_corridor_seen_along_its_length_is_placed_by_sliding(office):
    """Only the corridor's two walls and their door gaps in view (no wall across it): no pair
    of lines fixes the pose, sliding the view along the corridor does. The corridor repeats
    every 7 m, so the copy 7 m away is reported as a tie, not a winner."""
    from houghloc import GlobalMatchConfig, global_match, observe_lines

    true = np.array([5.5, 6.2, 0.0])
    along = np.arange(-4.0, 4.0, 0.03)
    world = [np.column_stack((true[0] + along, np.full_like(along, y))) for y in (5.0, 7.0)]
    world = np.concatenate(world)
    a, e = office.starts, office.ends - office.starts  # distance to every segment, exactly
    u = np.clip(((world[:, None] - a) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
    gap = np.hypot(*(a + u[..., None] * e - world[:, None]).transpose(2, 0, 1)).min(axis=1)
    points = world[gap < 1e-6] - true[:2]  # heading 0: robot frame = world shifted
    assert len(points) < 0.95 * len(world)  # the door gaps are in the view
    cfg = GlobalMatchConfig()
    _, _, lines = observe_lines(points, cfg.hough)
    result = global_match(lines, points, office, cfg)
    assert result.hypotheses, result.reason
    errors = [(math.hypot(*(h.pose[:2] - true[:2])),
               abs(math.remainder(h.pose[2] - true[2], 2 * math.pi))) for h in result.hypotheses]
    assert any(d < 0.05 and a < math.radians(1.0) for d, a in errors), errors
    assert result.ambiguous  # the copy 7 m along
    # searched near a guess 0.6 m and 8° off, the copy is out of reach: no tie, and only the
    # corridor's poses inside the neighbourhood are slid over
    from houghloc.neighbourhood import Neighbourhood

    near = Neighbourhood(true + [0.6, 0.1, math.radians(8.0)], 1.0, math.radians(20.0))
    local = global_match(lines, points, office, cfg, near=near)
    assert local.best is not None and not local.ambiguous, local.reason
    assert math.hypot(*(local.best.pose[:2] - true[:2])) < 0.05
    assert local.n_candidates < result.n_candidates / 5
    no_slide = cfg.model_copy(update={"slide_along_parallel": False})
    off = global_match(lines, points, office, no_slide)
    assert not off.hypotheses and "non-parallel" in off.reason


# references in a few directions, a little apart: parallel pairs at every spacing
_REFERENCE = st.tuples(st.sampled_from([0.0, 0.5 * math.pi, 2.0]), st.floats(-0.05, 0.05),
                       st.floats(0.0, 3.0)).map(lambda r: (r[0] + r[1], r[2]))


@given(st.lists(_REFERENCE, max_size=6), st.floats(0.0, 1.0), st.floats(0.1, 3.0))
def test_tracking_gives_up_when_sigma_exceeds_the_parallel_spacing_in_view(
        office, refs: list[tuple[float, float]], sigma: float, fraction: float) -> None:
    """The covariance check leaves tracking exactly when σ_xy > fraction × the closest spacing of
    parallel references in view (the check skips computing the spacing when σ is below any
    spacing it could return)."""
    manager = AmbiguityManager(office,
                               AmbiguityConfig(max_position_sigma_fraction=fraction))
    theta, rho = np.array([r[0] for r in refs]), np.array([r[1] for r in refs])
    manager.tracking_step(1.0, "accepted", np.diag([sigma**2, 0.25 * sigma**2, 1e-4]),
                          in_view=(theta, rho))
    expected = sigma > fraction * visible_parallel_spacing(theta, rho)
    assert (manager.state is State.COLLECTING) == expected


def test_a_match_spread_over_scans_hands_its_poses_on_where_the_robot_is_now():
    """A global start with every stage of the match on its own scan (the least budget): the
    match ends several scans after the views it matched, the robot has moved meanwhile, and
    the poses it hands to the followed filters are where the robot is at that scan (carried
    by the odometry since), not where it was; the start is then as good as with the whole
    match on one scan."""
    run = simulate(scenario_preset("office-laser", seed=0, duration=15))
    config = LocalizerConfig.from_yaml(OFFICE)
    slow = config.model_copy(update={"ambiguity": config.ambiguity.model_copy(
        update={"match_lookups_per_scan": 1})})
    loc = Localizer(run.map, slow, initial_pose=None)
    handed, started, spans = [], None, []
    for ev in run.events():
        if isinstance(ev, Odometry):
            loc.on_odometry(ev.t, ev.x, ev.y, ev.theta)
        elif isinstance(ev, Scan):
            before = len(loc.manager.transitions)
            loc.on_scan(ev.t, ev.ranges, ev.angles)
            for tr in loc.manager.transitions[before:]:
                if tr.new is State.RELOCALIZING:
                    started = tr.t
                elif "following" in tr.reason and started is not None:
                    spans.append(tr.t - started)
                    truth = interpolate_poses(np.array([ev.t]), run.odom_t, run.odom_truth)[0]
                    handed.append(min(math.hypot(*(p[:2] - truth[:2]))
                                      for p, _ in loc.manager.followed))
    assert spans and max(spans) >= 0.5  # five or more scans of the 10 Hz laser
    assert handed and min(handed) < 0.05, handed  # the right pose, at this scan
    times, errors, _ = drive(simulate(scenario_preset("office-laser", seed=0, duration=15)),
                             Localizer(run.map, slow, initial_pose=None))
    settle = settled_after(times, errors, times[0])
    assert settle is not None and settle <= 10.0


INTERIOR = {"rs1", "rs2", "rs3", "rn1", "rn2", "pil1", "pil2", "pil3", "pil4", "cab1", "cab2",
            "cab3", "alc1", "alc2", "alc3"}


@given(x=st.floats(0.5, 25.5), y=st.floats(5.3, 6.7), heading=st.floats(-math.pi, math.pi),
       seed=st.integers(0, 1000))
@example(x=6.0, y=6.0, heading=2.220446049250313e-16, seed=2)  # a beam through a door's edge
def test_a_scan_at_its_own_pose_sees_nothing_through_walls(office, x, y, heading, seed):
    """Anywhere in the office's corridor, a simulated scan placed at the pose it was taken from
    has no point beyond a wall (the ray to each point crosses none more than the visibility
    margin before it), whatever the range noise. The example's 45° beam passes exactly through
    the end of the wall at a door (7, 7), as the simulated laser's does."""
    from fusion.ambiguity.fit import ScanFit
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    truth = np.array([x, y, heading])
    scan = laser_scan(office, truth, np.random.default_rng(seed), LaserConfig(max_range=10.0))
    points = ranges_to_points(scan.ranges, scan.angles, 10.0, 0.0)
    assert ScanFit(office, AmbiguityConfig()).seen_through(truth, points) == 0.0


@pytest.mark.parametrize("truth", [(5.0, 6.0, 0.3), (12.0, 2.5, 1.0), (3.0, 9.5, -2.0)])
def test_a_scan_three_metres_from_its_pose_is_seen_through_walls(office, truth):
    """The same scan placed 3 m away (a kidnap) has a third to three quarters of its points
    beyond the map's walls: what contradicts a belief, where an unexplained point does not."""
    from fusion.ambiguity.fit import ScanFit
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    truth = np.array(truth)
    scan = laser_scan(office, truth, np.random.default_rng(0), LaserConfig(max_range=10.0))
    points = ranges_to_points(scan.ranges, scan.angles, 10.0, 0.0)
    fit = ScanFit(office, AmbiguityConfig())
    assert fit.seen_through(truth + [0.0, -3.0, 0.0], points) > 0.3
    assert fit.seen_through(truth + [2.0, 2.0, 0.6], points) > 0.08


@pytest.mark.parametrize("truth", [(5.0, 6.0, 0.3), (12.0, 2.5, 1.0), (3.0, 9.5, -2.0)])
def test_the_scan_is_far_likelier_at_its_pose_than_where_it_sees_through_walls(office, truth):
    """A scan's shares on walls, through them and neither sum to one; at its own pose nearly all
    its points are on walls and none beyond one. The same scan 3 m away sees through walls: the
    scan's likelihood makes its own pose more than 19 times likelier (what a local re-search
    needs to move the filter), and the pose 3 m away is no re-search result against it."""
    from collections import Counter

    from fusion.ambiguity.fit import ScanFit
    from fusion.ambiguity.local_search import LocalSearch
    from fusion.sim.config import LaserConfig
    from fusion.sim.laser import laser_scan

    truth = np.array(truth)
    scan = laser_scan(office, truth, np.random.default_rng(0), LaserConfig(max_range=10.0))
    points = ranges_to_points(scan.ranges, scan.angles, 10.0, 0.0)
    config = AmbiguityConfig()
    fit = ScanFit(office, config)
    away = truth + [0.0, -3.0, 0.0]
    shares = fit.shares(np.array([truth, away]), points)
    assert np.allclose(shares.sum(axis=1), 1.0)
    assert shares[0, 0] > 0.9 and shares[0, 1] == 0.0 and shares[1, 1] > 0.3
    search = LocalSearch(office, config, fit, Counter())
    assert search._likelier(truth, away, points, ("wall",))
    assert not search._likelier(away, truth, points, ("wall",))
    assert search.counts["local_less_likely"] == 1


@pytest.mark.parametrize("seed", [1, 3])
def test_a_map_without_its_rooms_walls_is_tracked_through_by_odometry(seed):
    """The office run localized in the office map without its interior walls (room dividers,
    pillar, cabinet, alcove): in the rooms most of a scan lands where the map has nothing,
    and fixes are scarce. None of those scans is seen through a wall from the right pose, so
    tracking carries on by odometry and the error stays under 15 cm; giving up after
    ``max_scans_without_fix`` such scans instead (``through_wall_scans`` None) hands the
    pose to a look-alike metres away."""
    raw = yaml.safe_load((REPO / "fusion" / "configs" / "maps" / "office.yaml").read_text())
    raw["segments"] = [s for s in raw["segments"] if s["id"] not in INTERIOR]
    lacking = SegmentMap.from_dict(raw)
    run = simulate(scenario_preset("office-laser", seed=seed, duration=120.0))
    base = LocalizerConfig.from_yaml(OFFICE)

    def localize(through_wall_scans: float | None) -> tuple[int, float]:
        config = base.model_copy(update={"ambiguity": base.ambiguity.model_copy(
            update={"through_wall_scans": through_wall_scans})})
        loc = Localizer(lacking, config, initial_pose=run.odom_truth[0])
        _, errors, _ = drive(run, loc)
        given_up = sum(tr.old is State.TRACKING and tr.new is State.COLLECTING
                       for tr in loc.manager.transitions)
        return given_up, float(errors[:, 0].max())

    given_up, worst = localize(base.ambiguity.through_wall_scans)
    assert base.ambiguity.through_wall_scans is not None  # the defaults judge by walls
    assert given_up == 0 and worst < 0.15
    given_up, worst = localize(None)
    assert given_up >= 1 and worst > 3.0


def test_scans_that_match_nothing_give_tracking_up_then_leave_the_robot_lost(office):
    """Scans of clutter that lies across the map's walls: tracking is given up on the points seen
    through walls, and its belief is the first pose followed; global matches of such views find
    nothing, and after ``failures_until_lost`` of them the robot is lost, with no belief left to
    weigh poses against. The transitions chain and every reason is recorded."""
    rng = np.random.default_rng(7)
    loc = Localizer(office, LocalizerConfig.from_yaml(OFFICE), np.array([5.0, 6.0, 0.0]))
    manager = loc.manager
    followed_when_given_up = None
    for k in range(400):
        t = 0.1 * k
        loc.on_odometry(t, 0.02 * k, 0.0, 0.0)
        estimate = loc.on_points(t, rng.uniform(-8.0, 8.0, (150, 2)), "laser")
        if manager.state is not State.TRACKING and followed_when_given_up is None:
            followed_when_given_up, belief = manager.followed, estimate.pose
        if manager.state is State.LOST:
            break
    steps = manager.transitions
    assert manager.state is State.LOST, [(tr.new.value, tr.reason) for tr in steps]
    assert steps[0].old is State.TRACKING and steps[0].new is State.COLLECTING
    assert "through the map's walls" in steps[0].reason
    assert followed_when_given_up is not None and len(followed_when_given_up) == 1
    assert np.allclose(followed_when_given_up[0][0], belief, atol=1e-9)
    assert all(later.old is earlier.new for earlier, later in pairwise(steps))
    failed = [tr for tr in steps if tr.reason.startswith("no global hypothesis")]
    assert len(failed) == manager.config.failures_until_lost and failed[-1].new is State.LOST
    assert manager.belief.prior is None and manager.relocalization.match is None

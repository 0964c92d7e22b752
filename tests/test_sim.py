"""Tests of the scenario simulator (fusion.sim): geometry, sensors, odometry, runs and files."""

from __future__ import annotations

import math

import numpy as np
import pydantic
import pytest

from fusion.events import Odometry, PointSet, Scan, Truth
from fusion.sim import (
    MAPS_DIR,
    MOVING_OBSTACLE,
    NO_RETURN,
    CameraConfig,
    Kidnap,
    LaserConfig,
    OdometryConfig,
    ScenarioConfig,
    SimulationError,
    camera_points,
    laser_scan,
    load_scenario,
    obstacle_fraction,
    path_crosses_walls,
    place_obstacles_near,
    random_free_pose,
    read_camera_points,
    scenario_preset,
    simulate,
    write_run,
)
from fusion.sim.poses import increments
from fusion.sim.raycast import min_distance, segment_segment_distance, segments_cross
from fusion.sim.routes import OFFICE_LOOP
from fusion.sim.world import wall_segments
from houghloc.geometry import wrap_angle
from houghloc.segment_map import SegmentMap

EXACT_LASER = LaserConfig(sigma=0.0, dropout_prob=0.0, spurious_prob=0.0, max_range=30.0)
EXACT_CAMERA = CameraConfig(sigma0=0.0, k=0.0, false_points=0.0)
NO_ODOM_ERROR = OdometryConfig(left_scale_error=0.0, right_scale_error=0.0, wheel_noise=0.0)


@pytest.fixture(scope="module")
def robocup() -> SegmentMap:
    return SegmentMap.from_yaml(MAPS_DIR / "robocup.yaml")


@pytest.fixture(scope="module")
def office() -> SegmentMap:
    return SegmentMap.from_yaml(MAPS_DIR / "office.yaml")


def box_map(w: float = 10.0, h: float = 6.0) -> SegmentMap:
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
    return SegmentMap(corners, np.roll(corners, -1, axis=0), ids=["south", "east", "north", "west"])


def seg_index(m: SegmentMap, seg_id: str) -> int:
    return m.ids.index(seg_id)


def no_laser(name: str, **update) -> ScenarioConfig:
    """A preset without sensors: fast, for tests of the motion and the odometry."""
    cfg = scenario_preset(name)
    return cfg.model_copy(update={"laser": None, "camera": None, **update})


# ------------------------------------------------------------------------------ determinism
def test_same_seed_same_run_other_seed_other_run():
    cfg = scenario_preset("robocup-laser", seed=3, duration=8.0)
    a, b = simulate(cfg), simulate(cfg)
    for name in ("odom_pose", "odom_truth", "ranges", "scan_labels", "scan_obstacles"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = simulate(scenario_preset("robocup-laser", seed=4, duration=8.0))
    assert not np.array_equal(a.ranges, c.ranges)


def test_camera_run_is_deterministic():
    cfg = scenario_preset("robocup-camera", seed=1, duration=3.0)
    a, b = simulate(cfg), simulate(cfg)
    assert len(a.cam_points) == len(b.cam_points) == 16
    for p, q in zip(a.cam_points, b.cam_points, strict=True):
        np.testing.assert_array_equal(p, q)


# ------------------------------------------------------------------------------ laser geometry
def test_laser_ranges_match_geometry_exactly():
    m = box_map()
    pose = np.array([2.0, 3.5, 0.3])
    scan = laser_scan(m, pose, np.random.default_rng(0), EXACT_LASER)
    # Independent scalar reference: the first positive crossing of the four box sides.
    expected = []
    for a in scan.angles:
        c, s = math.cos(pose[2] + a), math.sin(pose[2] + a)
        ts = [t for t in ((10 - 2) / c if c > 0 else -1, -2 / c if c < 0 else -1,
                          (6 - 3.5) / s if s > 0 else -1, -3.5 / s if s < 0 else -1) if t > 0]
        expected.append(min(ts))
    np.testing.assert_allclose(scan.ranges, expected, rtol=0, atol=1e-12)
    assert set(np.unique(scan.labels)) <= {0, 1, 2, 3}


def test_robot_facing_a_wall_at_known_distance():
    m = box_map()
    scan = laser_scan(m, (7.0, 2.0, 0.0), np.random.default_rng(0), EXACT_LASER)
    ahead = len(scan.angles) // 2
    assert scan.angles[ahead] == 0.0
    assert scan.ranges[ahead] == pytest.approx(3.0, abs=1e-12)
    assert scan.labels[ahead] == seg_index(m, "east")
    assert scan.ranges[0] == pytest.approx(2.0, abs=1e-12)  # right: the south wall
    assert scan.ranges[-1] == pytest.approx(4.0, abs=1e-12)  # left: the north wall


def test_every_beam_ends_on_its_labelled_wall_and_nothing_is_nearer(office):
    rng = np.random.default_rng(11)
    ws, we = wall_segments(office)
    for _ in range(5):
        pose = random_free_pose(office, rng)
        scan = laser_scan(office, pose, rng, EXACT_LASER)
        hit = scan.labels >= 0
        phi = pose[2] + scan.angles[hit]
        u = np.column_stack((np.cos(phi), np.sin(phi)))
        ends = pose[:2] + scan.ranges[hit, None] * u
        lab = scan.labels[hit]
        on_wall = min_distance_each(ends, office.starts[lab], office.ends[lab])
        assert on_wall.max() < 1e-9
        short = pose[:2] + (scan.ranges[hit, None] - 1e-6) * u
        origin = np.repeat(pose[None, :2], len(short), axis=0)
        assert not segments_cross(origin, short, ws, we).any()  # no wall before the hit


def min_distance_each(points, starts, ends):
    """Distance from point i to segment i."""
    e = ends - starts
    u = np.clip(np.einsum("ij,ij->i", points - starts, e) / np.einsum("ij,ij->i", e, e), 0, 1)
    return np.hypot(*(points - starts - u[:, None] * e).T)


def test_laser_no_return_dropout_and_spurious():
    m = box_map()
    rng = np.random.default_rng(1)
    short = LaserConfig(sigma=0.0, dropout_prob=0.0, spurious_prob=0.0, max_range=2.5)
    scan = laser_scan(m, (5.0, 3.0, 0.0), rng, short)
    far = scan.labels == NO_RETURN
    assert far.any() and np.all(scan.ranges[far] == 2.5) and np.all(scan.ranges[~far] < 2.5)
    noisy = LaserConfig(dropout_prob=0.2, spurious_prob=0.2)
    scans = [laser_scan(m, (5.0, 3.0, 0.0), rng, noisy) for _ in range(20)]
    labels = np.concatenate([s.labels for s in scans])
    ranges = np.concatenate([s.ranges for s in scans])
    assert 0.12 < np.mean(labels == NO_RETURN) < 0.22
    assert 0.15 < np.mean(labels == -4) < 0.25
    assert np.all(ranges[labels == NO_RETURN] == noisy.max_range)


def test_painted_lines_invisible_to_laser_but_seen_by_camera(robocup):
    pose = (-1.5, 0.3, 0.0)
    scan = laser_scan(robocup, pose, np.random.default_rng(0), EXACT_LASER)
    painted = np.flatnonzero(robocup.kinds == "line")
    assert not np.isin(scan.labels, painted).any()
    ahead = len(scan.angles) // 2
    # Straight through the centre line and the goal mouth to the back of the goal at x = 5.1.
    assert scan.ranges[ahead] == pytest.approx(6.6, abs=1e-12)
    assert scan.labels[ahead] == seg_index(robocup, "goal_e_back")

    frame = camera_points(robocup, pose, np.random.default_rng(0), EXACT_CAMERA)
    centre = frame.labels == seg_index(robocup, "c")
    assert centre.sum() > 20
    np.testing.assert_allclose(frame.points[centre, 0], 1.5, atol=1e-9)


def test_camera_sees_wall_bottoms_within_its_sector(robocup):
    cfg = EXACT_CAMERA
    frame = camera_points(robocup, (2.0, 0.0, 0.0), np.random.default_rng(0), cfg)
    d = np.hypot(*frame.points.T)
    bearing = np.arctan2(frame.points[:, 1], frame.points[:, 0])
    assert np.all((d >= cfg.min_range - 1e-9) & (d <= cfg.max_range + 1e-9))
    assert np.all(np.abs(bearing) <= math.radians(cfg.fov_deg) / 2 + 1e-9)
    walls = frame.labels[frame.labels >= 0]
    assert np.isin(seg_index(robocup, "d"), walls)  # the penalty line at x = 3.25
    assert robocup.is_wall[walls].any()  # and the wall x = 4.5 behind it (2.5 m away)
    # Spacing along a line is the configured density.
    on_d = np.sort(frame.points[frame.labels == seg_index(robocup, "d"), 1])
    np.testing.assert_allclose(np.diff(on_d), cfg.point_spacing, atol=1e-9)


def test_camera_noise_grows_with_distance():
    m = SegmentMap([[0, 0], [10, 0], [10, 6], [0, 6], [5, 1]],
                   [[10, 0], [10, 6], [0, 6], [0, 0], [5, 5]],
                   kinds=["wall", "wall", "wall", "wall", "line"])
    cfg = CameraConfig(false_points=0.0, sigma0=0.01, k=0.02)
    rng = np.random.default_rng(5)

    def spread(x0: float) -> float:  # scatter across the painted line x = 5, seen from x0
        xs = [camera_points(m, (x0, 3.0, 0.0), rng, cfg) for _ in range(20)]
        return float(np.std(np.concatenate([f.points[f.labels == 4, 0] for f in xs])))

    near, far = spread(4.0), spread(1.5)  # 1 m and 3.5 m from the line
    assert near == pytest.approx(0.01 + 0.02 * 1.0**2, rel=0.2)
    assert far > 5 * near


def test_false_points_in_view():
    cfg = CameraConfig(false_points=5.0)
    rng = np.random.default_rng(2)
    labels = np.concatenate([camera_points(box_map(), (1, 3, 0), rng, cfg).labels
                             for _ in range(200)])
    assert np.sum(labels == -4) / 200 == pytest.approx(5.0, rel=0.15)


# ------------------------------------------------------------------------------ occlusion
def test_moving_obstacle_occludes_laser_and_camera(robocup):
    pose = (-1.5, 0.0, 0.0)
    disc = np.array([[-0.5, 0.0, 0.25]])
    scan = laser_scan(robocup, pose, np.random.default_rng(0), EXACT_LASER, obstacles=disc)
    ahead = len(scan.angles) // 2
    assert scan.ranges[ahead] == pytest.approx(0.75, abs=1e-12)
    assert scan.labels[ahead] == MOVING_OBSTACLE
    hidden = np.abs(scan.angles) < math.asin(0.25 / 1.0) - 1e-3
    assert np.all(scan.labels[hidden] == MOVING_OBSTACLE)

    frame = camera_points(robocup, pose, np.random.default_rng(0), EXACT_CAMERA, obstacles=disc)
    centre = frame.points[frame.labels == seg_index(robocup, "c")]
    # The disc (1 m ahead, r = 0.25) shadows |y| < 1.5·tan(asin(0.25)) ≈ 0.387 on the line x = 1.5.
    assert np.all(np.abs(centre[:, 1]) > 0.38)
    assert np.any(np.abs(centre[:, 1]) < 0.6)
    rim = frame.points[frame.labels == MOVING_OBSTACLE]
    assert len(rim) > 5 and np.all(rim[:, 0] < 1.0 + 1e-9)  # only the near half of the disc


def test_clutter_is_seen_by_laser_but_not_in_the_map(robocup):
    box = np.array([[1.0, -0.5, 1.0, 0.5]])
    scan = laser_scan(robocup, (0.5, 0.0, 0.0), np.random.default_rng(0), EXACT_LASER,
                      clutter=box)
    assert scan.labels[len(scan.angles) // 2] == -3
    assert scan.ranges[len(scan.angles) // 2] == pytest.approx(0.5)


# ------------------------------------------------------------------------------ odometry
def test_odometry_drifts_metres_over_five_minutes():
    run = simulate(no_laser("robocup-laser"))
    assert run.odom_t[-1] - run.odom_t[0] == pytest.approx(300.0)
    np.testing.assert_allclose(run.odom_pose[0], (576.5, 0.1, -2.26))
    drift = np.hypot(*(run.odom_in_map()[-1, :2] - run.odom_truth[-1, :2]))
    assert drift > 1.0


def test_error_free_odometry_increments_equal_true_ones():
    run = simulate(no_laser("office-laser", odometry=NO_ODOM_ERROR, duration=120.0))
    np.testing.assert_allclose(increments(run.odom_pose), increments(run.odom_truth),
                               rtol=0, atol=1e-9)


def test_systematic_error_alone_turns_the_heading():
    odo = OdometryConfig(wheel_noise=0.0, left_scale_error=0.02, right_scale_error=-0.01)  # −0.075
    run = simulate(no_laser("robocup-laser", odometry=odo, duration=60.0))
    true_inc, odo_inc = increments(run.odom_truth), increments(run.odom_pose)
    ds = np.hypot(true_inc[:, 0], true_inc[:, 1])
    moving = ds > 1e-4
    # Straight-line rate −(0.02 + 0.01)/0.4 rad per metre; turning adds its own term.
    err = wrap_angle(odo_inc[:, 2] - true_inc[:, 2])
    straight = moving & (np.abs(true_inc[:, 2]) < 1e-6)
    np.testing.assert_allclose(err[straight] / ds[straight], -0.075, rtol=1e-3)


def test_kidnap_moves_truth_not_odometry():
    kid = Kidnap(t=10.0, dx=0.4, dy=-0.3, dtheta_deg=25.0)
    cfg = no_laser("robocup-laser", odometry=NO_ODOM_ERROR, duration=20.0, kidnaps=[kid])
    run = simulate(cfg)
    k = int(np.flatnonzero(run.kidnapped)[0])
    assert run.odom_t[k + 1] == pytest.approx(10.0)
    true_inc, odo_inc = increments(run.odom_truth), increments(run.odom_pose)
    others = np.ones(len(true_inc), dtype=bool)
    others[k] = False
    np.testing.assert_allclose(true_inc[others], odo_inc[others], atol=1e-9)
    jump = run.odom_truth[k + 1] - run.odom_truth[k]
    assert abs(wrap_angle(jump[2]) - math.radians(25.0)) < 0.05
    assert np.hypot(jump[0] - 0.4, jump[1] + 0.3) < 0.05  # plus one step of driving
    assert np.hypot(*odo_inc[k, :2]) < 0.05  # the wheels saw one ordinary step


# ------------------------------------------------------------------------------ motion
@pytest.mark.parametrize("name", ["office-laser", "robocup-laser"])
def test_true_path_never_crosses_a_wall(name):
    run = simulate(no_laser(name))
    assert not path_crosses_walls(run.map, run.odom_truth).any()
    ws, we = wall_segments(run.map)
    assert min_distance(run.odom_truth[:, :2], ws, we).min() > 0.4
    speed = np.hypot(*np.diff(run.odom_truth[:, :2], axis=0).T) * run.config.odom_rate
    assert speed.max() <= run.config.robot.v_max + 1e-9
    assert speed.mean() > 0.3  # it does not get stuck


def test_office_loop_keeps_half_a_metre_from_walls(office):
    w = np.asarray(OFFICE_LOOP + OFFICE_LOOP[:1])
    ws, we = wall_segments(office)
    assert segment_segment_distance(w[:-1], w[1:], ws, we).min() >= 0.5 - 1e-9


def test_obstacles_stay_in_free_space():
    run = simulate(scenario_preset("office-laser", duration=60.0))
    ws, we = wall_segments(run.map)
    for d in range(run.scan_obstacles.shape[1]):
        track = run.scan_obstacles[:, d]
        assert min_distance(track, ws, we).min() >= run.obstacle_radii[d]
        assert not path_crosses_walls(run.map, track).any()


def test_kidnap_through_walls_back_is_an_error():
    kid = Kidnap(t=5.0, dx=0.0, dy=3.0)  # from the corridor into the room north of it
    with pytest.raises(SimulationError, match="crosses a wall"):
        simulate(no_laser("office-laser", duration=30.0, kidnaps=[kid]))


def test_random_free_pose_is_reachable_and_clear(office):
    rng = np.random.default_rng(0)
    poses = np.array([random_free_pose(office, rng) for _ in range(300)])
    ws, we = wall_segments(office)
    assert min_distance(poses[:, :2], ws, we).min() >= 0.5
    inside = (poses[:, 0] > 0) & (poses[:, 0] < 26) & (poses[:, 1] > 0) & (poses[:, 1] < 12)
    assert inside.all()
    in_alcove = (poses[:, 0] < 1.2) & (poses[:, 1] > 9.0) & (poses[:, 1] < 10.5)
    beyond_diagonal = poses[:, 1] > 9.5 + (26.0 - poses[:, 0]) * 2.5 / 4.0
    assert not in_alcove.any() and not beyond_diagonal.any()


# ------------------------------------------------------------------------------ helpers
@pytest.mark.parametrize("map_name", ["robocup.yaml", "office.yaml"])
@pytest.mark.parametrize("sensor", [LaserConfig(), CameraConfig()], ids=["laser", "camera"])
def test_obstacles_near_reach_a_fifth_of_the_points(map_name, sensor):
    m = SegmentMap.from_yaml(MAPS_DIR / map_name)
    rng = np.random.default_rng(7)
    fractions = []
    while len(fractions) < 10:
        pose = random_free_pose(m, rng)
        try:
            discs = place_obstacles_near(m, pose, rng, 3, sensor=sensor)
        except ValueError:  # facing a wall: no room in view
            continue
        assert len(discs) == 3
        if isinstance(sensor, LaserConfig):
            labels = laser_scan(m, pose, rng, sensor, obstacles=discs).labels
        else:
            labels = camera_points(m, pose, rng, sensor, obstacles=discs).labels
        fractions.append(obstacle_fraction(labels))
    assert min(fractions) >= 0.2


# ------------------------------------------------------------------------------ events
def test_events_in_arrival_order_with_latency():
    cfg = scenario_preset("robocup-camera", duration=4.0)
    run = simulate(cfg)
    events = list(run.events())
    keys = [e.arrival if isinstance(e, PointSet) else e.t for e in events]
    assert keys == sorted(keys)
    sets = [e for e in events if isinstance(e, PointSet)]
    assert len(sets) == len(run.cam_t) == 21
    assert all(e.arrival == pytest.approx(e.t + 0.2) for e in sets)
    assert sum(isinstance(e, Truth) for e in events) == len(run.cam_t)
    assert sum(isinstance(e, Odometry) for e in events) == len(run.odom_t)


def test_laser_events_carry_the_scans():
    run = simulate(scenario_preset("robocup-laser", duration=2.0))
    scans = [e for e in run.events() if isinstance(e, Scan)]
    assert len(scans) == 21
    assert scans[3].max_range == 10.0 and scans[3].ranges.shape == (361,)
    np.testing.assert_array_equal(scans[3].ranges, run.ranges[3])


# ------------------------------------------------------------------------------ files
def _records(path, keyword):
    return [line.split() for line in path.read_text().splitlines() if line.startswith(keyword)]


def test_carmen_tum_and_scenario_files(tmp_path):
    run = simulate(scenario_preset("robocup-laser", duration=5.0))
    paths = write_run(run, tmp_path, laser_message="FLASER")
    odom = _records(paths["log"], "ODOM ")
    laser = _records(paths["log"], "FLASER ")
    assert len(odom) == len(run.odom_t) and {len(r) for r in odom} == {10}
    assert len(laser) == len(run.scan_t) == 51
    assert {len(r) for r in laser} == {361 + 11} and {r[1] for r in laser} == {"361"}
    fields = np.array([r[2:-3] for r in laser], dtype=float)
    np.testing.assert_allclose(fields[:, :361], run.ranges, atol=5e-4)
    np.testing.assert_allclose(fields[:, 361:364], run.scan_odom, atol=1e-6)
    np.testing.assert_allclose(fields[:, 364:367], run.scan_odom, atol=1e-6)
    stamps = [float(line.split()[-1]) for line in paths["log"].read_text().splitlines()
              if not line.startswith("#")]
    assert stamps == sorted(stamps)

    gt = np.loadtxt(paths["gt"])
    assert gt.shape == (len(run.scan_t), 8)
    np.testing.assert_allclose(gt[:, 1:3], run.scan_truth[:, :2], atol=1e-6)
    np.testing.assert_allclose(gt[:, 6] ** 2 + gt[:, 7] ** 2, 1.0, atol=1e-8)
    np.testing.assert_allclose(2 * np.arctan2(gt[:, 6], gt[:, 7]),
                               np.unwrap(run.scan_truth[:, 2]), atol=1e-6)

    assert len(SegmentMap.from_yaml(paths["map"])) == len(run.map)
    again = simulate(load_scenario(paths["scenario"]))
    np.testing.assert_array_equal(again.ranges, run.ranges)
    assert not list(tmp_path.glob(".*tmp"))  # no temporary files left behind


def test_non_180_degree_laser_is_written_as_robotlaser1(tmp_path):
    cfg = scenario_preset("robocup-laser", duration=2.0)
    cfg = cfg.model_copy(update={"laser": LaserConfig(fov_deg=240.0, n_beams=481)})
    run = simulate(cfg)
    paths = write_run(run, tmp_path)
    assert not _records(paths["log"], "FLASER")
    recs = _records(paths["log"], "ROBOTLASER1 ")
    assert len(recs) == 21 and {len(r) for r in recs} == {481 + 24}
    r = recs[0]
    assert float(r[2]) == pytest.approx(-math.radians(120.0), abs=1e-6)
    assert float(r[3]) == pytest.approx(math.radians(240.0), abs=1e-6)
    assert float(r[4]) == pytest.approx(math.radians(0.5), abs=1e-6)
    assert int(r[8]) == 481 and r[9 + 481] == "0"


def test_camera_points_round_trip_and_bad_lines_warn(tmp_path):
    run = simulate(scenario_preset("robocup-camera", duration=3.0))
    path = write_run(run, tmp_path)["camera"]
    sets = list(read_camera_points(path))
    assert len(sets) == len(run.cam_t)
    for s, pts, t in zip(sets, run.cam_points, run.cam_t, strict=True):
        assert s.t == pytest.approx(t) and s.arrival == pytest.approx(t + 0.2)
        np.testing.assert_allclose(s.points, pts, atol=5e-5)
    with open(path, "a") as f:
        f.write("POINTS 9.0 9.2 2 1.0 2.0 3.0\nPOINTS x y 0\nGARBAGE\n")
    with pytest.warns(UserWarning, match=r"camera\.points:\d+"):
        again = list(read_camera_points(path))
    assert len(again) == len(sets)


# ------------------------------------------------------------------------------ configs
def test_config_errors_name_the_problem():
    with pytest.raises(pydantic.ValidationError, match="n_beam"):
        LaserConfig(n_beam=10)
    with pytest.raises(ValueError, match="unknown scenario preset"):
        scenario_preset("mars")
    cfg = scenario_preset("office-laser", seed=2, duration=12.0)
    assert cfg.seed == 2 and cfg.duration == 12.0 and cfg.clutter.count == 8
    assert ScenarioConfig.model_validate(cfg.model_dump(mode="json")) == cfg


def test_default_log_states_its_beam_layout_and_reads_back_exactly(tmp_path):
    """The default ROBOTLASER1 carries start angle and resolution: the reader recovers the
    simulator's beams exactly, whatever FLASER convention it assumes."""
    from fusion.io import open_log

    run = simulate(scenario_preset("robocup-laser", duration=2.0))
    write_run(run, tmp_path)
    assert _records(tmp_path / "log.carmen", "ROBOTLASER1 ") and not _records(
        tmp_path / "log.carmen", "FLASER ")
    events, _ = open_log(tmp_path)
    scans = [e for e in events if isinstance(e, Scan)]
    assert len(scans) == len(run.scan_t)
    np.testing.assert_allclose(scans[0].angles, run.angles, atol=1e-8)
    np.testing.assert_allclose(scans[5].ranges, run.ranges[5], atol=5e-4)

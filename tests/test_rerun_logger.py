"""The Rerun logger: same interface as the no-op logger, every stage in the recording, every scan
on the ``scan`` timeline, serving on localhost only.

Scans are simulated on the RoboCup map (points on its walls seen from known poses) and pushed
through ``localize_scan``, so the logger sees real corrections; the ``.rrd`` is read back with
``rerun.chunk.RrdReader``.
"""

from __future__ import annotations

import inspect
import math
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

from fusion.ekf import UpdateOutcome
from fusion.estimate import Estimate
from fusion.rerun_columns import PATH_PIECE, PathPieces
from fusion.rerun_logger import RerunLogger
from fusion.rerun_scans import HoughRow, hough_columns
from fusion.rerun_serve import SERVE_HOST, free_port, web_viewer_command
from fusion.rerun_view import (
    LineColours,
    batch_point_rows,
    covariance_ellipse,
    hough_marks,
    line_palette,
    point_rows,
)
from fusion.visualize import NullLogger
from houghloc import ScanCorrection, SegmentMap, localize_scan
from houghloc.geometry import ray_segment_distances

N_SCANS = 12
COV = np.diag([0.02**2, 0.03**2, np.radians(1.0) ** 2])


def wall_scan(m: SegmentMap, pose: np.ndarray, n_beams: int = 361, sigma: float = 0.005,
              seed: int = 0) -> np.ndarray:
    """Robot-frame points where the beams of a 360° laser first hit a wall."""
    rng = np.random.default_rng(seed)
    bearing = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    d = np.column_stack((np.cos(bearing + pose[2]), np.sin(bearing + pose[2])))
    walls = np.flatnonzero(m.is_wall)
    r = ray_segment_distances(pose, d, m.starts[walls], m.ends[walls]).min(axis=1)
    r = r + rng.normal(0.0, sigma, n_beams)
    keep = np.isfinite(r)
    return np.column_stack((r * np.cos(bearing), r * np.sin(bearing)))[keep]


@pytest.fixture(scope="module")
def drive(robocup: SegmentMap) -> list[tuple[float, np.ndarray, np.ndarray, ScanCorrection,
                                             Estimate]]:
    """(t, true pose, points, correction, estimate) of a short drive across the field."""
    out = []
    for i in range(N_SCANS):
        t = 0.1 * i
        truth = np.array([-2.0 + 0.25 * i, 0.5 * np.sin(0.3 * i), 0.2 + 0.05 * i])
        points = wall_scan(robocup, truth, seed=i)
        fix = localize_scan(points, robocup, truth + np.array([0.04, -0.03, 0.01]))
        innovation = fix.pose - truth
        outcome = UpdateOutcome(True, 1.5, 3, innovation)
        out.append((t, truth, points, fix, Estimate(t, fix.pose, COV, "accepted", fix, outcome)))
    return out


def replay(logger: RerunLogger, robocup: SegmentMap, drive: list) -> None:
    logger.log_map(robocup)
    for i, (t, truth, points, fix, estimate) in enumerate(drive):
        logger.log_odometry(t, truth + np.array([10.0, -5.0, 0.0]))  # an arbitrary odometry frame
        logger.log_scan(t, i, "laser", points, fix, estimate)
        logger.log_truth(t, truth)  # after the scan: errors must not depend on the order
    logger.log_state(drive[-1][0], "collecting", "ambiguous correspondence")
    logger.log_hypotheses(drive[-1][0], np.array([[0.0, 0.0, 0.0], [1.0, 1.0, np.pi]]),
                          np.array([0.9, 0.4]))
    logger.close()


def chunks_by_entity(path: Path) -> dict[str, list[pa.RecordBatch]]:
    out: dict[str, list[pa.RecordBatch]] = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        out[chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())
    return out


def values(batches: list[pa.RecordBatch], column: str) -> np.ndarray:
    """Every instance of one component over the temporal chunks of an entity, in one array."""
    return np.concatenate([b.column(column).flatten().to_numpy(zero_copy_only=False)
                           for b in batches if column in b.schema.names])


def scan_indices(batches: list[pa.RecordBatch]) -> list[int]:
    return sorted(i for b in batches if "scan" in b.schema.names
                  for i in b.column("scan").to_pylist())


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory, robocup: SegmentMap,
              drive: list) -> dict[str, list[pa.RecordBatch]]:
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    replay(RerunLogger(path, recording_name="test drive"), robocup, drive)
    return chunks_by_entity(path)


def test_same_methods_and_signatures_as_the_null_logger() -> None:
    def public(cls: type) -> dict[str, inspect.Signature]:
        methods = inspect.getmembers(cls, inspect.isfunction)
        return {name: inspect.signature(f) for name, f in methods if not name.startswith("_")}

    assert public(RerunLogger) == public(NullLogger)


def test_recording_holds_every_stage(recording: dict[str, list[pa.RecordBatch]]) -> None:
    expected = [
        "world/map/walls", "world/map/lines", "world/scan/points", "world/robot/estimate",
        "world/robot/covariance", "world/robot/truth", "world/path/estimate/recent",
        "world/path/odometry/recent", "world/path/truth/recent", "hough/accumulator", "hough/peaks",
        "hough/references", "hough/matches", "metrics/innovation/x", "metrics/innovation/y",
        "metrics/innovation/theta", "metrics/nis", "metrics/sigma/x", "metrics/sigma/y",
        "metrics/sigma/theta", "metrics/error/position", "metrics/error/heading",
        "metrics/matches", "log/state", "global/hypotheses",
    ]
    missing = [e for e in expected if e not in recording]
    assert not missing, f"not in the recording: {missing}"


def test_every_scan_is_on_the_scan_timeline(recording: dict[str, list[pa.RecordBatch]]) -> None:
    assert scan_indices(recording["world/scan/points"]) == list(range(N_SCANS))
    for entity in ("world/robot/estimate", "hough/peaks", "metrics/sigma/x"):
        assert scan_indices(recording[entity]) == list(range(N_SCANS)), entity


def test_errors_for_every_scan_whatever_the_order_of_truth_and_scan(
        recording: dict[str, list[pa.RecordBatch]], drive: list) -> None:
    assert scan_indices(recording["metrics/error/position"]) == list(range(N_SCANS))
    errors = values(recording["metrics/error/position"], "Scalars:scalars")
    expected = [np.hypot(*(est.pose[:2] - truth[:2])) for _, truth, _, _, est in drive]
    assert np.allclose(np.sort(errors), np.sort(expected), atol=1e-9)


def test_map_and_static_data_are_logged_once(
        recording: dict[str, list[pa.RecordBatch]]) -> None:
    walls = recording["world/map/walls"]
    assert len(walls) == 1 and "scan" not in walls[0].schema.names


def test_matched_points_take_their_map_lines_colour(
        recording: dict[str, list[pa.RecordBatch]], drive: list) -> None:
    colours = values(recording["world/scan/points"], "Points2D:colors").astype(np.uint32)
    fix = drive[0][3]
    assert fix.matches is not None and len(fix.matches) >= 2
    palette = line_palette(int(fix.matched_map_lines.max()) + 1)
    packed = (palette[:, 0].astype(np.uint32) << 24 | palette[:, 1].astype(np.uint32) << 16
              | palette[:, 2].astype(np.uint32) << 8 | palette[:, 3])
    assert np.isin(packed[fix.matched_map_lines], colours).all()


def test_walls_in_one_colour_and_each_scans_matched_walls_in_their_lines_colours(
        recording: dict[str, list[pa.RecordBatch]], robocup: SegmentMap, drive: list) -> None:
    """Walls are drawn in one colour; at each scan the walls of the matched map lines are drawn
    over them, each in its line's colour, the colour of the points on it."""
    walls = values(recording["world/map/walls"], "LineStrips2D:colors")
    assert len(np.unique(walls)) == 1
    matched = recording["world/map/matched"]
    assert scan_indices(matched) == list(range(N_SCANS))
    is_wall = np.asarray(robocup.kinds) == "wall"
    line_of = np.asarray(robocup.line_of_segment)[is_wall]
    counts = [len(s) for b in matched for s in b.column("LineStrips2D:strips").to_pylist()]
    expected = [int(np.isin(line_of, fix.matched_map_lines).sum()) for *_, fix, _ in drive]
    assert counts == expected and min(expected) >= 2
    palette = line_palette(int(line_of.max()) + 1)
    packed = (palette[:, 0].astype(np.uint32) << 24 | palette[:, 1].astype(np.uint32) << 16
              | palette[:, 2].astype(np.uint32) << 8 | palette[:, 3])
    drawn = values(matched, "LineStrips2D:colors").astype(np.uint32)
    first = drive[0][3].matched_map_lines
    assert np.array_equal(drawn[:expected[0]], packed[line_of[np.isin(line_of, first)]])
    assert walls[0] not in set(packed[first].tolist())  # the highlight stands out


def test_accumulator_every_n_scans(tmp_path: Path, robocup: SegmentMap, drive: list) -> None:
    path = tmp_path / "sparse.rrd"
    replay(RerunLogger(path, accumulator_every=5), robocup, drive)
    recording = chunks_by_entity(path)
    assert scan_indices(recording["hough/accumulator"]) == [0, 5, 10]
    assert scan_indices(recording["hough/peaks"]) == list(range(N_SCANS))


def recorded_images(path: Path, dtype: type, shape: tuple[int, int]) -> list[np.ndarray]:
    """The Hough images of a recording, in scan order, decoded as ``dtype`` pixels."""
    rows = [row for b in chunks_by_entity(path)["hough/accumulator"]
            if "DepthImage:buffer" in b.schema.names
            for row in b.column("DepthImage:buffer").to_pylist()]  # one buffer a row
    return [np.frombuffer(bytes(buffer), dtype=dtype).reshape(shape) for [buffer] in rows]


def test_the_hough_image_is_the_accumulator(tmp_path: Path, robocup: SegmentMap,
                                            drive: list) -> None:
    """The recorded image is the votes cell for cell: 16 bits for 361-beam scans; 8 bits when
    the first scan has at most 255 points (a cell gets at most one vote per point), where a
    later scan with more votes in a cell is drawn saturated at 255."""
    path = tmp_path / "wide.rrd"
    replay(RerunLogger(path), robocup, drive)
    votes = [fix.accumulator for _, _, _, fix, _ in drive]
    assert max(fix.n_points for _, _, _, fix, _ in drive) > 255
    for image, expected in zip(recorded_images(path, np.uint16, votes[0].shape), votes,
                               strict=True):
        np.testing.assert_array_equal(image, expected)
    path = tmp_path / "narrow.rrd"
    logger = RerunLogger(path)
    logger.log_map(robocup)
    expected = []
    for i, (t, truth, points, fix, estimate) in enumerate(drive[:3]):
        if i < 2:  # a 180-beam laser's scans, then a dense one: 600 points on one wall
            points = wall_scan(robocup, truth, n_beams=180, seed=i)
        else:
            points = np.column_stack((np.full(600, 2.0), np.linspace(-3.0, 3.0, 600)))
        fix = localize_scan(points, robocup, truth)
        logger.log_scan(t, i, "laser", points, fix, estimate)
        expected.append(np.minimum(fix.accumulator, 255))
    logger.close()
    assert fix.accumulator.max() > 255  # the saturation is seen
    for image, votes_seen in zip(recorded_images(path, np.uint8, expected[0].shape), expected,
                                 strict=True):
        np.testing.assert_array_equal(image, votes_seen)


def test_unix_clock_becomes_a_timestamp_timeline(tmp_path: Path, robocup: SegmentMap,
                                                 drive: list) -> None:
    path = tmp_path / "wall-clock.rrd"
    logger = RerunLogger(path, accumulator_every=0)
    t, _, points, fix, estimate = drive[0]
    logger.log_scan(1.7e9 + t, 0, "laser", points, fix, estimate)
    logger.close()
    batch = chunks_by_entity(path)["world/scan/points"][0]
    assert pa.types.is_timestamp(batch.schema.field("time").type)


def test_loggers_are_independent_of_each_other_and_of_the_global_recording(
        tmp_path: Path, robocup: SegmentMap, drive: list) -> None:
    import rerun as rr

    a, b = RerunLogger(tmp_path / "a.rrd"), RerunLogger(tmp_path / "b.rrd")
    assert rr.get_global_data_recording() is None
    replay(a, robocup, drive[:2])
    replay(b, robocup, drive[:4])
    assert scan_indices(chunks_by_entity(tmp_path / "a.rrd")["world/scan/points"]) == [0, 1]
    assert scan_indices(chunks_by_entity(tmp_path / "b.rrd")["world/scan/points"]) == [0, 1, 2,
                                                                                          3]


def test_recording_carries_the_default_blueprint(tmp_path: Path) -> None:
    path = tmp_path / "empty.rrd"
    RerunLogger(path).close()
    assert len(RrdReader(path).blueprints()) == 1


def test_without_a_sink_the_recording_stays_in_memory(robocup: SegmentMap, drive: list) -> None:
    logger = RerunLogger()
    replay(logger, robocup, drive[:2])
    assert logger.memory is not None and logger.memory.num_msgs() > 0


@settings(max_examples=200, deadline=None)
@given(theta=st.lists(st.floats(0.0, 2 * math.pi, exclude_max=True), min_size=1, max_size=8),
       rho=st.floats(-0.2, 20.0), step_deg=st.sampled_from([1.0, 3.0]))
def test_hough_marks_fall_in_their_cells(theta: list[float], rho: float, step_deg: float) -> None:
    """A peak or a reference is drawn in the accumulator cell of its (θ, ρ): row round(θ/δθ)
    (cell 0 straddles θ = 0, so θ just below 2π is drawn in it), column (ρ − ρ_min)/δρ; and a
    match between two θ across 0 ≡ 2π is drawn short, not across the whole image."""
    step, rho_step, rho_min = math.radians(step_deg), 0.1, -0.2
    n_rows = round(2 * math.pi / step)
    angles = np.array(theta)
    rhos = np.full(len(angles), rho)
    across = np.array([0.3 * step, 2 * math.pi - 0.3 * step])  # one line, two sides of 0
    peaks, refs, ends = hough_marks(step, rho_step, rho_min, np.concatenate((angles, across[:1])),
                                    np.append(rhos, rho), np.concatenate((angles, across[1:])),
                                    np.append(rhos, rho), np.array([len(angles)]),
                                    np.array([len(angles)]))
    cells = np.round(angles / step).astype(int) % n_rows
    away = np.abs(angles / step - np.round(angles / step)) < 0.499  # not at a cell's edge
    for drawn in (peaks[:-1], refs[:-1]):
        assert np.array_equal(np.floor(drawn[away, 1]).astype(int), cells[away])
        assert np.allclose(drawn[:, 0], (rho - rho_min) / rho_step)
    assert np.floor(refs[-1, 1]) == 0  # θ just below 2π: the cell around θ = 0
    assert np.allclose(ends[0, 0], peaks[-1])
    assert abs(ends[0, 1, 1] - ends[0, 0, 1]) == pytest.approx(0.6, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 40), n_lines=st.integers(1, 6))
def test_each_point_takes_its_first_matched_lines_colour(seed: int, n: int, n_lines: int) -> None:
    """Colour rows: the map line of the first match whose scan line holds the point, else −2
    for a point on some line, else −1 (the law written with NumPy's masks)."""
    rng = np.random.default_rng(seed)
    members = rng.random((n, n_lines)) < 0.3
    matched = rng.choice(n_lines, size=rng.integers(0, n_lines + 1), replace=False)
    map_lines = rng.integers(0, 50, size=len(matched))
    expected = np.where(members.any(axis=1), -2, -1)
    if len(matched):
        mine = members[:, matched]
        owned = mine.any(axis=1)
        expected[owned] = map_lines[mine.argmax(axis=1)[owned]]
    assert np.array_equal(point_rows(members, matched.astype(np.int64),
                                     map_lines.astype(np.int64)), expected)


def test_covariance_ellipse_is_the_95_percent_contour() -> None:
    ellipse = covariance_ellipse([1.0, 2.0], np.diag([0.04, 0.01]))
    d = ellipse - [1.0, 2.0]
    assert np.allclose((d**2 / [0.04, 0.01]).sum(axis=1), 5.991464547107979)


@given(st.floats(1e-4, 1.0), st.floats(0.0, 1.0), st.floats(-math.pi, math.pi))
def test_covariance_ellipse_of_any_covariance(sigma: float, ratio: float, angle: float) -> None:
    """Any orientation, down to a degenerate covariance (a corridor's): a closed polyline whose
    points lie on the 95 % contour, along the axes the eigendecomposition gives, within the
    radius clamp."""
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    variances = np.array([sigma**2, (ratio * sigma) ** 2])
    cov = rotation @ np.diag(variances) @ rotation.T
    ellipse = covariance_ellipse([3.0, -1.0], cov)
    assert ellipse.shape == (37, 2) and np.allclose(ellipse[0], ellipse[-1])
    d = (ellipse - [3.0, -1.0]) @ rotation  # in the covariance's own axes
    radii = np.sqrt(variances * 5.991464547107979)
    assert np.hypot(d[:, 0], d[:, 1]).max() == pytest.approx(radii[0], rel=1e-9)  # major axis
    assert np.abs(d[:, 1]).max() <= radii[1] * (1 + 1e-9) + 1e-7 * radii[0]  # rounding of C
    if ratio > 1e-3:
        assert np.allclose(((d / radii) ** 2).sum(axis=1), 1.0, atol=1e-6)
    far = covariance_ellipse([0.0, 0.0], np.diag([1e6, 1e-6]))
    assert np.abs(far).max() == pytest.approx(20.0)  # MAX_ELLIPSE_RADIUS


def test_serving_binds_localhost_only(tmp_path: Path) -> None:
    """The gRPC server really listens on 127.0.0.1 (read from /proc); the web viewer is a child
    process whose command line is checked, not launched (slow, and it would open a port)."""
    assert SERVE_HOST == "127.0.0.1"
    command = web_viewer_command("rerun+http://127.0.0.1:9876/proxy", 9090)
    assert command[command.index("--bind") + 1] == "127.0.0.1"
    port = free_port()
    logger = RerunLogger(tmp_path / "served.rrd", serve=True, grpc_port=port, web_port=None)
    try:
        assert logger.grpc_url == f"rerun+http://127.0.0.1:{port}/proxy"
        tables = [Path("/proc/net/tcp"), Path("/proc/net/tcp6")]
        if not tables[0].exists():
            pytest.skip("no /proc/net/tcp to read listening sockets from")
        listening = [line.split()[1] for table in tables if table.exists()
                     for line in table.read_text().splitlines()[1:]
                     if line.split()[3] == "0A"]  # state LISTEN
        mine = [addr for addr in listening if int(addr.rsplit(":", 1)[1], 16) == port]
        assert mine == [f"0100007F:{port:04X}"]  # 127.0.0.1 only, no 0.0.0.0 nor [::]
    finally:
        logger.close()


def test_the_web_viewer_ends_with_houghloc_however_it_ends(tmp_path: Path) -> None:
    """A process serving the viewer is killed outright (no close(), no handler runs): its
    `rerun --serve-web` child must not outlive it, holding the port."""
    script = (
        "import sys, time\n"
        "from fusion.rerun_logger import RerunLogger\n"
        f"logger = RerunLogger(None, serve=True, grpc_port={free_port()}, "
        f"web_port={free_port()})\n"
        "print(logger._web_viewer.pid, flush=True)\n"
        "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        line = parent.stdout.readline() if parent.stdout else ""
        if not line.strip():
            pytest.skip("the Rerun web viewer could not be started here")
        child = int(line)
        assert Path(f"/proc/{child}").exists()
    finally:
        parent.kill()
        parent.wait(timeout=10)
    deadline = time.monotonic() + 10
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(child), "the web viewer outlived houghloc"


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for its reaper has ended)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_points_off_every_line_are_grey(tmp_path: Path, robocup: SegmentMap,
                                        drive: list) -> None:
    t, truth, points, _, estimate = drive[0]
    clutter = np.random.default_rng(7).uniform(-0.4, 0.4, (30, 2))  # a person near the robot
    scan = np.vstack((points, clutter))
    fix = localize_scan(scan, robocup, truth)
    path = tmp_path / "clutter.rrd"
    logger = RerunLogger(path, accumulator_every=0)
    logger.log_map(robocup)
    logger.log_scan(t, 0, "laser", scan, fix, estimate)
    logger.close()
    colours = values(chunks_by_entity(path)["world/scan/points"], "Points2D:colors")
    grey = np.uint32(100 << 24 | 100 << 16 | 100 << 8 | 255)  # UNMATCHED
    assert len(colours) == len(scan)
    assert (colours[-len(clutter):] == grey).mean() > 0.9
    assert (colours[: len(points)] != grey).mean() > 0.75  # corners and short pieces: grey


def test_a_cli_run_records_every_stage_of_every_scan(tmp_path: Path) -> None:
    """`houghloc run` on a simulated log (a laser among moving robots): the .rrd holds every
    stage, the ground truth and the manager's state; every scan is on the `scan` timeline, as
    many as the trajectory has lines."""
    from fusion.cli import main
    from fusion.sim import scenario_preset, simulate, write_run

    run = simulate(scenario_preset("robocup-laser", seed=4, duration=6.0))
    write_run(run, tmp_path / "sim")
    out = tmp_path / "out"
    start = [str(v) for v in run.odom_truth[0]]
    code = main(["run", "--map", str(tmp_path / "sim" / "map.yaml"), "--log",
                 str(tmp_path / "sim"), "--out", str(out), "--no-progress",
                 "--initial-pose", *start])
    assert code == 0
    entities = chunks_by_entity(out / "run.rrd")
    for name in ("world/map/walls", "world/map/lines", "world/scan/points", "world/robot/estimate",
                 "world/path/truth/recent", "hough/accumulator", "hough/matches", "metrics/nis",
                 "metrics/error/position", "log/state"):
        assert any(e == name or e.startswith(name) for e in entities), name
    n_scans = len((out / "trajectory.tum").read_text().splitlines())
    assert scan_indices(entities["world/scan/points"]) == list(range(n_scans))
    # the truth path follows the run, a pose per scan (not the file's last pose drawn once)
    drawn = 0  # poses drawn at the end: the last row of every entity of the path
    for entity, batches in entities.items():
        if entity.startswith("world/path/truth/"):
            rows = [row for batch in batches if "LineStrips2D:strips" in batch.schema.names
                    for row in batch.column("LineStrips2D:strips").to_pylist()]
            drawn += sum(len(strip) - 1 for strip in rows[-1])  # blocks share their ends
    assert drawn >= n_scans - 3, (drawn, n_scans)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 40 * PATH_PIECE))
def test_a_path_drawn_from_its_entities_latest_values_is_the_whole_path(n: int) -> None:
    """What the viewer shows after pose k (each entity's latest polyline, older levels first)
    is exactly poses 0..k, with at most 2 + log2(k / PATH_PIECE) entities."""
    path = PathPieces("p")
    poses = np.column_stack((np.arange(n, dtype=float), np.arange(n, dtype=float) ** 2))
    latest: dict[str, np.ndarray] = {}
    for k, pose in enumerate(poses):
        latest.update(path.append(pose))
        if k in (0, n // 2, n - 1):
            levels = sorted((e for e in latest if not e.endswith("recent")),
                            key=lambda e: -int(e.split("/")[-1]))
            blocks = [latest[e] for e in levels if len(latest[e])] + [latest["p/recent"]]
            drawn = np.vstack([blocks[0]] + [b[1:] for b in blocks[1:]])
            np.testing.assert_array_equal(drawn, poses[: k + 1])
            assert len(latest) <= 2 + np.log2(max(k / PATH_PIECE, 1.0))


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 6 * PATH_PIECE), cuts=st.lists(st.integers(1, 3 * PATH_PIECE), max_size=8))
def test_a_path_extended_in_batches_is_drawn_as_pose_by_pose(n: int, cuts: list[int]) -> None:
    """Poses added a batch at a time give, row for row, the newest piece and the older pieces'
    changes that adding them one at a time gives."""
    poses = np.column_stack((np.arange(n, dtype=float), np.sin(np.arange(n, dtype=float))))
    one, batched = PathPieces("p"), PathPieces("p")
    expected = []
    for k, pose in enumerate(poses):
        *older, (_, recent) = one.append(pose)
        expected.append((k, recent, older))
    got, start = [], 0
    for size in [*cuts, n]:
        if start >= n:
            break
        strips, updates = batched.extend(poses[start:start + size])
        for i, strip in enumerate(strips.to_pylist()):
            older = [(entity, line) for k, entity, line in updates if k == i]
            got.append((start + i, np.asarray(strip, dtype=float).reshape(-1, 2), older))
        start += size
    assert len(got) == n
    for (k, recent, older), (k2, strip, older2) in zip(expected, got, strict=True):
        assert k == k2
        np.testing.assert_allclose(strip, recent, atol=1e-4)  # float32 in the recording
        assert [e for e, _ in older] == [e for e, _ in older2]
        for (_, a), (_, b) in zip(older, older2, strict=True):
            np.testing.assert_array_equal(a, b)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_scans=st.integers(1, 6))
def test_the_points_of_many_scans_are_coloured_as_each_alone(seed: int, n_scans: int) -> None:
    rng = np.random.default_rng(seed)
    scans = []
    for _ in range(n_scans):
        n, k = int(rng.integers(0, 30)), int(rng.integers(0, 5))
        members = rng.random((n, k)) < 0.3
        m = int(rng.integers(0, k + 1))
        matched = rng.permutation(k)[:m].astype(np.int64)
        scans.append((members, matched, rng.integers(0, 40, m).astype(np.int64)))
    joined = batch_point_rows(
        np.concatenate([s[0].reshape(-1) for s in scans]),
        np.array([s[0].shape[0] for s in scans], np.int64),
        np.array([s[0].shape[1] for s in scans], np.int64),
        np.concatenate([s[1] for s in scans]), np.concatenate([s[2] for s in scans]),
        np.array([len(s[1]) for s in scans], np.int64))
    alone = [point_rows(*scan) for scan in scans]
    np.testing.assert_array_equal(joined, np.concatenate(alone))


@pytest.mark.parametrize("grids", [((0.05, 0.1, -20.0), (0.05, 0.1, -20.0)),
                                   ((0.05, 0.1, -20.0), (0.02, 0.05, -10.0))])
def test_the_hough_marks_of_a_batch_are_each_scans_own(grids: tuple) -> None:
    """Marks drawn for a batch (one grid, or a grid per scan) are those of each scan alone,
    its match indices shifted to its own lines and references."""
    rng = np.random.default_rng(3)
    marks = []
    for row, grid in enumerate((*grids, None)):
        n_lines, n_refs = (0, 0) if grid is None else (4 + row, 6)
        pairs = rng.permutation(min(n_lines, n_refs))[:3]
        marks.append(HoughRow(row, grid, rng.uniform(0, 6.28, n_lines), rng.uniform(-5, 5, n_lines),
                              rng.uniform(0, 6.28, n_refs), rng.uniform(-5, 5, n_refs),
                              rng.integers(0, 9, n_refs), pairs.astype(np.int64),
                              rng.permutation(n_refs)[:len(pairs)].astype(np.int64)))
    columns = hough_columns(marks, LineColours())
    alone = [hough_marks(*m.grid, m.line_theta, m.line_rho, m.ref_theta, m.ref_rho,
                         m.match_line, m.match_ref) for m in marks if m.grid is not None]
    np.testing.assert_allclose(columns["peaks"], np.concatenate([a[0] for a in alone]))
    np.testing.assert_allclose(columns["references"], np.concatenate([a[1] for a in alone]))
    ends = np.asarray(columns["matches"].to_pylist(), dtype=float).reshape(-1, 2, 2)
    np.testing.assert_allclose(ends, np.concatenate([a[2] for a in alone]), rtol=1e-6)
    assert columns["peak_lengths"].tolist() == [4, 5, 0]
    assert columns["match_lengths"].tolist() == [3, 3, 0]

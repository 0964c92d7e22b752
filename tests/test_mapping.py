"""The segment-map builder: occupancy grids, ROS maps, wall extraction and the whole pipeline."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import require_data

from fusion.mapping import (
    GridMapError,
    OccupancyGrid,
    build_map,
    endpoint_coverage,
    extract_segments,
    load_ros_map,
    occupancy_from_log,
    point_segment_distance,
    read_reference_scans,
    refit_to_endpoints,
    scan_endpoints,
)
from houghloc import SegmentMap
from houghloc.segment_map import MapError

RES = 0.05
INTEL_SLICE = 150


# ------------------------------------------------------------------------------------------------
# A synthetic room: 8 m × 5 m (cell centres), a 0.9 m door in the bottom wall, seen from inside
# and through the door.


def _room(angle_deg: float = 0.0) -> tuple[OccupancyGrid, list[tuple[np.ndarray, np.ndarray]],
                                           np.ndarray]:
    """Grid, true wall segments (through cell centres) and the door's centre, in metres."""
    origin = np.array([-1.0, -2.0]) - RES / 2  # true walls through cell centres
    corners = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 5.0], [0.0, 5.0]])
    door = (3.0, 3.9)  # along the bottom wall
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    rot = np.array([[c, -s], [s, c]])
    pivot = np.array([4.0, 2.5])

    def world(p: np.ndarray) -> np.ndarray:
        return (np.atleast_2d(p) - pivot) @ rot.T + pivot

    def pixels(p: np.ndarray) -> np.ndarray:  # cell-centre coordinates, OpenCV fixed point ×16
        return np.round(((world(p) - origin) / RES - 0.5) * 16).astype(np.int32)

    shape = (200, 240)
    occupied = np.zeros(shape, np.uint8)
    free = np.zeros(shape, np.uint8)
    cv2.fillPoly(free, [pixels(corners)], 1, shift=4)
    outside_door = np.array([[door[0], 0.0], [door[1], 0.0], [door[1], -1.5], [door[0], -1.5]])
    cv2.fillPoly(free, [pixels(outside_door)], 1, shift=4)
    walls = [
        (corners[0], np.array([door[0], 0.0])),
        (np.array([door[1], 0.0]), corners[1]),
        (corners[1], corners[2]),
        (corners[2], corners[3]),
        (corners[3], corners[0]),
    ]
    for a, b in walls:
        cv2.line(occupied, *[tuple(int(v) for v in pixels(p)[0]) for p in (a, b)], 1,
                 lineType=cv2.LINE_8, shift=4)
    truth = [(world(a)[0], world(b)[0]) for a, b in walls]
    door_centre = world(np.array([sum(door) / 2, 0.0]))[0]
    grid = OccupancyGrid.from_masks(occupied.astype(bool), free.astype(bool), RES, tuple(origin))
    return grid, truth, door_centre


def _nearest_segment_error(segment_map: SegmentMap, a: np.ndarray, b: np.ndarray) -> float:
    """Largest endpoint distance between the true segment (a, b) and the best extracted one."""
    errors = np.maximum(
        np.minimum(np.linalg.norm(segment_map.starts - a, axis=1),
                   np.linalg.norm(segment_map.ends - a, axis=1)),
        np.minimum(np.linalg.norm(segment_map.starts - b, axis=1),
                   np.linalg.norm(segment_map.ends - b, axis=1)),
    )
    return float(errors.min())


@pytest.mark.parametrize("angle_deg", [0.0, 17.0])
def test_room_walls_within_one_cell_and_door_open(angle_deg: float) -> None:
    grid, truth, door_centre = _room(angle_deg)
    m = extract_segments(grid, min_length=0.5, name="room")
    assert len(m) == len(truth), f"expected one segment per wall, got {len(m)}"
    for a, b in truth:
        assert _nearest_segment_error(m, a, b) <= 1.0 * RES + 1e-9
    # Every wall cell lies within one cell of a segment.
    wall_points, _ = grid.occupied_points()
    assert np.all(point_segment_distance(m, wall_points, RES) <= RES)
    # The doorway stays open: nothing within 0.3 m of its centre.
    assert np.isinf(point_segment_distance(m, door_centre[None], 0.3)[0])
    assert m.ids == [f"w{i}" for i in range(len(m))]
    assert set(m.kinds) == {"wall"} and m.name == "room"
    # Both pieces of the wall with the door lie on one line (one Hough point).
    assert m.n_lines == len(truth) - 1


def test_occluded_gap_is_bridged_but_a_seen_through_gap_is_not() -> None:
    grid, truth, _door = _room()
    occupied = grid.occupied.copy()
    rows, cols = grid.world_to_cell(np.array([[2.0, 5.0], [2.6, 5.0]]))
    occupied[rows[0], cols[0]:cols[1]] = False  # a 0.6 m hole in the top wall, never seen through
    free = grid.free.copy()
    free[rows[0], cols[0]:cols[1]] = False
    hidden = OccupancyGrid.from_masks(occupied, free, RES, grid.origin)
    m = extract_segments(hidden)
    assert len(m) == len(truth)
    free[rows[0] - 5:rows[0] + 6, cols[0]:cols[1]] = True  # now the hole is a doorway
    seen = OccupancyGrid.from_masks(occupied, free, RES, grid.origin)
    assert len(extract_segments(seen)) == len(truth) + 1


def _lines(*segments: tuple[tuple[float, float], tuple[float, float]]):
    from fusion.mapping.lines import lines_from_ends

    a = np.array([s[0] for s in segments], dtype=float)
    b = np.array([s[1] for s in segments], dtype=float)
    return lines_from_ends(a, b)


def test_near_duplicate_lines_of_one_face_are_merged_onto_one_line() -> None:
    from fusion.mapping.pieces import merge_duplicates

    tilt = math.tan(math.radians(2.0))
    lines = _lines(((0.0, 0.0), (6.0, 0.0)),             # a wall, seen from +y
                   ((1.0, 0.05), (3.0, 0.05 + 2 * tilt)),  # the same face again: 5 cm, 2° off
                   ((7.0, 0.04), (8.0, 0.04)),           # beyond a door, 4 cm off the line
                   ((1.0, -0.12), (4.0, -0.12)),         # the wall's other face, seen from −y
                   ((1.0, 0.4), (4.0, 0.4)))             # a different wall, 40 cm away
    up, down = (0.0, 1.0), (0.0, -1.0)
    facing = np.array([up, up, up, down, up])
    merged = merge_duplicates(lines, facing, math.radians(6.0), 0.15, 2.0, 0.25)
    m = SegmentMap(merged.starts, merged.ends)
    assert len(m) == 4  # the duplicate joined the wall; the door still splits it
    assert m.n_lines == 3  # wall (both pieces on one line), its other face, the far wall
    on_wall = np.abs(merged.point[:, 1]) < 0.1
    assert on_wall.sum() == 2
    d = merged.direction[on_wall]
    assert np.all(np.abs(d[:, 1]) < math.sin(math.radians(1.0)))  # the long wall dominates
    extents = sorted(zip(merged.starts[on_wall, 0], merged.ends[on_wall, 0], strict=True))
    assert extents[0][0] == pytest.approx(0.0, abs=0.02)
    assert extents[0][1] == pytest.approx(6.0, abs=0.02)
    assert extents[1][0] == pytest.approx(7.0, abs=0.02)
    assert extents[1][1] == pytest.approx(8.0, abs=0.02)
    # Nothing to merge: unchanged.
    single = merge_duplicates(_lines(((0.0, 0.0), (1.0, 0.0))), np.array([up]),
                               math.radians(6.0), 0.15, 2.0, 0.25)
    assert len(single) == 1


def _wall_endpoints(a: np.ndarray, b: np.ndarray, n: int, noise: float,
                    rng: np.random.Generator) -> np.ndarray:
    t = rng.uniform(0.0, 1.0, n)[:, None]
    return a + t * (b - a) + rng.normal(0.0, noise, (n, 2))


def _line_angle_offset(segment_map: SegmentMap, i: int) -> tuple[float, float]:
    """Direction (degrees, mod 180) and signed offset of the line of segment i from the origin."""
    a, b = segment_map.starts[i], segment_map.ends[i]
    d = (b - a) / np.linalg.norm(b - a)
    return math.degrees(math.atan2(d[1], d[0])) % 180.0, float(a[0] * -d[1] + a[1] * d[0])


def test_refit_to_endpoints_moves_lines_onto_the_seen_faces() -> None:
    rng = np.random.default_rng(4)
    # The true faces: y = 1 (a wall with a doorway: two pieces of one line) and x = 3.
    endpoints = np.vstack((
        _wall_endpoints(np.array([0.0, 1.0]), np.array([2.0, 1.0]), 800, 0.01, rng),
        _wall_endpoints(np.array([2.9, 1.0]), np.array([6.0, 1.0]), 1200, 0.01, rng),
        _wall_endpoints(np.array([3.0, 1.5]), np.array([3.0, 5.0]), 1500, 0.01, rng),
        # clutter 12 cm in front of the x = 3 face, along part of it
        _wall_endpoints(np.array([2.88, 2.0]), np.array([2.88, 3.0]), 150, 0.01, rng),
    ))
    tilt = math.tan(math.radians(3.0))
    grid_map = SegmentMap(  # as a grid fit leaves them: 4 cm off, turned by 3°
        np.array([[0.0, 1.04], [2.9, 1.04 + 2.9 * tilt], [2.96, 1.5], [8.0, 8.0]]),
        np.array([[2.0, 1.04 + 2.0 * tilt], [6.0, 1.04 + 6.0 * tilt], [2.96 + 3.5 * tilt, 5.0],
                  [9.0, 8.0]]),
        kinds=["wall"] * 4)
    assert grid_map.n_lines == 3
    m = refit_to_endpoints(grid_map, endpoints)
    assert len(m) == 4 and m.n_lines == 3  # the doorway's two pieces still share one line
    assert m.ids == ["w0", "w1", "w2", "w3"] and np.all(np.diff(m.lengths) <= 1e-12)
    for i in range(len(m)):
        angle, offset = _line_angle_offset(m, i)
        mid = 0.5 * (m.starts[i] + m.ends[i])
        if mid[1] > 7.0:  # no endpoint supports it: it stays where it was
            assert np.allclose(m.starts[i], [8.0, 8.0]) and np.allclose(m.ends[i], [9.0, 8.0])
        elif abs(angle - 90.0) < 10.0:  # the x = 3 face, despite the clutter in front of it
            assert abs(angle - 90.0) < 0.2 and abs(abs(offset) - 3.0) < 0.005
        else:  # y = 1
            assert min(angle, 180.0 - angle) < 0.2 and abs(abs(offset) - 1.0) < 0.005


def test_refit_to_endpoints_will_not_turn_a_line_onto_other_structure() -> None:
    rng = np.random.default_rng(5)
    # the only endpoints near the segment lie on a line 8° from it: they are something else
    endpoints = _wall_endpoints(np.array([0.0, 0.0]), np.array([3.0, 3.0 * math.tan(
        math.radians(8.0))]), 2000, 0.005, rng)
    before = SegmentMap(np.array([[0.0, 0.2]]), np.array([[3.0, 0.2]]), kinds=["wall"])
    after = refit_to_endpoints(before, endpoints)
    assert np.allclose(after.starts, before.starts) and np.allclose(after.ends, before.ends)


def test_refit_to_endpoints_refuses_painted_lines() -> None:
    """A laser returns nothing from a painted line: refitting one to endpoints would move it
    onto whatever wall is near, so such a map is refused by name."""
    painted = SegmentMap(np.array([[0.0, 0.0]]), np.array([[3.0, 0.0]]), kinds=["line"],
                         name="pitch")
    with pytest.raises(ValueError, match=r"'pitch'.*only a map of walls"):
        refit_to_endpoints(painted, np.zeros((50, 2)))


def test_empty_grid_is_an_error() -> None:
    empty = OccupancyGrid.from_masks(np.zeros((20, 20), bool), np.ones((20, 20), bool), RES)
    with pytest.raises(ValueError, match="occupied"):
        extract_segments(empty)


# ------------------------------------------------------------------------------------------------
# ROS map_server maps


def _write_ros_map(folder: Path, yaml_text: str | None = None, negate: int = 0) -> Path:
    image = np.full((30, 40), 205, np.uint8)  # unknown
    image[5:25, 5:35] = 254  # free
    image[0, 3] = 0  # occupied: top row of the image = highest y
    if negate:
        image = 255 - image
    cv2.imwrite(str(folder / "map.pgm"), image)
    path = folder / "map.yaml"
    path.write_text(yaml_text if yaml_text is not None else (
        "image: map.pgm\nresolution: 0.1\norigin: [-2.0, -1.5, 0.0]\n"
        f"negate: {negate}\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"))
    return path


@pytest.mark.parametrize("negate", [0, 1])
def test_ros_map_loads_with_origin_and_resolution(tmp_path: Path, negate: int) -> None:
    grid = load_ros_map(_write_ros_map(tmp_path, negate=negate))
    assert grid.resolution == pytest.approx(0.1)
    assert grid.origin == pytest.approx((-2.0, -1.5))
    assert grid.shape == (30, 40)
    assert grid.extent == pytest.approx((-2.0, 2.0, -1.5, 1.5))
    # The image's top-left pixel region is the grid's highest row: y up, as in ROS.
    (row, col), = np.argwhere(grid.occupied)
    assert (row, col) == (29, 3)
    assert grid.cell_centres(np.array([row]), np.array([col]))[0] == pytest.approx((-1.65, 1.45))
    assert grid.free.sum() == 20 * 30
    assert np.isnan(grid.probability[0, 0])
    assert np.array_equal(grid.image(), np.where(grid.occupied, 0, np.where(grid.free, 254, 205))[
        ::-1])


@pytest.mark.parametrize(
    ("text", "field", "problem"),
    [
        ("image: map.pgm\norigin: [0, 0, 0]\n", "resolution", "missing"),
        ("image: map.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n", "resolution", "positive"),
        ("image: map.pgm\nresolution: abc\norigin: [0, 0, 0]\n", "resolution", "number"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0]\n", "origin", "[x, y, yaw]"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0.5]\n", "origin", "rotated"),
        ("image: nothere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "image", "not found"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 2\n", "negate", "0 or 1"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n", "mode", "trinary"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n",
         "free_thresh", "free < occupied"),
        ("image: [map.pgm\n", None, "not valid YAML"),
        ("- a\n- list\n", None, "expected a mapping"),
    ],
)
def test_bad_ros_yaml_names_file_field_and_problem(
    tmp_path: Path, text: str, field: str | None, problem: str,
) -> None:
    path = _write_ros_map(tmp_path, text)
    with pytest.raises(GridMapError) as info:
        load_ros_map(path)
    message = str(info.value)
    assert str(path) in message and problem in message
    if field is not None:
        assert f"'{field}'" in message
    assert isinstance(info.value, MapError)  # callers handling map errors catch it too


def test_ros_map_missing_file(tmp_path: Path) -> None:
    with pytest.raises(GridMapError, match="file not found"):
        load_ros_map(tmp_path / "none.yaml")


def test_ros_map_not_an_image(tmp_path: Path) -> None:
    path = _write_ros_map(tmp_path)
    (tmp_path / "map.pgm").write_text("not an image")
    with pytest.raises(GridMapError, match="not a readable image"):
        load_ros_map(path)


def test_build_map_from_ros_map(tmp_path: Path) -> None:
    grid, truth, _ = _room()
    cv2.imwrite(str(tmp_path / "room.pgm"), grid.image())
    ox, oy = grid.origin
    (tmp_path / "room.yaml").write_text(
        f"image: room.pgm\nresolution: {RES}\norigin: [{ox}, {oy}, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    m = build_map(tmp_path / "room.yaml", tmp_path / "out" / "room-map.yaml")
    assert len(m) == len(truth)
    assert SegmentMap.from_yaml(tmp_path / "out" / "room-map.yaml").name == "room-map"
    assert (tmp_path / "out" / "room-map.png").stat().st_size > 0


# ------------------------------------------------------------------------------------------------
# The Intel lab, first scans of the corrected log


@pytest.fixture(scope="module")
def intel_slice() -> tuple[Path, list]:
    path = require_data("intel", "intel.gfs.log")
    return path, read_reference_scans(path, max_scans=INTEL_SLICE)


def test_intel_occupancy_grid(intel_slice: tuple[Path, list], tmp_path: Path) -> None:
    path, scans = intel_slice
    grid = occupancy_from_log(path, max_scans=INTEL_SLICE)
    assert grid.resolution == RES and grid.hit_count is not None
    endpoints = scan_endpoints(scans)
    rows, cols = grid.world_to_cell(endpoints)
    assert grid.inside(rows, cols).all()
    assert grid.hit_count.sum() == len(endpoints)
    # Most endpoints land on occupied cells; the robot's own positions are free.
    assert grid.occupied[rows, cols].mean() > 0.9
    poses = np.array([s.reference for s in scans])
    prow, pcol = grid.world_to_cell(poses[:, :2])
    assert grid.free[prow, pcol].mean() > 0.9
    grid.to_png(tmp_path / "grid.png")
    assert cv2.imread(str(tmp_path / "grid.png")).shape[:2] == grid.shape


def test_intel_slice_map(intel_slice: tuple[Path, list], tmp_path: Path) -> None:
    path, scans = intel_slice
    out = tmp_path / "intel.yaml"
    m = build_map(path, out, max_scans=INTEL_SLICE)
    assert 20 <= len(m) <= 400
    reloaded = SegmentMap.from_yaml(out)
    assert len(reloaded) == len(m) and reloaded.name == "intel"
    assert np.allclose(reloaded.starts, m.starts) and np.allclose(reloaded.ends, m.ends)
    assert (tmp_path / "intel.png").stat().st_size > 10_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["intel.png", "intel.yaml"]  # no temp
    assert m.lengths.min() >= 0.5
    coverage = endpoint_coverage(m, scan_endpoints(scans), tolerance=0.10)
    assert coverage >= 0.80, f"only {coverage:.1%} of the endpoints within 10 cm of a wall"


def test_raw_log_cannot_be_mapped(tmp_path: Path) -> None:
    log = tmp_path / "raw.log"
    log.write_text("ODOM 0 0 0 0 0 0 1.0 host 1.0\n"
                   "FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 1.1 host 1.1\n"
                   "ODOM 0.1 0 0 0 0 0 1.2 host 1.2\n")
    with pytest.raises(ValueError, match="reference pose"):
        occupancy_from_log(log)


def test_point_segment_distance_is_exact() -> None:
    m = SegmentMap([[0.0, 0.0]], [[2.0, 0.0]])
    points = np.array([[1.0, 0.05], [2.03, 0.04], [-0.2, 0.0], [1.0, -0.099]])
    d = point_segment_distance(m, points, 0.1)
    assert d[0] == pytest.approx(0.05)
    assert d[1] == pytest.approx(0.05)
    assert np.isinf(d[2])
    assert d[3] == pytest.approx(0.099)
    assert endpoint_coverage(m, points, 0.1) == pytest.approx(0.75)

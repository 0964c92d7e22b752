"""Segment maps from corrected logs or occupancy grids (``houghloc map build``, DESIGN §3.4, §6).

The pipeline, one function per stage:

1. **Occupancy grid.** :func:`occupancy_from_log` projects every scan of a corrected CARMEN log
   from its reference pose (``Scan.reference``). Hits are counted per cell with ``np.bincount``;
   free space is the scan's polygon (the sensor plus the beam ends), filled by ``cv2.fillPoly`` —
   one C call per scan instead of one ray cast per beam. A cell is occupied when it was hit often
   enough and hits make up a large enough share of its observations, which removes people walking
   by. :func:`load_ros_map` reads a ROS ``map_server`` map instead.
2. **Candidates.** OpenCV's line segment detector (LSD) runs on the image of occupied cells. LSD
   is deterministic, has sub-pixel output and no accumulator thresholds to tune (unlike
   ``HoughLinesP``, whose output on thick, noisy walls is a bundle of overlapping, slightly
   rotated fragments). On a wall one to three cells thick it reports the two edges of the wall,
   half a cell outside the cell centres — so every candidate is only a hypothesis:
3. **Refinement.** Each candidate is refitted by total least squares to the occupied cells near
   it (their hit centroids when the grid has them, else the cell centres): first within σ + 1.5
   cells, then within 1.5 cells of the refitted line, which pulls both edges onto the wall. A
   refit that turns the line by more than 5° was a blob of clutter and is dropped.
4. **Collinear grouping.** Candidates, longest first, join a group whose line they match (angle
   within a few degrees, both ends within 1.5 cells) and whose extent is at most a door away;
   a group is one wall line. Duplicates of one wall face fall into one group here.
5. **Segments.** Each occupied cell is assigned to the nearest group line (so a cell supports one
   wall only), each line is refitted to its cells, and the cells are split into runs along the
   line: a gap splits the run when it is longer than ``bridge_gap``, or when it holds free space
   (a door opening seen through) or is longer than ``occlusion_gap``. Pieces must be solid (most
   cell-steps along them hold a cell) and have free space along one side (a wall face is seen
   through free space; a line through clutter has none). Runs shorter than ``min_length`` are
   dropped. Segments of one group lie exactly on one line, so the segment map
   merges them into one Hough point.
6. **Duplicates.** A thick or slightly bent wall can still come out as two or more lines a few
   centimetres and degrees apart, each holding part of its cells; the localizer would find two
   map lines in one observed wall's gate. Lines of one face (within ``duplicate_angle`` and
   ``duplicate_offset``, free space on the same side) are merged onto their length-weighted
   fit; the two faces of a thin wall stay apart.

:func:`build_map` chains the stages and writes the map YAML and a PNG preview (segments over the
grid, metre axes). :func:`endpoint_coverage` scores a map against scan endpoints.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fusion.events import Scan
from fusion.io import open_log
from fusion.io.files import atomic_write_bytes, atomic_write_text
from houghloc.geometry import ranges_to_points, transform_points
from houghloc.segment_map import MapError, SegmentMap

# ROS map_server conventions (image values and thresholds).
ROS_UNKNOWN, ROS_FREE, ROS_OCCUPIED = 205, 254, 0
DEFAULT_MAX_RANGE = 30.0
"""Beams longer than this (metres) give no hit: far endpoints carry the heading error × range."""

_POLY_SHIFT = 4  # fillPoly fixed-point bits: vertices at 1/16 cell
_CANDIDATE_BLUR_CELLS = 1.5  # Gaussian σ before line detection, in cells
_FREE_SIDE_OFFSETS = (3, 4, 5, 6)  # cells from a wall where its observed side must be free
_MAX_REFIT_TURN_COS = math.cos(math.radians(5.0))  # a refit may turn a detection this much


class GridMapError(MapError):
    """An occupancy-grid file that cannot be used; the message names the file, field and problem."""


# ================================================================================================
# Occupancy grid
# ================================================================================================


@dataclass(frozen=True)
class OccupancyGrid:
    """A 2-D occupancy grid in the map frame.

    Row ``i``, column ``j`` is the cell ``[ox + j·res, ox + (j+1)·res) × [oy + i·res, …)``: rows
    grow with y (the array is *not* an image; :meth:`image` flips it), and ``origin = (ox, oy)`` is
    the outer corner of cell (0, 0), as in ROS ``map_server``.

    ``probability``: P(occupied) per cell, NaN where never observed. ``occupied``/``free``: the
    decided cells (neither = unknown). ``hit_count``/``pass_count``: observations behind a grid
    built from scans. ``hit_centroid``: mean world position of the hits in each cell (rows × cols
    × 2, NaN without hits) — wall fits use it instead of cell centres, which removes up to half a
    cell of quantisation from axis-aligned walls.
    """

    probability: NDArray[np.float32]
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]
    hit_count: NDArray[np.int32] | None = None
    pass_count: NDArray[np.int32] | None = None
    hit_centroid: NDArray[np.float64] | None = None

    @classmethod
    def from_masks(cls, occupied: NDArray[np.bool_], free: NDArray[np.bool_], resolution: float,
                   origin: tuple[float, float] = (0.0, 0.0)) -> OccupancyGrid:
        """A grid from decided cells (rows grow with y); the rest is unknown."""
        occupied = np.asarray(occupied, dtype=bool)
        free = np.asarray(free, dtype=bool) & ~occupied
        probability = np.full(occupied.shape, np.nan, dtype=np.float32)
        probability[free] = 0.0
        probability[occupied] = 1.0
        return cls(probability, occupied, free, float(resolution),
                   (float(origin[0]), float(origin[1])))

    @property
    def shape(self) -> tuple[int, int]:
        return self.probability.shape  # type: ignore[return-value]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the grid in metres (matplotlib's ``extent``)."""
        rows, cols = self.shape
        ox, oy = self.origin
        return ox, ox + cols * self.resolution, oy, oy + rows * self.resolution

    def cell_centres(self, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.float64]:
        """World coordinates (N×2) of the centres of cells (rows[k], cols[k])."""
        ox, oy = self.origin
        return np.column_stack(
            (ox + (cols + 0.5) * self.resolution, oy + (rows + 0.5) * self.resolution)
        )

    def world_to_cell(self, xy: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(rows, cols) of the cells containing world points (may lie outside the grid)."""
        ox, oy = self.origin
        cols = np.floor((xy[:, 0] - ox) / self.resolution).astype(np.intp)
        rows = np.floor((xy[:, 1] - oy) / self.resolution).astype(np.intp)
        return rows, cols

    def inside(self, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.bool_]:
        n_rows, n_cols = self.shape
        return (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)

    def occupied_points(self) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Representative points of the occupied cells (hit centroid, else centre) and their flat
        cell indices."""
        flat = np.flatnonzero(self.occupied)
        rows, cols = np.divmod(flat, self.shape[1])
        points = self.cell_centres(rows, cols)
        if self.hit_centroid is not None:
            centroid = self.hit_centroid.reshape(-1, 2)[flat]
            have = np.isfinite(centroid).all(axis=1)
            points[have] = centroid[have]
        return points, flat

    def image(self) -> NDArray[np.uint8]:
        """The grid as a ROS-style greyscale image, y up: occupied black, free white, unknown
        grey."""
        img = np.full(self.shape, ROS_UNKNOWN, dtype=np.uint8)
        img[self.free] = ROS_FREE
        img[self.occupied] = ROS_OCCUPIED
        return np.ascontiguousarray(img[::-1])

    def to_png(self, path: str | Path) -> Path:
        """Write :meth:`image` as a PNG (atomically)."""
        ok, data = cv2.imencode(".png", self.image())
        if not ok:
            raise OSError(f"{path}: OpenCV could not encode the grid as PNG")
        return atomic_write_bytes(path, data.tobytes())


# ------------------------------------------------------------------------------------------------
# From a corrected log
# ------------------------------------------------------------------------------------------------


def read_reference_scans(path: str | Path, max_scans: int | None = None) -> list[Scan]:
    """The scans of a corrected log that carry a reference pose, in file order (the first
    ``max_scans`` of them when given). Raises :class:`fusion.io.LogError` for an unusable file and
    ``ValueError`` when no scan has a reference pose (a raw log cannot be mapped)."""
    events, _stats = open_log(path)
    scans = (e for e in events if isinstance(e, Scan) and e.reference is not None)
    selected = list(islice(scans, max_scans)) if max_scans is not None else list(scans)
    if not selected:
        raise ValueError(f"{path}: no scan with a reference pose (is it a corrected log?)")
    return selected


def scan_endpoints(scans: Iterable[Scan], max_range: float = DEFAULT_MAX_RANGE) -> NDArray:
    """World endpoints (N×2) of all returns shorter than ``max_range``, at the reference poses."""
    chunks = [
        transform_points(scan.reference, ranges_to_points(
            scan.ranges, scan.angles, max_range=min(max_range, scan.max_range)))
        for scan in scans
    ]
    return np.concatenate(chunks) if chunks else np.empty((0, 2))


def occupancy_from_log(
    path: str | Path,
    resolution: float = 0.05,
    max_range: float = DEFAULT_MAX_RANGE,
    *,
    max_scans: int | None = None,
    min_hits: int = 1,
    occupied_ratio: float = 0.2,
    free_clearance: float = 0.1,
) -> OccupancyGrid:
    """Occupancy grid of a corrected CARMEN log (scans projected from ``Scan.reference``).

    ``max_range``: returns beyond it give no hit, and free space only up to it. A cell is occupied
    when hit at least ``min_hits`` times and hits are at least ``occupied_ratio`` of its
    observations (hits + passes); free when passed and not occupied with few hits. Free space
    keeps ``free_clearance`` from the scan polygon's edges: the reference poses are a few
    centimetres off, and a wall placed by one scan must not be erased by the next one's free
    space (coverage of the scans by the extracted walls grows by 2–4 points from 0 to 0.1 m on
    the three real logs). ``max_scans`` takes only the first scans (short slices for tests).
    """
    scans = read_reference_scans(path, max_scans)
    return occupancy_from_scans(scans, resolution, max_range, min_hits=min_hits,
                                occupied_ratio=occupied_ratio, free_clearance=free_clearance)


def occupancy_from_scans(
    scans: Sequence[Scan],
    resolution: float = 0.05,
    max_range: float = DEFAULT_MAX_RANGE,
    *,
    min_hits: int = 1,
    occupied_ratio: float = 0.2,
    free_clearance: float = 0.1,
) -> OccupancyGrid:
    """Occupancy grid of scans with reference poses; see :func:`occupancy_from_log`."""
    if resolution <= 0 or max_range <= 0:
        raise ValueError("resolution and max_range must be positive")
    clearance_cells = max(0, round(free_clearance / resolution))
    beams = [_beam_geometry(scan, max_range) for scan in scans]
    hits = np.concatenate([b.hits for b in beams])
    corners = np.concatenate([np.vstack((b.free_polygon, b.hits)) for b in beams])
    margin = 2 * resolution
    origin = (
        math.floor((corners[:, 0].min() - margin) / resolution) * resolution,
        math.floor((corners[:, 1].min() - margin) / resolution) * resolution,
    )
    n_cols = math.ceil((corners[:, 0].max() + margin - origin[0]) / resolution)
    n_rows = math.ceil((corners[:, 1].max() + margin - origin[1]) / resolution)
    shape = (n_rows, n_cols)

    hit_count, hit_centroid = _count_hits(hits, origin, resolution, shape)
    pass_count = np.zeros(shape, dtype=np.int32)
    for b in beams:  # one fillPoly per scan; the beams inside a scan are never looped over
        _add_free_polygon(pass_count, b, origin, resolution, clearance_cells)

    observed = hit_count + pass_count
    with np.errstate(invalid="ignore", divide="ignore"):
        probability = (hit_count / observed).astype(np.float32)
    occupied = (hit_count >= min_hits) & (probability >= occupied_ratio)
    free = (pass_count > 0) & ~occupied & (probability < 0.5 * occupied_ratio)
    return OccupancyGrid(probability, occupied, free, float(resolution), origin,
                         hit_count, pass_count, hit_centroid)


@dataclass(frozen=True)
class _BeamGeometry:
    """One scan in world coordinates: its hits and the polygon of the space its beams crossed."""

    hits: NDArray[np.float64]
    free_polygon: NDArray[np.float64]


def _beam_geometry(scan: Scan, max_range: float) -> _BeamGeometry:
    r = np.asarray(scan.ranges, dtype=float)
    usable = np.isfinite(r) & (r > 0) & (r < scan.max_range)
    is_hit = usable & (r < max_range)
    # A long return proves free space up to max_range; a "no return" proves nothing (black or
    # glass surfaces also give none), so its vertex collapses onto the sensor.
    r_free = np.where(usable, np.minimum(r, max_range), 0.0)
    a = np.asarray(scan.angles, dtype=float)
    local = np.column_stack((r_free * np.cos(a), r_free * np.sin(a)))
    polygon = transform_points(scan.reference, np.vstack(([0.0, 0.0], local)))
    return _BeamGeometry(hits=polygon[1:][is_hit], free_polygon=polygon)


def _count_hits(
    hits: NDArray[np.float64], origin: tuple[float, float], resolution: float,
    shape: tuple[int, int],
) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    """Hit counts and hit centroids per cell, by ``np.bincount`` on flat cell indices."""
    cols = np.floor((hits[:, 0] - origin[0]) / resolution).astype(np.intp)
    rows = np.floor((hits[:, 1] - origin[1]) / resolution).astype(np.intp)
    flat = rows * shape[1] + cols
    size = shape[0] * shape[1]
    count = np.bincount(flat, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = np.bincount(flat, weights=hits[:, 0], minlength=size) / count
        cy = np.bincount(flat, weights=hits[:, 1], minlength=size) / count
    centroid = np.stack((cx, cy), axis=-1).reshape(*shape, 2)
    return count.astype(np.int32).reshape(shape), centroid


def _add_free_polygon(
    pass_count: NDArray[np.int32], beams: _BeamGeometry, origin: tuple[float, float],
    resolution: float, clearance_cells: int,
) -> None:
    """Add 1 to every cell inside the scan's polygon and ``clearance_cells`` away from its
    edges."""
    # Cell coordinates with cell centres at integers (OpenCV's pixel convention).
    uv = (beams.free_polygon - origin) / resolution - 0.5
    lo = np.maximum(np.floor(uv.min(axis=0)).astype(int) - 1, 0)
    hi = np.minimum(np.ceil(uv.max(axis=0)).astype(int) + 2, pass_count.shape[::-1])
    mask = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), dtype=np.uint8)
    fixed = np.round((uv - lo) * (1 << _POLY_SHIFT)).astype(np.int32)
    cv2.fillPoly(mask, [fixed], 1, lineType=cv2.LINE_8, shift=_POLY_SHIFT)
    # The polygon's edges run along the walls its beams end on (and, at grazing angles, over
    # them): eroding it keeps a scan from voting its own wall cells — and those of the same
    # wall as placed by a slightly different reference pose — free.
    if clearance_cells > 0:
        mask = cv2.erode(mask, np.ones((2 * clearance_cells + 1,) * 2, np.uint8))
    pass_count[lo[1]:hi[1], lo[0]:hi[0]] += mask


# ------------------------------------------------------------------------------------------------
# From a ROS map_server map
# ------------------------------------------------------------------------------------------------


def load_ros_map(yaml_path: str | Path) -> OccupancyGrid:
    """Load a ROS ``map_server`` map: a YAML with ``image``, ``resolution``, ``origin``,
    ``negate``, ``occupied_thresh``, ``free_thresh`` (and optional ``mode``: ``trinary``,
    ``scale`` or ``raw``), and its image (PGM/PNG, path relative to the YAML).

    As in map_server, a pixel value v gives p = (255 − v)/255 (v/255 with ``negate``); p above
    ``occupied_thresh`` is occupied, below ``free_thresh`` free, else unknown. ``raw`` mode reads v
    as a percentage (> 100 unknown). Rotated maps (origin yaw ≠ 0) are refused: the segment map is
    in the map frame. Raises :class:`GridMapError` naming the file, the field and the problem.
    """
    path = Path(yaml_path)
    spec = _read_ros_yaml(path)
    image_path = (path.parent / spec["image"]).resolve()
    pixels = _read_ros_image(path, image_path)
    if spec["mode"] == "raw":
        probability = pixels.astype(np.float32) / 100.0
        probability[pixels > 100] = np.nan
    else:
        probability = pixels.astype(np.float32) / 255.0
        if not spec["negate"]:
            probability = 1.0 - probability
    probability = probability[::-1].copy()  # image rows run top-down; grid rows grow with y
    with np.errstate(invalid="ignore"):
        occupied = probability > spec["occupied_thresh"]
        free = probability < spec["free_thresh"]
    unknown = ~occupied & ~free
    probability[unknown] = np.nan
    ox, oy, _yaw = spec["origin"]
    return OccupancyGrid(probability, occupied, free, spec["resolution"], (ox, oy))


def _read_ros_yaml(path: Path) -> dict:
    def fail(field: str, problem: str) -> GridMapError:
        return GridMapError(f"ROS map {path}: {field!r} {problem}")

    try:
        raw = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise GridMapError(f"ROS map {path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GridMapError(f"ROS map {path}: cannot read ({exc})") from None
    except yaml.YAMLError as exc:
        raise GridMapError(f"ROS map {path}: not valid YAML ({exc})") from None
    if not isinstance(raw, dict):
        raise GridMapError(f"ROS map {path}: expected a mapping with 'image', 'resolution', "
                           f"'origin', got {type(raw).__name__}")
    for field in ("image", "resolution", "origin"):
        if field not in raw:
            raise fail(field, "is missing")
    if not isinstance(raw["image"], str) or not raw["image"]:
        raise fail("image", "must be a file name")
    spec: dict = {"image": raw["image"]}
    spec["resolution"] = _ros_number(raw["resolution"], "resolution", fail)
    if spec["resolution"] <= 0:
        raise fail("resolution", f"must be positive, got {spec['resolution']}")
    origin = raw["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise fail("origin", f"must be [x, y, yaw], got {origin!r}")
    spec["origin"] = tuple(_ros_number(v, "origin", fail) for v in origin)
    if abs(spec["origin"][2]) > 1e-9:
        raise fail("origin", f"has yaw {spec['origin'][2]}: rotated maps are not supported")
    negate = raw.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise fail("negate", f"must be 0 or 1, got {negate!r}")
    spec["negate"] = bool(negate)
    spec["occupied_thresh"] = _ros_number(raw.get("occupied_thresh", 0.65), "occupied_thresh", fail)
    spec["free_thresh"] = _ros_number(raw.get("free_thresh", 0.196), "free_thresh", fail)
    if not 0 <= spec["free_thresh"] < spec["occupied_thresh"] <= 1:
        raise fail("free_thresh", f"and 'occupied_thresh' must satisfy 0 ≤ free < occupied ≤ 1, "
                   f"got {spec['free_thresh']} and {spec['occupied_thresh']}")
    spec["mode"] = raw.get("mode", "trinary")
    if spec["mode"] not in ("trinary", "scale", "raw"):
        raise fail("mode", f"must be trinary, scale or raw, got {spec['mode']!r}")
    return spec


def _ros_number(value: object, field: str, fail) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(field, f"must be a finite number, got {value!r}")
    return float(value)


def _read_ros_image(yaml_path: Path, image_path: Path) -> NDArray[np.uint8]:
    if not image_path.is_file():
        raise GridMapError(f"ROS map {yaml_path}: 'image' {image_path} not found")
    pixels = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.size == 0:
        raise GridMapError(f"ROS map {yaml_path}: 'image' {image_path} is not a readable image")
    if pixels.dtype != np.uint8:
        raise GridMapError(f"ROS map {yaml_path}: 'image' {image_path} has {pixels.dtype} pixels, "
                           "expected 8-bit")
    if pixels.ndim == 3:
        # map_server averages the colour channels (an alpha channel is ignored).
        pixels = pixels[..., :3].mean(axis=2).round().astype(np.uint8)
    return pixels


# ================================================================================================
# Segment extraction
# ================================================================================================


@dataclass(frozen=True)
class _Lines:
    """Fitted lines: a point on each, its unit direction, and an extent [s0, s1] along it
    (measured from ``point``)."""

    point: NDArray[np.float64]
    direction: NDArray[np.float64]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.column_stack((-self.direction[:, 1], self.direction[:, 0]))

    @property
    def starts(self) -> NDArray[np.float64]:
        return self.point + self.s0[:, None] * self.direction

    @property
    def ends(self) -> NDArray[np.float64]:
        return self.point + self.s1[:, None] * self.direction

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0

    def __len__(self) -> int:
        return len(self.point)


def extract_segments(
    grid: OccupancyGrid,
    min_length: float = 0.5,
    *,
    angle_tol: float = math.radians(3.0),
    offset_tol_cells: float = 1.5,
    bridge_gap: float = 0.25,
    occlusion_gap: float = 1.0,
    door_gap: float = 2.0,
    duplicate_offset: float = 0.15,
    duplicate_angle: float = math.radians(6.0),
    name: str = "map",
) -> SegmentMap:
    """Wall segments of an occupancy grid (see the module docstring for the stages).

    ``angle_tol``/``offset_tol_cells``: how far a detection may deviate from a wall line and still
    belong to it. Gaps along a wall shorter than ``bridge_gap`` are closed; gaps up to
    ``occlusion_gap`` are closed only where the grid has no free cell (an occluded stretch of
    wall, not a doorway); longer gaps, and any gap with free space, split the wall into separate
    segments that still share one line when within ``door_gap``. Segments shorter than
    ``min_length`` are dropped. Near-duplicate lines of one wall face (within
    ``duplicate_angle``, both ends within ``duplicate_offset``, free space on the same side, at
    most ``door_gap`` apart along the wall) are merged onto one line. All segments are walls,
    with ids ``w0, w1, …`` (longest first).
    """
    points, _cells = grid.occupied_points()
    if len(points) < 2:
        raise ValueError("the grid has fewer than two occupied cells: no wall to extract")
    res = grid.resolution
    tree = cKDTree(points)
    candidates = _detect_candidates(grid)
    # LSD's edges of the blurred image lie about one σ outside the wall: gather widely first,
    # then again around the refitted line.
    candidates = _refine(candidates, points, tree, (_CANDIDATE_BLUR_CELLS + 1.5) * res, 2 * res)
    candidates = _refine(candidates, points, tree, offset_tol_cells * res, 2 * res)
    groups = _group_collinear(candidates, angle_tol, offset_tol_cells * res, door_gap)
    segments, facing = _segments_on_lines(
        groups, grid, points, tree, support_tol=offset_tol_cells * res,
        bridge_gap=bridge_gap, occlusion_gap=occlusion_gap, min_length=min_length,
    )
    segments = _merge_duplicates(segments, facing, duplicate_angle, duplicate_offset, door_gap,
                                 bridge_gap)
    if len(segments) == 0:
        raise ValueError(f"no wall segment of at least {min_length} m found in the grid")
    order = np.argsort(-segments.length, kind="stable")
    starts, ends = segments.starts[order], segments.ends[order]
    ids = [f"w{i}" for i in range(len(order))]
    return SegmentMap(starts, ends, kinds=["wall"] * len(order), ids=ids, name=name)


def _detect_candidates(grid: OccupancyGrid) -> _Lines:
    """LSD on the occupied-cell image → candidate segments in world coordinates."""
    image = np.where(grid.occupied, 255, 0).astype(np.uint8)
    # Walls in a grid built from scans are jagged chains of cells; LSD needs level lines that
    # agree in orientation, which a blur over a few cells gives (on the raw binary image it
    # finds only short, straight stretches). The blur's edges sit beside the wall: refined later.
    image = cv2.GaussianBlur(image, (0, 0), _CANDIDATE_BLUR_CELLS)
    detector = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale=1.0)
    found = detector.detect(image)[0]
    if found is None:
        return _lines_from_ends(np.empty((0, 2)), np.empty((0, 2)))
    uv = found.reshape(-1, 4).astype(float)
    ox, oy = grid.origin
    # LSD's pixel centres sit at integer coordinates: cell j spans [j − ½, j + ½].
    a = np.column_stack((ox + (uv[:, 0] + 0.5) * grid.resolution,
                         oy + (uv[:, 1] + 0.5) * grid.resolution))
    b = np.column_stack((ox + (uv[:, 2] + 0.5) * grid.resolution,
                         oy + (uv[:, 3] + 0.5) * grid.resolution))
    long_enough = np.linalg.norm(b - a, axis=1) >= 3 * grid.resolution
    return _lines_from_ends(a[long_enough], b[long_enough])


def _lines_from_ends(a: NDArray[np.float64], b: NDArray[np.float64]) -> _Lines:
    length = np.linalg.norm(b - a, axis=1)
    direction = (b - a) / np.maximum(length, 1e-12)[:, None]
    return _Lines(a, direction, np.zeros(len(a)), length)


def _support(
    lines: _Lines, points: NDArray[np.float64], tree: cKDTree, tol: float, margin: float,
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """All (line, point) pairs with the point within ``tol`` of the line and within its extent
    ± ``margin``; returns line indices, point indices, position along and distance across."""
    if len(lines) == 0:
        empty = np.empty(0, dtype=np.intp)
        return empty, empty, np.empty(0), np.empty(0)
    mid_s = 0.5 * (lines.s0 + lines.s1)
    centre = lines.point + mid_s[:, None] * lines.direction
    radius = np.hypot(0.5 * lines.length + margin, tol)
    near = tree.query_ball_point(centre, radius)
    counts = np.fromiter((len(n) for n in near), dtype=np.intp, count=len(near))
    line = np.repeat(np.arange(len(lines)), counts)
    point = np.concatenate([np.asarray(n, dtype=np.intp) for n in near]) if counts.sum() else line
    rel = points[point] - lines.point[line]
    s = np.einsum("ij,ij->i", rel, lines.direction[line])
    d = np.abs(np.einsum("ij,ij->i", rel, lines.normal[line]))
    keep = (d <= tol) & (s >= lines.s0[line] - margin) & (s <= lines.s1[line] + margin)
    return line[keep], point[keep], s[keep], d[keep]


@dataclass(frozen=True)
class _Moments:
    """Point counts, sums and second moments per line: a total-least-squares fit in closed form
    that can be merged by adding."""

    n: NDArray[np.float64]
    sx: NDArray[np.float64]
    sy: NDArray[np.float64]
    sxx: NDArray[np.float64]
    sxy: NDArray[np.float64]
    syy: NDArray[np.float64]

    @classmethod
    def of(cls, labels: NDArray[np.intp], xy: NDArray[np.float64], count: int) -> _Moments:
        x, y = xy[:, 0], xy[:, 1]

        def total(weights: NDArray[np.float64] | None) -> NDArray[np.float64]:
            return np.bincount(labels, weights=weights, minlength=count).astype(float)

        return cls(total(None), total(x), total(y), total(x * x), total(x * y), total(y * y))

    def fit(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centroid and principal direction per line (where n ≥ 2)."""
        n = np.maximum(self.n, 1.0)
        mx, my = self.sx / n, self.sy / n
        cxx = self.sxx / n - mx * mx
        cxy = self.sxy / n - mx * my
        cyy = self.syy / n - my * my
        phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
        return np.column_stack((mx, my)), np.column_stack((np.cos(phi), np.sin(phi)))


def _refine(candidates: _Lines, points: NDArray[np.float64], tree: cKDTree, tol: float,
            margin: float) -> _Lines:
    """Refit every candidate to the occupied cells around it (TLS); extent from its cells."""
    line, point, _s, _d = _support(candidates, points, tree, tol, margin)
    moments = _Moments.of(line, points[point], len(candidates))
    centroid, direction = moments.fit()
    # Keep the candidate's orientation so its extent stays meaningful.
    flip = np.einsum("ij,ij->i", direction, candidates.direction) < 0
    direction[flip] *= -1
    rel = points[point] - centroid[line]
    s = np.einsum("ij,ij->i", rel, direction[line])
    n = len(candidates)
    s0 = np.full(n, np.inf)
    s1 = np.full(n, -np.inf)
    np.minimum.at(s0, line, s)
    np.maximum.at(s1, line, s)
    ok = (moments.n >= 3) & (np.abs(np.einsum("ij,ij->i", direction, candidates.direction))
                             >= _MAX_REFIT_TURN_COS)
    return _Lines(centroid[ok], direction[ok], s0[ok], s1[ok])


def _group_collinear(lines: _Lines, angle_tol: float, offset_tol: float,
                     door_gap: float) -> _Lines:
    """Greedy grouping, longest detection first: a detection joins the first group whose line it
    matches (direction within ``angle_tol``, both ends within ``offset_tol``) and whose extent it
    overlaps or nearly touches (gap ≤ ``door_gap``); otherwise it starts a group.

    The loop runs over detections (hundreds), each step vectorised over the groups. A group's
    line is refitted from the length-weighted ends of its members as they join, so long walls
    dominate and a chain of slightly rotated pieces cannot drift.
    """
    order = np.argsort(-lines.length, kind="stable")
    starts, ends = lines.starts, lines.ends
    g_point = np.empty((0, 2))
    g_dir = np.empty((0, 2))
    g_s = np.empty((0, 2))
    g_mom = np.empty((0, 6))
    cos_tol = math.cos(angle_tol)
    for i in order:
        a, b = starts[i], ends[i]
        d = lines.direction[i]
        if len(g_point):
            normal = np.column_stack((-g_dir[:, 1], g_dir[:, 0]))
            off_a = np.abs(np.einsum("ij,ij->i", a - g_point, normal))
            off_b = np.abs(np.einsum("ij,ij->i", b - g_point, normal))
            sa = np.einsum("ij,ij->i", a - g_point, g_dir)
            sb = np.einsum("ij,ij->i", b - g_point, g_dir)
            gap = np.maximum(np.minimum(sa, sb) - g_s[:, 1], g_s[:, 0] - np.maximum(sa, sb))
            match = ((np.abs(g_dir @ d) >= cos_tol) & (off_a <= offset_tol)
                     & (off_b <= offset_tol) & (gap <= door_gap))
            hit = np.flatnonzero(match)
        else:
            hit = np.empty(0, dtype=np.intp)
        weight = float(lines.length[i])
        mom = weight * _end_moments(a, b)
        if len(hit):
            g = hit[0]
            old_ends = g_point[g] + g_s[g][:, None] * g_dir[g]  # the group's ends, in the world
            g_mom[g] += mom
            g_point[g], new_dir = _fit_moments(g_mom[g])
            g_dir[g] = new_dir if new_dir @ g_dir[g] >= 0 else -new_dir
            # The refitted line moved: re-express the old extent and add the new member's.
            s_all = (np.vstack((old_ends, a, b)) - g_point[g]) @ g_dir[g]
            g_s[g] = [s_all.min(), s_all.max()]
        else:
            g_point = np.vstack((g_point, 0.5 * (a + b)))
            g_dir = np.vstack((g_dir, d))
            half = 0.5 * float(lines.length[i])
            g_s = np.vstack((g_s, [-half, half]))
            g_mom = np.vstack((g_mom, mom))
    return _Lines(g_point, g_dir, g_s[:, 0], g_s[:, 1])


def _end_moments(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Moments of a segment as a uniform distribution of mass 1 along it (not just its ends):
    the covariance of a uniform segment is ``(b − a)(b − a)ᵀ/12`` about its midpoint."""
    m = 0.5 * (a + b)
    d = b - a
    return np.array([1.0, m[0], m[1], m[0] * m[0] + d[0] * d[0] / 12,
                     m[0] * m[1] + d[0] * d[1] / 12, m[1] * m[1] + d[1] * d[1] / 12])


def _fit_moments(mom: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centroid, direction = _Moments(*(np.atleast_1d(v) for v in mom)).fit()
    return centroid[0], direction[0]


def _segments_on_lines(
    groups: _Lines,
    grid: OccupancyGrid,
    points: NDArray[np.float64],
    tree: cKDTree,
    *,
    support_tol: float,
    bridge_gap: float,
    occlusion_gap: float,
    min_length: float,
    min_fill: float = 0.6,
    min_piece: float = 0.25,
) -> tuple[_Lines, NDArray[np.float64]]:
    """Occupied cells → wall lines (refitted) → runs of cells along each line → segments, and
    each segment's facing: the unit normal pointing to the side it is seen from (free space)."""
    line, point, _s, dist = _support(groups, points, tree, support_tol, margin=occlusion_gap)
    line, point = _keep_best_of_parallel(groups, line, point, dist)
    moments = _Moments.of(line, points[point], len(groups))
    centroid, direction = moments.fit()
    # A refit that turns the line is a blob of clutter, not a wall: drop the line.
    turned = np.abs(np.einsum("ij,ij->i", direction, groups.direction)) < _MAX_REFIT_TURN_COS
    fitted = (moments.n >= 2) & ~turned
    rel = points[point] - centroid[line]
    s = np.einsum("ij,ij->i", rel, direction[line])
    across = np.abs(rel[:, 0] * direction[line, 1] - rel[:, 1] * direction[line, 0])
    keep = fitted[line] & (across <= support_tol)
    line, s = line[keep], s[keep]
    order = np.lexsort((s, line))
    line, s = line[order], s[order]

    pieces = _solid_pieces(line, s, grid.resolution, bridge_gap, min_fill, min_piece)
    pieces = _with_free_side(pieces, grid, centroid, direction)
    runs = _join_occluded_gaps(pieces, grid, centroid, direction, occlusion_gap)
    keep = runs.length >= min_length
    runs = _Runs(runs.line[keep], runs.s0[keep], runs.s1[keep])
    lines = _Lines(centroid[runs.line], direction[runs.line], runs.s0, runs.s1)
    share = _free_side_share(runs, grid, centroid, direction)
    facing = lines.normal * np.where(share[:, 0] >= share[:, 1], 1.0, -1.0)[:, None]
    return lines, facing


@dataclass(frozen=True)
class _Runs:
    """Stretches ``[s0, s1]`` of wall along the fitted lines ``line``, sorted by (line, s0)."""

    line: NDArray[np.intp]
    s0: NDArray[np.float64]
    s1: NDArray[np.float64]

    @property
    def length(self) -> NDArray[np.float64]:
        return self.s1 - self.s0


def _solid_pieces(line: NDArray[np.intp], s: NDArray[np.float64], resolution: float,
                  bridge_gap: float, min_fill: float, min_piece: float) -> _Runs:
    """Cells sorted by (line, s) → pieces without gaps longer than ``bridge_gap``, kept when at
    least ``min_piece`` long and at least ``min_fill`` of their cell-steps hold a cell. Clutter
    and crossing walls put a few isolated cells on a line; a wall fills it."""
    if len(s) == 0:
        empty = np.empty(0)
        return _Runs(np.empty(0, dtype=np.intp), empty, empty)
    split = (line[1:] != line[:-1]) | (np.diff(s) > bridge_gap)
    piece = np.concatenate(([0], np.cumsum(split)))
    first = np.flatnonzero(np.concatenate(([True], split)))
    last = np.concatenate((first[1:] - 1, [len(s) - 1]))
    half = 0.5 * resolution  # a cell's point lies inside it; the wall spans the whole cell
    s0, s1 = s[first] - half, s[last] + half
    # Distinct cell-steps along the line per piece (a wall two cells thick counts once).
    step = np.floor((s - s[first][piece]) / resolution).astype(np.intp)
    distinct = np.unique(np.column_stack((piece, step)), axis=0)[:, 0]
    filled = np.bincount(distinct, minlength=len(first)) * resolution
    keep = ((s1 - s0) >= min_piece) & (filled >= min_fill * (s1 - s0))
    return _Runs(line[first][keep], s0[keep], s1[keep])


def _with_free_side(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                    direction: NDArray[np.float64], min_share: float = 0.5) -> _Runs:
    """Keep the pieces with free space along one side: a wall face is seen through free space,
    while a line drawn through a blob of clutter or a thick, smeared wall has none."""
    if len(pieces.line) == 0:
        return pieces
    keep = _free_side_share(pieces, grid, point, direction).max(axis=1) >= min_share
    return _Runs(pieces.line[keep], pieces.s0[keep], pieces.s1[keep])


def _free_side_share(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                     direction: NDArray[np.float64]) -> NDArray[np.float64]:
    """Share of free samples on each side of every piece (n × 2: along +normal, along −normal),
    sampled every cell along the piece, 3–6 cells out (free space keeps a clearance from the
    walls)."""
    if len(pieces.line) == 0:
        return np.zeros((0, 2))
    res = grid.resolution
    count = np.maximum(np.ceil(pieces.length / res).astype(np.intp), 1)
    piece = np.repeat(np.arange(len(count)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    along = pieces.s0[piece] + (k + 0.5) * res
    line = pieces.line[piece]
    base = point[line] + along[:, None] * direction[line]
    normal = np.column_stack((-direction[line, 1], direction[line, 0]))
    share = np.zeros((len(count), 2))
    for side, sign in enumerate((1.0, -1.0)):  # two sides, each vectorised over all samples
        seen_free = np.zeros(len(base), dtype=bool)
        for cells_out in _FREE_SIDE_OFFSETS:
            rows, cols = grid.world_to_cell(base + sign * cells_out * res * normal)
            inside = grid.inside(rows, cols)
            seen_free[inside] |= grid.free[rows[inside], cols[inside]]
        share[:, side] = np.bincount(piece, weights=seen_free, minlength=len(count)) / count
    return share


def _merge_duplicates(segments: _Lines, facing: NDArray[np.float64], angle_tol: float,
                      offset_tol: float, max_gap: float, bridge_gap: float) -> _Lines:
    """Merge near-duplicate lines of one wall face onto one line.

    A thick or slightly bent wall often yields two or more lines a few centimetres and a degree
    or two apart, each holding part of the wall's cells. The localizer then sees two map lines
    inside one observed wall's gate: an ambiguous match, or a fix pulled between them. Greedy,
    longest segment first: a segment joins the first cluster whose line it follows (direction
    within ``angle_tol``, both ends within ``offset_tol``), whose face looks the same way (the
    two faces of a thin wall stay apart) and whose extent is at most ``max_gap`` away along
    the line. A cluster's line is the length-weighted fit of its members; the members'
    extents, projected on it, are united where they overlap or are at most ``bridge_gap``
    apart, and stay separate segments of the one line otherwise (a wall with doors).
    """
    if len(segments) < 2:
        return segments
    order = np.argsort(-segments.length, kind="stable")
    starts, ends = segments.starts, segments.ends
    cos_tol = math.cos(angle_tol)
    c_point = np.empty((0, 2))
    c_dir = np.empty((0, 2))
    c_face = np.empty((0, 2))
    c_s = np.empty((0, 2))
    c_mom = np.empty((0, 6))
    members: list[list[int]] = []
    for i in order:
        a, b, d = starts[i], ends[i], segments.direction[i]
        hit = np.empty(0, dtype=np.intp)
        if len(c_point):
            normal = np.column_stack((-c_dir[:, 1], c_dir[:, 0]))
            off_a = np.abs(np.einsum("ij,ij->i", a - c_point, normal))
            off_b = np.abs(np.einsum("ij,ij->i", b - c_point, normal))
            sa = np.einsum("ij,ij->i", a - c_point, c_dir)
            sb = np.einsum("ij,ij->i", b - c_point, c_dir)
            gap = np.maximum(np.minimum(sa, sb) - c_s[:, 1], c_s[:, 0] - np.maximum(sa, sb))
            match = ((np.abs(c_dir @ d) >= cos_tol) & (off_a <= offset_tol)
                     & (off_b <= offset_tol) & (c_face @ facing[i] > 0) & (gap <= max_gap))
            hit = np.flatnonzero(match)
        mom = float(segments.length[i]) * _end_moments(a, b)
        if len(hit):
            c = hit[0]
            members[c].append(i)
            c_mom[c] += mom
            c_point[c], new_dir = _fit_moments(c_mom[c])
            c_dir[c] = new_dir if new_dir @ c_dir[c] >= 0 else -new_dir
            ends_c = np.concatenate([(starts[k], ends[k]) for k in members[c]])
            s_all = (ends_c - c_point[c]) @ c_dir[c]
            c_s[c] = [s_all.min(), s_all.max()]
        else:
            members.append([i])
            c_point = np.vstack((c_point, 0.5 * (a + b)))
            c_dir = np.vstack((c_dir, d))
            c_face = np.vstack((c_face, facing[i]))
            half = 0.5 * float(segments.length[i])
            c_s = np.vstack((c_s, [-half, half]))
            c_mom = np.vstack((c_mom, mom))
    pieces: list[tuple[int, float, float]] = []  # (cluster, s0, s1) on the cluster's line
    for c, group in enumerate(members):
        s_ends = np.column_stack(((starts[group] - c_point[c]) @ c_dir[c],
                                  (ends[group] - c_point[c]) @ c_dir[c]))
        lo, hi = s_ends.min(axis=1), s_ends.max(axis=1)
        by = np.argsort(lo)
        cur_lo, cur_hi = lo[by[0]], hi[by[0]]
        for k in by[1:]:
            if lo[k] - cur_hi > bridge_gap:
                pieces.append((c, cur_lo, cur_hi))
                cur_lo = lo[k]
            cur_hi = max(cur_hi, hi[k])
        pieces.append((c, cur_lo, cur_hi))
    cluster = np.array([p[0] for p in pieces], dtype=np.intp)
    return _Lines(c_point[cluster], c_dir[cluster], np.array([p[1] for p in pieces]),
                  np.array([p[2] for p in pieces]))


def _join_occluded_gaps(pieces: _Runs, grid: OccupancyGrid, point: NDArray[np.float64],
                        direction: NDArray[np.float64], occlusion_gap: float) -> _Runs:
    """Join consecutive pieces of one line across a gap no longer than ``occlusion_gap`` and
    than either piece, when the gap holds no free space: a stretch of wall hidden behind
    furniture. A gap with free space is a doorway the laser saw through: it stays open."""
    if len(pieces.line) < 2:
        return pieces
    length = pieces.length
    gap = pieces.s0[1:] - pieces.s1[:-1]
    candidate = ((pieces.line[1:] == pieces.line[:-1]) & (gap <= occlusion_gap)
                 & (gap <= np.minimum(length[1:], length[:-1])))
    lines = pieces.line[1:][candidate]
    joined = np.zeros(len(gap), dtype=bool)
    joined[candidate] = ~_gap_has_free_space(grid, point[lines], direction[lines],
                                             pieces.s1[:-1][candidate], pieces.s0[1:][candidate])
    start = np.flatnonzero(np.concatenate(([True], ~joined)))
    end = np.concatenate((start[1:] - 1, [len(gap)]))
    return _Runs(pieces.line[start], pieces.s0[start], pieces.s1[end])


def _keep_best_of_parallel(
    groups: _Lines, line: NDArray[np.intp], point: NDArray[np.intp], dist: NDArray[np.float64],
    parallel_cos: float = math.cos(math.radians(20.0)),
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """A cell supports at most one of several near-parallel lines (the nearest): two detections
    of one wall face must not both become segments. Crossing lines keep a shared cell, so a
    corner cell ends both walls."""
    if len(line) == 0:
        return line, point
    order = np.lexsort((dist, point))
    first = np.ones(len(order), dtype=bool)
    first[1:] = point[order][1:] != point[order][:-1]
    best_line = np.empty(point.max() + 1, dtype=np.intp)
    best_line[point[order][first]] = line[order][first]
    best = best_line[point]
    cos = np.abs(np.einsum("ij,ij->i", groups.direction[line], groups.direction[best]))
    keep = (line == best) | (cos < parallel_cos)
    return line[keep], point[keep]


def _gap_has_free_space(
    grid: OccupancyGrid, point: NDArray[np.float64], direction: NDArray[np.float64],
    s_from: NDArray[np.float64], s_to: NDArray[np.float64], min_free_share: float = 0.25,
) -> NDArray[np.bool_]:
    """For each gap along a line, whether free cells make up ≥ ``min_free_share`` of it (a
    doorway seen through), sampled every half cell strictly inside the gap."""
    if len(point) == 0:
        return np.zeros(0, dtype=bool)
    step = 0.5 * grid.resolution
    inner_from, inner_to = s_from + step, s_to - step
    count = np.maximum(np.ceil((inner_to - inner_from) / step).astype(np.intp), 1)
    gap = np.repeat(np.arange(len(point)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    s = inner_from[gap] + k * step
    xy = point[gap] + s[:, None] * direction[gap]
    rows, cols = grid.world_to_cell(xy)
    inside = grid.inside(rows, cols)
    free = np.zeros(len(xy), dtype=bool)
    free[inside] = grid.free[rows[inside], cols[inside]]
    share = np.bincount(gap, weights=free, minlength=len(point)) / count
    return share >= min_free_share


# ================================================================================================
# The whole pipeline, files and scoring
# ================================================================================================

GRID_SUFFIXES = (".yaml", ".yml")


def build_map(
    log_or_grid_path: str | Path,
    out_yaml: str | Path,
    png: bool = True,
    *,
    resolution: float = 0.05,
    max_range: float = DEFAULT_MAX_RANGE,
    min_length: float = 0.5,
    name: str | None = None,
    max_scans: int | None = None,
) -> SegmentMap:
    """Build a segment map from a corrected log or a ROS map YAML; write it to ``out_yaml`` and,
    with ``png``, a preview beside it (same name, ``.png``). Returns the map.

    A ``.yaml``/``.yml`` source is a ROS ``map_server`` map (its own resolution applies); anything
    else is a log read by :func:`fusion.io.open_log` from its reference poses. ``name`` defaults to
    the output file's stem.
    """
    source = Path(log_or_grid_path)
    out_yaml = Path(out_yaml)
    if source.suffix.lower() in GRID_SUFFIXES:
        grid = load_ros_map(source)
    else:
        grid = occupancy_from_log(source, resolution, max_range, max_scans=max_scans)
    segment_map = extract_segments(grid, min_length, name=name or out_yaml.stem)
    write_map_yaml(segment_map, out_yaml)
    if png:
        render_map_png(grid, segment_map, out_yaml.with_suffix(".png"))
    return segment_map


def write_map_yaml(segment_map: SegmentMap, path: str | Path) -> Path:
    """The map's YAML written atomically to ``path``."""
    return atomic_write_text(path, segment_map.to_yaml_text())


def render_map_png(grid: OccupancyGrid, segment_map: SegmentMap, path: str | Path,
                   dpi: int = 150) -> Path:
    """PNG of the segments (coloured lines) over the grid (grey), with metre axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    x0, x1, y0, y1 = grid.extent
    scale = min(16.0 / max(x1 - x0, y1 - y0), 1.0)  # inches per metre, capped for big maps
    fig = Figure(figsize=(max((x1 - x0) * scale, 4.0) + 1.5, max((y1 - y0) * scale, 4.0) + 1.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    shade = np.where(grid.occupied, 0.55, np.where(grid.free, 1.0, 0.85))
    ax.imshow(shade, cmap="gray", vmin=0, vmax=1, origin="lower", extent=grid.extent,
              interpolation="nearest")
    colours = _segment_colours(len(segment_map))
    lines = np.stack((segment_map.starts, segment_map.ends), axis=1)
    ax.add_collection(LineCollection(lines, colors=colours, linewidths=1.2))
    ax.set_aspect("equal")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.set_title(f"{segment_map.name}: {len(segment_map)} wall segments on "
                 f"{segment_map.n_lines} lines (grid {grid.resolution:g} m)")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return atomic_write_bytes(path, buffer.getvalue())


def _segment_colours(n: int) -> NDArray[np.float64]:
    from matplotlib import colormaps

    return colormaps["tab10"](np.arange(n) % 10)


def point_segment_distance(
    segment_map: SegmentMap, points: NDArray[np.float64], max_distance: float,
    spacing: float = 0.01,
) -> NDArray[np.float64]:
    """Distance from each point to its nearest map segment, exact up to ``max_distance`` (inf
    beyond). The segments are sampled every ``spacing`` into a k-d tree: the nearest sample
    names a segment, whose exact distance is returned — cost independent of the map's size."""
    length = segment_map.lengths
    count = np.ceil(length / spacing).astype(np.intp) + 1
    seg = np.repeat(np.arange(len(segment_map)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    t = k / (count[seg] - 1)
    starts, ends = segment_map.starts, segment_map.ends
    samples = starts[seg] + t[:, None] * (ends - starts)[seg]
    bound = math.hypot(max_distance, spacing)
    near, index = cKDTree(samples).query(points, distance_upper_bound=bound)
    out = np.full(len(points), np.inf)
    found = np.isfinite(near)
    s = seg[index[found]]
    a, d = starts[s], ends[s] - starts[s]
    u = np.clip(np.einsum("ij,ij->i", points[found] - a, d) / np.einsum("ij,ij->i", d, d), 0, 1)
    exact = np.linalg.norm(points[found] - (a + u[:, None] * d), axis=1)
    out[found] = np.where(exact <= max_distance, exact, np.inf)
    return out


def endpoint_coverage(segment_map: SegmentMap, points: NDArray[np.float64],
                      tolerance: float = 0.10) -> float:
    """Share of ``points`` (e.g. scan endpoints at the reference poses) within ``tolerance`` of
    a segment: how much of what the laser sees the map explains."""
    if len(points) == 0:
        return float("nan")
    return float(np.mean(point_segment_distance(segment_map, points, tolerance) <= tolerance))

"""Occupancy grids: from the scans of a corrected log at their reference poses (stage 1 of
:mod:`fusion.mapping`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from fusion.events import Scan
from fusion.io import open_log
from fusion.io.files import atomic_write_bytes
from houghloc.geometry import ranges_to_points, transform_points
from houghloc.segment_map import MapError, check_grid_size

# ROS map_server conventions (image values and thresholds).
ROS_UNKNOWN, ROS_FREE, ROS_OCCUPIED = 205, 254, 0
DEFAULT_MAX_RANGE = 30.0
"""Beams longer than this (metres) give no hit: far endpoints carry the heading error × range."""

_POLY_SHIFT = 4  # fillPoly fixed-point bits: vertices at 1/16 cell


class GridMapError(MapError):
    """An occupancy-grid file that cannot be used; the message names the file, field and problem."""


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


def read_reference_scans(path: str | Path, max_scans: int | None = None) -> list[Scan]:
    """The scans of a corrected log that carry a reference pose, in file order (the first
    ``max_scans`` of them when given). Raises :class:`fusion.io.LogError` for an unusable file and
    ``ValueError`` when no scan has a reference pose (a raw log cannot be mapped)."""
    events, _stats = open_log(path)
    scans = (e for e in events if isinstance(e, Scan) and e.reference is not None)
    selected = list(islice(scans, max_scans)) if max_scans is not None else list(scans)
    if not selected:
        raise ValueError(
            f"{path}: no scan with a reference pose: it reads as a raw log (no ODOM record "
            "stamped 0 re-anchors the odometry on a laser record's pose, as a corrected log's "
            "do), so its laser poses are odometry; map build needs a corrected log (e.g. "
            "GMapping's) or a map_server grid (--grid)")
    return selected


def scan_endpoints(scans: Iterable[Scan], max_range: float = DEFAULT_MAX_RANGE) -> NDArray:
    """World endpoints (N×2) of all returns shorter than ``max_range``, at the reference poses."""
    chunks = [
        transform_points(_reference(scan), ranges_to_points(
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
    check_grid_size(shape, resolution, _farthest_scan(scans))

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


def _farthest_scan(scans: Sequence[Scan]) -> str:
    """The scan whose reference pose lies farthest from the others' median, named by its line:
    what to look at when the grid of a log is too large."""
    poses = np.asarray([s.reference for s in scans], dtype=float)[:, :2]
    k = int(np.argmax(np.linalg.norm(poses - np.median(poses, axis=0), axis=1)))
    where = f"line {scans[k].line}" if scans[k].line is not None else f"t = {scans[k].t:g} s"
    return (f"the scans' reference poses (the farthest, at {where}, is "
            f"({poses[k, 0]:.4g}, {poses[k, 1]:.4g}))")


@dataclass(frozen=True)
class _BeamGeometry:
    """One scan in world coordinates: its hits and the polygon of the space its beams crossed."""

    hits: NDArray[np.float64]
    free_polygon: NDArray[np.float64]


def _reference(scan: Scan) -> tuple[float, float, float]:
    """The corrected pose a map is built from (a corrected log gives every scan one)."""
    if scan.reference is None:
        raise ValueError(f"scan at t = {scan.t}: no corrected pose to build a map from")
    return scan.reference


def _beam_geometry(scan: Scan, max_range: float) -> _BeamGeometry:
    r = np.asarray(scan.ranges, dtype=float)
    usable = np.isfinite(r) & (r > 0) & (r < scan.max_range)
    is_hit = usable & (r < max_range)
    # A long return proves free space up to max_range; a "no return" proves nothing (black or
    # glass surfaces also give none), so its vertex collapses onto the sensor.
    r_free = np.where(usable, np.minimum(r, max_range), 0.0)
    a = np.asarray(scan.angles, dtype=float)
    local = np.column_stack((r_free * np.cos(a), r_free * np.sin(a)))
    polygon = transform_points(_reference(scan), np.vstack(([0.0, 0.0], local)))
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

"""Segment maps from corrected logs or occupancy grids (``houghloc map build``; the map:
docs/method.md §4, its file: docs/architecture.md).

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
7. **Refit to the scans** (maps built from a log). :func:`refit_to_endpoints` refits every wall
   line by total least squares to the scan endpoints near it, in bands that shrink from 20 cm to
   4 cm: the endpoints are where the laser saw the face, which cells 5 cm wide, smeared by
   furniture standing against the wall, only approximate.

:func:`build_map` chains the stages and writes the map YAML and a PNG preview (segments over the
grid, metre axes). :func:`endpoint_coverage` scores a map against scan endpoints.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.files import atomic_write_bytes, atomic_write_text
from fusion.mapping.grid import (
    DEFAULT_MAX_RANGE,
    GridMapError,
    OccupancyGrid,
    occupancy_from_log,
    occupancy_from_scans,
    read_reference_scans,
    scan_endpoints,
)
from fusion.mapping.refit import nearest_segment, refit_to_endpoints
from fusion.mapping.ros_map import load_ros_map
from fusion.mapping.segments import extract_segments
from houghloc.segment_map import SegmentMap

__all__ = [
    "DEFAULT_MAX_RANGE",
    "GridMapError",
    "OccupancyGrid",
    "build_map",
    "endpoint_coverage",
    "extract_segments",
    "load_ros_map",
    "occupancy_from_log",
    "occupancy_from_scans",
    "point_segment_distance",
    "read_reference_scans",
    "refit_to_endpoints",
    "render_map_png",
    "scan_endpoints",
    "segment_map_from_scans",
    "write_map_yaml",
]


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
    name = name or out_yaml.stem
    if source.suffix.lower() in GRID_SUFFIXES:
        grid = load_ros_map(source)
        segment_map = extract_segments(grid, min_length, name=name)
    else:
        scans = read_reference_scans(source, max_scans)
        grid, segment_map = segment_map_from_scans(scans, resolution, max_range, min_length,
                                                   name)
    write_map_yaml(segment_map, out_yaml)
    if png:
        render_map_png(grid, segment_map, out_yaml.with_suffix(".png"))
    return segment_map


def segment_map_from_scans(
    scans: list, resolution: float = 0.05, max_range: float = DEFAULT_MAX_RANGE,
    min_length: float = 0.5, name: str = "map",
) -> tuple[OccupancyGrid, SegmentMap]:
    """Stages 1–7 on scans with reference poses: their occupancy grid and its wall segments,
    refitted to the scans' endpoints."""
    grid = occupancy_from_scans(scans, resolution, max_range)
    segment_map = extract_segments(grid, min_length, name=name)
    return grid, refit_to_endpoints(segment_map, scan_endpoints(scans, max_range))


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
    ax.add_collection(LineCollection(list(lines), colors=colours, linewidths=1.2))
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
    """Distance from each point to its nearest map segment (:func:`nearest_segment`, sampled
    every ``spacing``), exact up to ``max_distance`` (inf beyond)."""
    starts, ends = segment_map.starts, segment_map.ends
    found, s = nearest_segment(starts, ends, points, max_distance, spacing)
    out = np.full(len(points), np.inf)
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

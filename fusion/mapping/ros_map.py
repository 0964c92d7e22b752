"""Occupancy grids from ROS ``map_server`` maps (PGM/PNG + YAML)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from fusion.mapping.grid import GridMapError, OccupancyGrid
from houghloc.yaml_io import read_yaml


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

    raw = read_yaml(path, GridMapError, "ROS map")
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
    return np.asarray(pixels, dtype=np.uint8)

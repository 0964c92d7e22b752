"""The segment map and its reference points in the Hough domain (docs/method.md §4).

A map is a set of segments of two kinds: ``wall`` (range sensors see it, it occludes) and ``line``
(painted on the floor: only a camera sees it, it occludes nothing). Collinear segments — a wall
broken by doors — are merged into one *line*, which is one reference point in the Hough domain;
each segment keeps its own extent along that line.

World lines are stored in the canonical form ``n·p = r`` with ``n = (cos α, sin α)``, α ∈ [0, π).
Seen from a pose, a line becomes the robot-frame Hough point (θ_r, ρ_r) with ρ_r ≥ 0, θ_r ∈ [0, 2π).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from pydantic import ValidationError

from houghloc.geometry import TWO_PI, Pose
from houghloc.map_file import MapFile, describe_error
from houghloc.visibility import (
    predict_references,
    ray_directions,
    segments_near,
    unpack_visible,
    visible_packed,
)
from houghloc.yaml_io import read_yaml

SegmentKind = Literal["wall", "line"]


# Entries (cell × range): a robot stays local, memory stays flat. An entry is one small int32
# array, about 200 bytes with its key: the full memo costs under 1 MiB.
_VISIBILITY_CACHE_SIZE = 4096


MAX_MAP_EXTENT = 5000.0
"""m: no building a robot localizes in is wider; a map beyond it is in other units (mm, cm) or
has a stray vertex, and would ask for grids of gigabytes."""

MAX_GRID_CELLS = 100_000_000
"""Cells of any grid built over a map or a log (a distance field, an occupancy grid): 500 m ×
500 m at 5 cm, 400 MB of float32. More is refused before allocating, with the size named."""


def check_grid_size(shape: tuple[int, int], cell: float, what: str) -> None:
    """Raise :class:`MapError` naming ``what`` when a grid of ``shape`` exceeds MAX_GRID_CELLS."""
    cells = int(shape[0]) * int(shape[1])
    if cells > MAX_GRID_CELLS:
        raise MapError(f"{what}: a {cell:g} m grid over it would need {shape[1]} × {shape[0]} "
                       f"cells ({cells * 4 / 2**30:.1f} GiB), more than the "
                       f"{MAX_GRID_CELLS:,} allowed (is it in metres?)")


class MapError(ValueError):
    """A map file or map definition that cannot be used; the message names the file and entry."""


@dataclass(slots=True)  # built on every scan: not frozen, which costs 0.2 µs a field
class References:
    """Map lines as predicted Hough points seen from one pose (one row per visible line).

    ``theta``/``rho`` are the robot-frame Hough coordinates (ρ ≥ 0). ``beta`` is the world angle of
    the normal pointing from the robot to the line, so that ∂ρ/∂(x, y) = −(cos β, sin β) and
    ∂θ/∂θ_robot = −1. ``seg_*`` describe the candidate segments of those lines (for extent checks):
    ``seg_ref`` indexes rows of this table, ``seg_s0``/``seg_s1`` are extents along the line's
    direction ``(−sin β, cos β)`` in world metres.
    """

    line: NDArray[np.intp]
    theta: NDArray[np.float64]
    rho: NDArray[np.float64]
    beta: NDArray[np.float64]
    seg_ref: NDArray[np.intp]
    seg_s0: NDArray[np.float64]
    seg_s1: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.line)


class SegmentMap:
    """Segments, their merged lines and a spatial index (cost per query independent of map size)."""

    def __init__(
        self,
        starts: ArrayLike,
        ends: ArrayLike,
        kinds: Sequence[str] | None = None,
        ids: Sequence[str] | None = None,
        name: str = "unnamed",
        collinear_angle_tol: float = math.radians(0.5),
        collinear_dist_tol: float = 0.02,
        index_spacing: float = 1.0,
        visibility_cell: float = 0.2,
    ) -> None:
        self.name = name
        self.source = repr(name)  # what messages call it: its file when read from one
        self.starts = np.asarray(starts, dtype=float).reshape(-1, 2)
        self.ends = np.asarray(ends, dtype=float).reshape(-1, 2)
        n = len(self.starts)
        if n == 0 or len(self.ends) != n:
            raise MapError(f"map {name!r}: needs at least one segment with a start and an end")
        self.kinds = np.asarray(kinds if kinds is not None else ["wall"] * n)
        self.ids = list(ids) if ids is not None else [f"s{i}" for i in range(n)]
        self.is_wall = self.kinds == "wall"
        lengths = np.linalg.norm(self.ends - self.starts, axis=1)
        if np.any(lengths < 1e-6):
            bad = int(np.argmax(lengths < 1e-6))
            raise MapError(f"map {name!r}: segment {self.ids[bad]!r} has zero length")
        self.lengths = lengths
        self._check_extent(name)
        self._merge_collinear(collinear_angle_tol, collinear_dist_tol)
        self._build_index(index_spacing)
        self.visibility_cell = visibility_cell
        self.landmarks: dict[str, tuple[float, float]] = {}
        self._visibility_cache: dict[tuple, NDArray[np.int32]] = {}
        self._kind_masks: dict[tuple[str, ...], NDArray[np.bool_]] = {}

    def _check_extent(self, name: str) -> None:
        ends = np.concatenate((self.starts, self.ends))
        if not np.isfinite(ends).all():
            raise MapError(f"map {name!r}: non-finite coordinates")
        centre = np.median(ends, axis=0)
        far = np.abs(ends - centre).max(axis=1)
        if far.max() > MAX_MAP_EXTENT / 2:
            worst = int(np.argmax(far)) % len(self.starts)
            span = ends.max(axis=0) - ends.min(axis=0)
            raise MapError(f"map {name!r}: segment {self.ids[worst]!r} lies {far.max():.4g} m "
                           f"from the map's centre (the map spans {span[0]:.4g} m × "
                           f"{span[1]:.4g} m; at most {MAX_MAP_EXTENT:g} m is a building): "
                           "coordinates must be in metres")

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_yaml(cls, path: str | Path) -> SegmentMap:
        """Load a map YAML (docs/architecture.md, formats); :class:`MapError` names the file,
        entry and problem."""
        path = Path(path)
        raw = read_yaml(path, MapError, "map")
        if raw is None:
            raise MapError(f"map {path}: the file is empty")
        if not isinstance(raw, dict):
            kind = type(raw).__name__
            raise MapError(f"map {path}: expected a mapping with 'segments', got {kind}")
        return cls.from_dict(raw, source=str(path))

    @classmethod
    def from_dict(cls, raw: dict, source: str = "<dict>") -> SegmentMap:
        try:
            spec = MapFile.model_validate(raw)
        except ValidationError as exc:
            raise MapError(f"map {source}: {describe_error(exc, raw)}") from None
        ids = [s.id if s.id is not None else f"s{i}" for i, s in enumerate(spec.segments)]
        seen: dict[str, int] = {}
        for i, sid in enumerate(ids):
            if sid in seen:
                raise MapError(f"map {source}: segment #{i} (id {sid!r}): duplicate id")
            seen[sid] = i
        starts = [s.start for s in spec.segments]
        ends = [s.end for s in spec.segments]
        for i, (a, b) in enumerate(zip(starts, ends, strict=True)):
            if math.dist(a, b) < 1e-6:
                raise MapError(f"map {source}: segment #{i} (id {ids[i]!r}): 'from' equals 'to'")
        kinds = [s.kind for s in spec.segments]
        try:
            m = cls(starts, ends, kinds=kinds, ids=ids, name=spec.name)
        except MapError as error:
            raise MapError(f"map {source}: {str(error).split(': ', 1)[-1]}") from None
        m.landmarks = {lm.id: lm.at for lm in spec.landmarks}
        m.source = source
        return m

    def to_dict(self) -> dict:
        segs = [
            {"id": i, "kind": str(k), "from": [float(a[0]), float(a[1])],
             "to": [float(b[0]), float(b[1])]}
            for i, k, a, b in zip(self.ids, self.kinds, self.starts, self.ends, strict=True)
        ]
        out = {"name": self.name, "frame": "map", "units": "m", "segments": segs}
        if self.landmarks:
            out["landmarks"] = [{"id": k, "at": list(v)} for k, v in self.landmarks.items()]
        return out

    def to_yaml_text(self) -> str:
        """The map YAML of docs/architecture.md, formats."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, width=120)

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(self.to_yaml_text())

    def __len__(self) -> int:
        return len(self.starts)

    # ---------------------------------------------------------------- lines
    def check_within_reach(self, xy: ArrayLike, reach: float, what: str = "pose") -> None:
        """A ValueError when ``xy`` lies farther than ``reach`` (m) outside the box of the map's
        segments: no sensor of that reach could see any of the map from there."""
        x, y = (float(v) for v in np.asarray(xy, dtype=float)[:2])
        ends = np.concatenate((self.starts, self.ends))
        low, high = ends.min(axis=0), ends.max(axis=0)
        xy_arr = np.array((x, y))
        outside = float(np.linalg.norm(np.maximum(np.maximum(low - xy_arr, xy_arr - high), 0.0)))
        if outside > reach:
            raise ValueError(
                f"{what} ({x:g}, {y:g}) lies {outside:.1f} m outside the map {self.source} "
                f"(x {low[0]:.1f}…{high[0]:.1f} m, y {low[1]:.1f}…{high[1]:.1f} m), beyond the "
                f"sensors' {reach:g} m: no wall could be seen")

    def _merge_collinear(self, angle_tol: float, dist_tol: float) -> None:
        """Group segments on one infinite line; canonical form α ∈ [0, π), r signed."""
        d = (self.ends - self.starts) / self.lengths[:, None]
        alpha = np.arctan2(d[:, 0], -d[:, 1])  # normal (−d_y, d_x) rotated: atan2(n_y, n_x)
        r = self.starts[:, 0] * np.cos(alpha) + self.starts[:, 1] * np.sin(alpha)
        flip = (alpha < 0) | (alpha >= np.pi)
        alpha = np.where(flip, np.mod(alpha, TWO_PI) - np.pi, alpha)
        alpha = np.where(alpha < 0, alpha + np.pi, alpha)
        r = np.where(flip, -r, r)
        # Hash (α, r) on a grid of the tolerances; a segment joins a line found in a neighbour cell.
        buckets: dict[tuple[int, int], list[int]] = {}
        line_alpha: list[float] = []
        line_r: list[float] = []
        line_of = np.empty(len(alpha), dtype=np.intp)
        n_a = max(1, round(np.pi / angle_tol))
        for i, (a, ri) in enumerate(zip(alpha, r, strict=True)):
            ka, kr = int(a / angle_tol), math.floor(ri / dist_tol)
            found = -1
            for da in (-1, 0, 1):
                for dr in (-1, 0, 1):
                    wrapped = (ka + da) % n_a != ka + da  # across α = 0 ≡ π the sign of r flips
                    key = ((ka + da) % n_a, (-kr - 1 - dr) if wrapped else kr + dr)
                    for j in buckets.get(key, ()):
                        da_ = abs(line_alpha[j] - a)
                        same = da_ < angle_tol and abs(line_r[j] - ri) < dist_tol
                        opposite = np.pi - da_ < angle_tol and abs(line_r[j] + ri) < dist_tol
                        if same or opposite:
                            found = j
                            break
                    if found >= 0:
                        break
                if found >= 0:
                    break
            if found < 0:
                found = len(line_alpha)
                line_alpha.append(float(a))
                line_r.append(float(ri))
                buckets.setdefault((ka, kr), []).append(found)
            line_of[i] = found
        self.line_alpha = np.asarray(line_alpha)
        self.line_r = np.asarray(line_r)
        self._line_normal = np.stack((np.cos(self.line_alpha), np.sin(self.line_alpha)))  # 2×L
        self.line_of_segment = line_of
        t = np.column_stack((-np.sin(self.line_alpha), np.cos(self.line_alpha)))[line_of]
        s_a = np.einsum("ij,ij->i", self.starts, t)
        s_b = np.einsum("ij,ij->i", self.ends, t)
        self.seg_s0 = np.minimum(s_a, s_b)  # extent along the line's canonical direction
        self.seg_s1 = np.maximum(s_a, s_b)

    @property
    def n_lines(self) -> int:
        return len(self.line_alpha)

    # ---------------------------------------------------------------- spatial index
    def _build_index(self, spacing: float) -> None:
        """Points every ``spacing`` (at most) along each segment, both ends included: a segment
        is near a centre when one of its points is (:meth:`segments_near`)."""
        n_samples = np.maximum(2, np.ceil(self.lengths / spacing).astype(int) + 1)
        seg = np.repeat(np.arange(len(self)), n_samples)
        offsets = np.concatenate([np.linspace(0.0, 1.0, k) for k in n_samples])
        self._index_spacing = spacing
        self._samples = self.starts[seg] + offsets[:, None] * (self.ends - self.starts)[seg]
        self._first_sample = np.concatenate(([0], np.cumsum(n_samples)))

    def clear_cache(self) -> None:
        """Forget memoised visibility (benchmarks measuring the cold cost call this)."""
        self._visibility_cache.clear()

    def segments_near(self, center: ArrayLike, radius: float) -> NDArray[np.intp]:
        """Indices of segments with any part within ``radius`` (approximately: one of their
        points every ``index_spacing`` within ``radius`` + ``index_spacing``) of ``center``,
        in increasing order."""
        c = np.asarray(center, dtype=float)
        return segments_near(self.starts, self.ends, self._samples, self._first_sample,
                              float(c[0]), float(c[1]), radius + self._index_spacing)

    # ---------------------------------------------------------------- references
    def references(
        self,
        pose: Pose,
        max_range: float,
        kinds: tuple[str, ...] = ("wall",),
        n_rays: int = 180,
    ) -> References:
        """Predicted Hough points of the lines visible from ``pose`` (docs/method.md §4).

        Walls are kept if a ray from the pose hits them first (walls occlude, painted lines do
        not); painted lines are kept if they come within range.
        """
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        segs, lines, seg_ref = self._visible((x, y), max_range, tuple(kinds), n_rays)
        if len(segs) == 0:
            return _empty_references()
        theta, rho, beta, s0, s1 = predict_references(
            self.line_alpha, self.line_r, self._line_normal, self.seg_s0, self.seg_s1, segs,
            lines, seg_ref, x, y, th)
        return References(lines, theta, rho, beta, seg_ref, s0, s1)

    def _visible(self, origin: tuple[float, float], max_range: float, kinds: tuple[str, ...],
                 n_rays: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
        """Visible segments, their lines and each segment's row among those lines.

        Visibility changes slowly with position, so it is memoised per ``visibility_cell`` of
        space — except where a wall passes within a cell of the origin: there a step can cross to
        the other side, and the rays are cast from the exact position.
        """
        cell = self.visibility_cell
        key = (math.floor(origin[0] / cell), math.floor(origin[1] / cell),
               round(max_range, 1), kinds, n_rays)
        hit = self._visibility_cache.get(key)
        if hit is not None:
            return unpack_visible(hit)
        packed, clearance = visible_packed(
            self.starts, self.ends, self._samples, self._first_sample, self.kind_mask(kinds),
            self.is_wall, self.line_of_segment, ray_directions(n_rays), origin[0], origin[1],
            max_range + self._index_spacing, max_range)
        if clearance > 1.5 * cell:
            if len(self._visibility_cache) >= _VISIBILITY_CACHE_SIZE:
                self._visibility_cache.pop(next(iter(self._visibility_cache)))
            self._visibility_cache[key] = packed
        return unpack_visible(packed)

    def kind_mask(self, kinds: Sequence[str]) -> NDArray[np.bool_]:
        """Which segments are of one of ``kinds`` (read-only; computed once per set of kinds)."""
        key = tuple(kinds)
        mask = self._kind_masks.get(key)
        if mask is None:
            mask = self._kind_masks[key] = np.isin(self.kinds, key)
            mask.flags.writeable = False
        return mask


def _empty_references() -> References:
    e = np.empty(0)
    i = np.empty(0, dtype=np.intp)
    return References(i, e, e, e, i, e, e)

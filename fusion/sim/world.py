"""The simulated world: the segment map, reachable free space, unmapped clutter, moving discs.

* Free space is the part of the map a robot can reach: a grid over the map's bounding box keeps
  the cells at least ``CONNECT_CLEARANCE`` from every wall; of its 4-connected components, those
  touching the grid's border are outside the building and the largest remaining one is the
  reachable interior (so closed boxes such as a pillar or an alcove block are excluded). Samples
  are then checked exactly against the segments for the requested clearance.
* Clutter: boxes as four segments each, stored as an (M×4) array ``[x0, y0, x1, y1]``.
* Moving obstacles: discs ``[x, y, r]`` that wander at constant speed; see
  :func:`simulate_obstacles` for the motion model.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from fusion.resources import maps_dir
from fusion.sim.config import ClutterConfig, ObstacleGroup
from fusion.sim.raycast import min_distance, point_segment_distances
from houghloc.segment_map import MapError, SegmentMap

FloatArray = NDArray[np.float64]

MAPS_DIR = maps_dir()
CONNECT_CLEARANCE = 0.2  # a robot of radius ≈ 0.2 m fits through every passage kept
_GRID_RESOLUTION = 0.05


def resolve_map_path(name: str | Path, base: Path | None = None) -> Path:
    """Find a map file: as given, relative to ``base``, or packaged (:mod:`fusion.resources`)."""
    p = Path(name)
    maps = MAPS_DIR
    candidates = [p] if p.is_absolute() else [
        *([base / p] if base is not None else []),
        p,
        maps / p,
        maps / f"{p}.yaml",
    ]
    for c in candidates:
        if c.is_file():
            return c.resolve()
    tried = ", ".join(str(c) for c in candidates)
    raise MapError(f"map {str(name)!r}: file not found (tried {tried})")


def wall_segments(m: SegmentMap) -> tuple[FloatArray, FloatArray]:
    """Starts and ends of the map's walls (painted lines are not obstacles)."""
    return m.starts[m.is_wall], m.ends[m.is_wall]


def clutter_segments(clutter: FloatArray) -> tuple[FloatArray, FloatArray]:
    c = np.asarray(clutter, dtype=float).reshape(-1, 4)
    return c[:, :2], c[:, 2:]


def obstacle_segments(m: SegmentMap, clutter: FloatArray | None = None
                      ) -> tuple[FloatArray, FloatArray]:
    """Everything a body collides with: walls plus clutter."""
    ws, we = wall_segments(m)
    if clutter is None or len(clutter) == 0:
        return ws, we
    cs, ce = clutter_segments(clutter)
    return np.vstack((ws, cs)), np.vstack((we, ce))


# ---------------------------------------------------------------------------------- free space
@dataclass(frozen=True)
class FreeSpace:
    """Reachable interior of a map on a grid: ``dist[i, j]`` (m, to the nearest wall, from a
    distance transform; accurate to about one cell) for cells of the reachable component."""

    origin: FloatArray  # (x, y) of cell (0, 0)'s corner
    resolution: float
    dist: FloatArray  # rows = y, cols = x; 0 outside the reachable component

    def sample(self, rng: np.random.Generator, starts: FloatArray, ends: FloatArray,
               clearance: float, region: tuple[float, float, float, float] | None = None,
               max_tries: int = 200) -> FloatArray:
        """One point of the reachable interior at least ``clearance`` from the given segments."""
        iy, ix = np.nonzero(self.dist >= clearance - 1.5 * self.resolution)
        cx = self.origin[0] + (ix + 0.5) * self.resolution
        cy = self.origin[1] + (iy + 0.5) * self.resolution
        if region is not None:
            keep = (cx >= region[0]) & (cx <= region[2]) & (cy >= region[1]) & (cy <= region[3])
            cx, cy = cx[keep], cy[keep]
        if len(cx) == 0:
            raise ValueError(f"no free space with clearance {clearance} m")
        for _ in range(max_tries):
            k = rng.integers(len(cx), size=64)
            pts = np.column_stack((cx[k], cy[k])) + rng.uniform(
                -0.5 * self.resolution, 0.5 * self.resolution, size=(64, 2))
            ok = min_distance(pts, starts, ends) >= clearance
            if region is not None:
                ok &= ((pts[:, 0] >= region[0]) & (pts[:, 0] <= region[2])
                       & (pts[:, 1] >= region[1]) & (pts[:, 1] <= region[3]))
            if ok.any():
                return pts[int(np.argmax(ok))]
        raise ValueError(f"could not find a free point with clearance {clearance} m")


_FREE_SPACE_CACHE: weakref.WeakKeyDictionary[SegmentMap, FreeSpace] = weakref.WeakKeyDictionary()


def free_space(m: SegmentMap) -> FreeSpace:
    """The map's reachable interior (cached per map object)."""
    fs = _FREE_SPACE_CACHE.get(m)
    if fs is None:
        fs = _build_free_space(m)
        _FREE_SPACE_CACHE[m] = fs
    return fs


def _build_free_space(m: SegmentMap) -> FreeSpace:
    res = _GRID_RESOLUTION
    starts, ends = wall_segments(m)
    if len(starts) == 0:
        raise MapError(f"map {m.name!r}: has no walls, so it has no interior")
    lo = np.minimum(starts.min(axis=0), ends.min(axis=0)) - 3 * res
    hi = np.maximum(starts.max(axis=0), ends.max(axis=0)) + 3 * res
    shape = (math.ceil((hi[1] - lo[1]) / res), math.ceil((hi[0] - lo[0]) / res))
    # Rasterise the walls by sampling them at a third of a cell, then take the distance transform.
    lengths = np.linalg.norm(ends - starts, axis=1)
    n = np.maximum(2, np.ceil(lengths / (res / 3)).astype(int) + 1)
    seg = np.repeat(np.arange(len(starts)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n - 1, n)
    pts = starts[seg] + frac[:, None] * (ends - starts)[seg]
    occupied = np.zeros(shape, dtype=bool)
    rows = ((pts[:, 1] - lo[1]) / res).astype(int)
    cols = ((pts[:, 0] - lo[0]) / res).astype(int)
    occupied[rows, cols] = True
    dist = ndimage.distance_transform_edt(~occupied) * res
    # A cell centre is within res·√2/2 of a wall sample's cell centre: stay on the safe side.
    passable = dist >= CONNECT_CLEARANCE + res
    labels, n_labels = ndimage.label(passable)
    border = np.unique(np.concatenate((labels[0], labels[-1], labels[:, 0], labels[:, -1])))
    sizes = np.bincount(labels.ravel(), minlength=n_labels + 1)
    sizes[0] = 0
    sizes[border] = 0
    if sizes.max() == 0:
        raise MapError(f"map {m.name!r}: no enclosed free space found (is the outline closed?)")
    reachable = labels == int(np.argmax(sizes))
    return FreeSpace(origin=lo, resolution=res, dist=np.where(reachable, dist, 0.0))


def random_free_point(m: SegmentMap, rng: np.random.Generator, clearance: float = 0.5,
                      extra_segments: FloatArray | None = None,
                      region: tuple[float, float, float, float] | None = None) -> FloatArray:
    """A reachable point ≥ ``clearance`` from every wall (and every extra segment)."""
    starts, ends = obstacle_segments(m, extra_segments)
    return free_space(m).sample(rng, starts, ends, clearance, region)


def random_free_pose(m: SegmentMap, rng: np.random.Generator, clearance: float = 0.5,
                     kinds: tuple[str, ...] = ("wall",)) -> FloatArray:
    """A pose (x, y, θ) in the map's reachable interior, ≥ ``clearance`` from every segment of
    the given kinds, heading uniform in [−π, π).

    Painted lines are not obstacles, so by default a pose may lie on one; pass
    ``kinds=("wall", "line")`` to keep away from them too.
    """
    keep = m.kind_mask(kinds)
    fs = free_space(m)
    xy = fs.sample(rng, m.starts[keep], m.ends[keep], clearance)
    return np.array([xy[0], xy[1], rng.uniform(-np.pi, np.pi)])


# ---------------------------------------------------------------------------------- clutter
def make_clutter(m: SegmentMap, rng: np.random.Generator, cfg: ClutterConfig,
                 avoid_paths: FloatArray | None = None) -> FloatArray:
    """``cfg.count`` boxes (M×4 segments, four per box) in free space, not overlapping each other
    and at least ``cfg.route_clearance`` from the polyline ``avoid_paths`` (the robot's route), so
    the robot never drives through one. Fewer boxes are placed if the map is too crowded."""
    boxes: list[FloatArray] = []
    centres: list[tuple[float, float, float]] = []
    ws, we = wall_segments(m)
    route = None if avoid_paths is None or len(avoid_paths) < 2 else avoid_paths
    tries = 0
    while len(centres) < cfg.count and tries < 50 * max(cfg.count, 1):
        tries += 1
        w, h = rng.uniform(cfg.size[0], cfg.size[1], size=2)
        half_diag = 0.5 * math.hypot(w, h)
        try:
            c = free_space(m).sample(rng, ws, we, half_diag + 0.05)
        except ValueError:
            continue
        if route is not None:
            d = point_segment_distances(c[None, :], route[:-1], route[1:]).min()
            if d < cfg.route_clearance + half_diag:
                continue
        if any(math.dist(c, (x, y)) < half_diag + r + 0.1 for x, y, r in centres):
            continue
        centres.append((float(c[0]), float(c[1]), half_diag))
        phi = rng.uniform(0.0, np.pi / 2)
        u = np.array([math.cos(phi), math.sin(phi)])
        v = np.array([-u[1], u[0]])
        corners = np.array([c + sx * 0.5 * w * u + sy * 0.5 * h * v
                            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        boxes.append(np.hstack((corners, np.roll(corners, -1, axis=0))))
    return np.vstack(boxes) if boxes else np.empty((0, 4))


# ---------------------------------------------------------------------------------- obstacles
def place_discs(m: SegmentMap, rng: np.random.Generator, groups: list[ObstacleGroup],
                clutter: FloatArray, keep_away: ArrayLike, keep_away_dist: float = 1.5
                ) -> FloatArray:
    """Initial discs (D×3): reachable, clear of walls and clutter, apart from each other and at
    least ``keep_away_dist`` from the point ``keep_away`` (the robot's start)."""
    starts, ends = obstacle_segments(m, clutter)
    away = np.asarray(keep_away, dtype=float)[:2]
    discs: list[tuple[float, float, float]] = []
    for g in groups:
        for _ in range(g.count):
            for _attempt in range(200):
                p = free_space(m).sample(rng, starts, ends, g.radius + 0.1)
                far = math.dist(p, away) >= keep_away_dist
                if far and all(math.dist(p, (x, y)) > r + g.radius + 0.1 for x, y, r in discs):
                    discs.append((float(p[0]), float(p[1]), g.radius))
                    break
            else:
                raise ValueError(f"cannot place {g.count} obstacles of radius {g.radius} m")
    return np.array(discs, dtype=float).reshape(-1, 3)


def simulate_obstacles(m: SegmentMap, rng: np.random.Generator, discs: FloatArray,
                       speeds: FloatArray, turn_noise: FloatArray, clutter: FloatArray,
                       dt: float, n_steps: int, robot_xy: FloatArray, robot_radius: float
                       ) -> FloatArray:
    """Disc centres at times ``k·dt`` (n_steps × D × 2).

    Each disc moves ``p ← p + s·dt·(cos ψ, sin ψ)`` with ``ψ ← ψ + turn_noise·√dt·N(0, 1)``. A step
    that would end within the disc's radius (+2 cm) of a wall or clutter, or move closer to the
    robot (``robot_xy[k]``) while within ``r + robot_radius + 0.1`` of it, is not taken and ψ is
    redrawn uniformly; a disc already that close to the robot heads straight away from it.
    Steps are shorter than the radius (checked in the config), so a disc cannot jump over a wall
    between two clear positions.
    """
    n = len(discs)
    out = np.empty((n_steps, n, 2))
    if n == 0:
        return out
    starts, ends = obstacle_segments(m, clutter)
    pos = discs[:, :2].copy()
    radii = discs[:, 2]
    psi = rng.uniform(-np.pi, np.pi, size=n)
    step = speeds * dt
    keep_out = radii + robot_radius + 0.1
    sqrt_dt = math.sqrt(dt)
    for k in range(n_steps):
        out[k] = pos
        psi = psi + turn_noise * sqrt_dt * rng.standard_normal(n)
        # The robot does not avoid anyone: a disc it comes close to steps out of its way.
        r_next = robot_xy[min(k + 1, len(robot_xy) - 1)]
        away = pos - r_next
        d_now = np.hypot(away[:, 0], away[:, 1])
        crowded = d_now < keep_out
        psi = np.where(crowded, np.arctan2(away[:, 1], away[:, 0]), psi)
        new = pos + step[:, None] * np.column_stack((np.cos(psi), np.sin(psi)))
        blocked = min_distance(new, starts, ends) < radii + 0.02
        d_new = np.hypot(*(new - r_next).T)
        blocked |= (d_new < keep_out) & (d_new < d_now)
        pos = np.where(blocked[:, None], pos, new)
        psi = np.where(blocked, rng.uniform(-np.pi, np.pi, size=n), psi)
    return out


def discs_at(t_query: ArrayLike, dt: float, track: FloatArray, radii: FloatArray) -> FloatArray:
    """Discs (Q × D × 3) at times ``t_query`` (relative to the track's start), linearly
    interpolated between the obstacle steps."""
    tq = np.asarray(t_query, dtype=float)
    if track.shape[1] == 0:
        return np.empty((len(tq), 0, 3))
    f = np.clip(tq / dt, 0.0, len(track) - 1)
    i0 = np.minimum(np.floor(f).astype(int), len(track) - 2) if len(track) > 1 else np.zeros(
        len(tq), dtype=int)
    w = (f - i0)[:, None, None] if len(track) > 1 else np.zeros((len(tq), 1, 1))
    i1 = np.minimum(i0 + 1, len(track) - 1)
    xy = (1.0 - w) * track[i0] + w * track[i1]
    r = np.broadcast_to(radii, (len(tq), len(radii)))[..., None]
    return np.concatenate((xy, r), axis=2)

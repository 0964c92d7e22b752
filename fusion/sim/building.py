"""Generated buildings: a floor plan, a tour through it and a faulty robot, all drawn from a seed.

``building_scenario(seed)`` is the ``building`` scenario (``houghloc sim --scenario building
--seed N``): places the localizer was never tuned on, each with the hazards of real floors.

The floor plan (metres, x east, y north)::

        ┌──────┬──────┬──────┬──────┐┌──────────────┐
        │ room │ room │ room │ room ││     hall     │
   ─────┴──▯───┴──▯───┴──▯───┴──▯───┘│   ■      ■   │   ▯ doors, ■ pillars
   featureless   main corridor (width w)              │
   ─────┬──▯───┬──▯───┬──▯───┬──▯───┐│   ■      ■   │
        │ room │ room │ room │ room ││              │
        └──────┴──────┴──────┴──────┘└─────┐  ┌─────┘
                                           │  │  a second featureless corridor (some seeds)

* The **main corridor** is 1.8–3.0 m wide with rooms on both sides. Rooms on a side share one
  width (a *module*, 3–4.5 m) and have their door at the same place, so doors repeat at the
  module's spacing: a corridor that looks the same one module further on.
* A **featureless corridor** continues the main one westwards for 12–20 m with no door; some
  seeds add a second, off the hall's south wall. Beyond the laser's range of its end wall, the
  position along it is not observable.
* The **hall** at the east end holds 2–4 square **pillars**.
* A room's corridor wall is **glass** with probability :data:`GLASS_PROBABILITY`: it is on the
  map (an architect draws it) but the laser sees through it (``ScenarioConfig.transparent``).
* **Furniture** (desks and cabinets, unmapped boxes) and **people** (moving discs).

The robot drives a tour from the corridor's west end: the featureless corridor to its end and
back, into some rooms through their doors, around the hall, down the second corridor if there is
one, and back west; then again. Its faults (:func:`_faults`): each wheel's scale wrong by up to
±5 %, slip in turns, a few seconds with no odometry record, and one kidnap (carried 2–4 m along
the main corridor and turned 20–45°, the wheels not turning).

Every leg of the tour keeps :data:`ROUTE_CLEARANCE` from the walls by construction (doors are
at least :data:`MIN_DOOR` wide and passed through their middle); :func:`fusion.sim.simulate`
checks the path again.
"""

from __future__ import annotations

import itertools
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fusion.io.files import atomic_file
from fusion.sim.config import (
    ClutterConfig,
    Kidnap,
    LaserConfig,
    ObstacleGroup,
    OdometryConfig,
    OdometryGap,
    RouteConfig,
    ScenarioConfig,
)
from houghloc.segment_map import SegmentMap

GENERATOR_VERSION = 3
"""Bumped whenever a seed would draw another building: cached maps carry it in their name."""
DURATION = 240.0
"""s of driving per generated run (2400 scans at 10 Hz)."""
MIN_DOOR = 0.9
"""m: the narrowest door; the robot (r = 0.25 m) passes through its middle with 0.2 m spare."""
ROUTE_CLEARANCE = 0.45
"""m: the least distance from a leg of the tour to a wall (half the narrowest door)."""
GLASS_PROBABILITY = 0.25
"""The chance that a room's corridor wall is glass (mapped, not seen by the laser)."""
WHEEL_SCALE_ERROR = 0.05
"""Each wheel's scale error is drawn uniformly within ± this fraction."""
TURN_SLIP = 0.05
"""The wheels over-report turns by up to this fraction (drawn per run)."""
ODOMETRY_GAP = (1.0, 4.0)
"""s: the odometry records stop for a time drawn from this range, once per run."""
KIDNAP_SHIFT = (2.0, 4.0)
"""m along the main corridor a kidnap carries the robot (and 20–45° it turns it)."""
KIDNAP_TURN_DEG = (20.0, 45.0)

Point = tuple[float, float]
Wall = tuple[str, Point, Point]


@dataclass
class Plan:
    """A floor plan: walls (id, from, to), the ids of the glass ones, the tour's waypoints and
    the main corridor's box (x0, x1, y0, y1), where kidnaps land."""

    walls: list[Wall] = field(default_factory=list)
    glass: list[str] = field(default_factory=list)
    tour: list[Point] = field(default_factory=list)
    corridor: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def wall(self, name: str, a: Point, b: Point) -> None:
        if math.dist(a, b) > 1e-9:
            self.walls.append((f"{name}{len(self.walls)}", a, b))

    def wall_with_gaps(self, name: str, a: Point, b: Point, gaps: list[tuple[float, float]]
                       ) -> None:
        """A straight wall from a to b with openings: (from, to) distances along it."""
        length = math.dist(a, b)
        ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
        at = 0.0
        for lo, hi in sorted(gaps):
            if lo > at:
                self.wall(name, (a[0] + at * ux, a[1] + at * uy), (a[0] + lo * ux, a[1] + lo * uy))
            at = max(at, hi)
        if at < length:
            self.wall(name, (a[0] + at * ux, a[1] + at * uy), b)

    def segment_map(self, name: str) -> SegmentMap:
        return SegmentMap(np.array([w[1] for w in self.walls], dtype=float),
                          np.array([w[2] for w in self.walls], dtype=float),
                          ids=[w[0] for w in self.walls], name=name)


def draw_plan(rng: np.random.Generator) -> Plan:
    """The floor plan and tour of one building (see the module docstring)."""
    plan = Plan()
    width = rng.uniform(1.8, 3.0)
    depth = rng.uniform(4.0, 6.0)
    yc = width / 2
    # rooms: per side a module, a room count and where the door sits in the room
    sides = []
    n_rooms = int(rng.integers(5, 9))
    module = rng.uniform(3.0, 4.5)
    length = n_rooms * module
    for side in (-1, +1):
        door = rng.uniform(MIN_DOOR, 1.1)
        door_at = rng.uniform(0.5, module - door - 0.5)  # from the room's west wall
        shift = 0.0 if side < 0 else rng.uniform(0.0, module / 2)
        edges = [0.0, *(shift + module * k for k in range(1, n_rooms)), length]
        edges = sorted({round(e, 6) for e in edges if 0.0 <= e <= length})
        rooms = [(x0, x1) for x0, x1 in itertools.pairwise(edges) if x1 - x0 > 2.5]
        sides.append((side, door, door_at, rooms))
    # the main corridor's side walls, doors cut in; the rooms behind them
    visits: list[list[Point]] = []
    for side, door, door_at, rooms in sides:
        y_wall = 0.0 if side < 0 else width
        y_back = y_wall + side * depth
        gaps = []
        for x0, x1 in rooms:
            d0 = min(x0 + door_at, x1 - door - 0.5)
            gaps.append((d0, d0 + door))
            xd = d0 + door / 2
            inside = y_wall + side * 1.0
            centre = ((x0 + x1) / 2, y_wall + side * depth / 2)
            visits.append([(xd, yc), (xd, inside), centre, (xd, inside), (xd, yc)])
            if x0 > 0.0:  # the west end's wall is drawn once below, room or not
                plan.wall(f"{'s' if side < 0 else 'n'}div", (x0, y_wall), (x0, y_back))
        plan.wall(f"{'s' if side < 0 else 'n'}west", (0.0, y_wall), (0.0, y_back))
        before = len(plan.walls)
        plan.wall_with_gaps(f"{'s' if side < 0 else 'n'}cor", (0.0, y_wall), (length, y_wall), gaps)
        glass_mask = rng.random(len(plan.walls) - before) < GLASS_PROBABILITY
        plan.glass.extend(w[0] for w, g in zip(plan.walls[before:], glass_mask, strict=True) if g)
        plan.wall(f"{'s' if side < 0 else 'n'}back", (0.0, y_back), (length, y_back))
    # the featureless corridor, west
    west = rng.uniform(12.0, 20.0)
    plan.wall("wcor", (-west, 0.0), (0.0, 0.0))
    plan.wall("wcor", (-west, width), (0.0, width))
    plan.wall("wend", (-west, 0.0), (-west, width))
    # the hall, east, as deep as the rooms on both sides
    hall = rng.uniform(8.0, 12.0)
    x_hall, x_east = length, length + hall
    y_south, y_north = -depth, width + depth
    plan.wall("hallw", (x_hall, y_south), (x_hall, 0.0))
    plan.wall("hallw", (x_hall, width), (x_hall, y_north))
    plan.wall("halle", (x_east, y_south), (x_east, y_north))
    plan.wall("halln", (x_hall, y_north), (x_east, y_north))
    second = rng.random() < 0.5
    x_second = x_hall + hall / 2
    if second:
        south_len = rng.uniform(10.0, 16.0)
        plan.wall_with_gaps("halls", (x_hall, y_south), (x_east, y_south),
                            [(hall / 2 - width / 2, hall / 2 + width / 2)])
        for x in (x_second - width / 2, x_second + width / 2):
            plan.wall("scor", (x, y_south), (x, y_south - south_len))
        plan.wall("send", (x_second - width / 2, y_south - south_len),
                  (x_second + width / 2, y_south - south_len))
    else:
        plan.wall("halls", (x_hall, y_south), (x_east, y_south))
    # the tour around the hall: a ring 1.5 m inside its walls; pillars inside the ring
    margin = 1.5
    ring = [(x_hall + margin, yc), (x_hall + margin, y_north - margin),
            (x_east - margin, y_north - margin), (x_east - margin, y_south + margin)]
    if second:  # down the second corridor from the ring's south side, and back
        ring += [(x_second, y_south + margin), (x_second, y_south - south_len + 1.5),
                 (x_second, y_south + margin)]
    ring += [(x_hall + margin, y_south + margin), (x_hall + margin, yc)]
    inner = (x_hall + margin + 1.2, x_east - margin - 1.2, y_south + margin + 1.2,
             y_north - margin - 1.2)
    for k in range(int(rng.integers(2, 5))):
        size = rng.uniform(0.4, 0.6)
        px = rng.uniform(inner[0] + size / 2, inner[1] - size / 2)
        py = rng.uniform(inner[2] + size / 2, inner[3] - size / 2)
        h = size / 2
        corners = [(px - h, py - h), (px + h, py - h), (px + h, py + h), (px - h, py + h)]
        for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
            plan.wall(f"pillar{k}_", a, b)
    # the tour: west to the featureless corridor's end, then east through some rooms
    tour: list[Point] = [(1.0, yc), (-west + 1.5, yc)]
    visits.sort(key=lambda v: v[0][0])
    chosen = rng.random(len(visits)) < 0.35
    for v, go in zip(visits, chosen, strict=True):
        if go:
            tour.extend(v)
    tour.extend(ring)
    plan.tour = tour
    plan.corridor = (0.0, length, 0.0, width)
    return plan


def _faults(rng: np.random.Generator, duration: float) -> dict[str, object]:
    """The robot's wheel errors, its odometry gap, and the time of its kidnap (placed later)."""
    gap_at = rng.uniform(0.15, 0.35) * duration
    return {
        "odometry": OdometryConfig(
            left_scale_error=rng.uniform(-WHEEL_SCALE_ERROR, WHEEL_SCALE_ERROR),
            right_scale_error=rng.uniform(-WHEEL_SCALE_ERROR, WHEEL_SCALE_ERROR),
            turn_slip=rng.uniform(0.0, TURN_SLIP),
            frame_offset=(rng.uniform(-500, 500), rng.uniform(-500, 500),
                          rng.uniform(-math.pi, math.pi)),
        ),
        "odometry_gaps": [OdometryGap(t=gap_at, duration=rng.uniform(*ODOMETRY_GAP))],
    }


def _laser(rng: np.random.Generator) -> LaserConfig:
    """A 2D laser as robots carry them: 180°, 240° or 270° wide at 0.5°, 8–30 m."""
    fov = float(rng.choice([180.0, 240.0, 270.0]))
    return LaserConfig(n_beams=round(fov / 0.5) + 1, fov_deg=fov,
                       max_range=float(rng.choice([8.0, 10.0, 30.0])))


def _kidnap(rng: np.random.Generator, plan: Plan, cfg: ScenarioConfig) -> Kidnap | None:
    """A kidnap at a time the robot is in the main corridor, carrying it along the corridor
    (so it drives straight back to its tour), or None when no such time is found."""
    from fusion.sim.robot import drive
    from fusion.sim.routes import make_route
    from fusion.sim.run import path_crosses_walls

    dt = 1.0 / cfg.odom_rate
    n = math.floor(cfg.duration * cfg.odom_rate) + 1
    m = plan.segment_map("tmp")
    route = make_route(m, cfg.route, rng, 0.0)
    poses = drive(route, cfg.robot, dt, n).poses
    x0, x1, y0, y1 = plan.corridor
    for _ in range(200):
        t = rng.uniform(0.45, 0.75) * cfg.duration
        x, y, _th = poses[min(round(t / dt), n - 1)]
        if not (x0 + 1.0 < x < x1 - 1.0 and y0 + 0.5 < y < y1 - 0.5):
            continue
        shift = rng.uniform(*KIDNAP_SHIFT) * rng.choice([-1.0, 1.0])
        if not x0 + 1.0 < x + shift < x1 - 1.0:
            shift = -shift
        if not x0 + 1.0 < x + shift < x1 - 1.0:
            continue
        turn = rng.uniform(*KIDNAP_TURN_DEG) * rng.choice([-1.0, 1.0])
        kidnap = Kidnap(t=t, dx=shift, dy=0.0, dtheta_deg=turn)
        # the way back to the tour must not touch a wall (the robot turns back onto its leg)
        path = drive(route, cfg.robot, dt, n, [kidnap])
        if not path_crosses_walls(m, path.poses, path.kidnapped).any():
            return kidnap
    return None


def map_cache_dir() -> Path:
    """Where generated maps are written (``HOUGHLOC_BUILDINGS`` or the system's temp folder)."""
    return Path(os.environ.get("HOUGHLOC_BUILDINGS",
                               Path(tempfile.gettempdir()) / "houghloc-buildings"))


def building_scenario(seed: int, duration: float | None = None,
                      map_dir: Path | None = None) -> ScenarioConfig:
    """The ``building`` scenario of a seed; its map is written to ``map_dir`` (default:
    :func:`map_cache_dir`) as ``building-v<version>-<seed>.yaml``."""
    rng = np.random.default_rng(np.random.SeedSequence([GENERATOR_VERSION, seed]))
    plan = draw_plan(rng)
    name = f"building-{seed}"
    folder = map_dir or map_cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"building-v{GENERATOR_VERSION}-{seed}.yaml"
    text = plan.segment_map(name).to_yaml_text()
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        with atomic_file(path) as f:
            f.write(text)
    span = float(duration) if duration is not None else DURATION
    people = int(rng.integers(2, 7))
    cfg = ScenarioConfig(
        name=name, map=str(path), duration=span, seed=seed,
        route=RouteConfig(kind="waypoints", waypoints=plan.tour, loop=True),
        laser=_laser(rng), camera=None,
        obstacles=[ObstacleGroup(count=people, radius=0.2, speed=0.8, turn_noise=0.8,
                                 kind="person")],
        clutter=ClutterConfig(count=int(rng.integers(8, 20)), size=(0.5, 1.4),
                              route_clearance=0.6),
        transparent=plan.glass,
        **_faults(rng, span),  # type: ignore[arg-type]
    )
    kidnap = _kidnap(rng, plan, cfg)
    return cfg if kidnap is None else cfg.model_copy(update={"kidnaps": [kidnap]})

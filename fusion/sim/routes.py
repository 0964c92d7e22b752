"""Routes: the waypoint polylines the robot follows.

* RoboCup field: random waypoints inside the pitch, ≥ 0.5 m from the walls (the pitch is convex,
  so every straight leg stays inside).
* Office floor: a hand-written loop — west to east along the corridor (y = 6), into each room
  through its door (south doors on y = 5 at x = 3.5, 10.5, 17.5, 23.5; north doors on y = 7 at
  x = 6.5, 13.5, 20.5), around two points inside the room, back out the same door, and finally back
  west along the corridor. Every leg keeps ≥ 0.5 m from the walls (checked in the tests).
* Any other map: random waypoints in the reachable free space, accepted only if the straight leg
  from the previous waypoint keeps the route's clearance from every wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.sim.config import RouteConfig
from fusion.sim.raycast import segment_segment_distance
from fusion.sim.world import free_space, wall_segments
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]

ROBOCUP_FIELD = (-4.0, -2.0, 4.0, 2.0)  # the 9 m × 5 m pitch shrunk by 0.5 m on every side


def _room(door_x: float, inner: list[tuple[float, float]], south: bool
          ) -> list[tuple[float, float]]:
    """Corridor → door → the room's points → door → corridor."""
    y_in = 4.0 if south else 8.0
    return [(door_x, 6.0), (door_x, y_in), *inner, (door_x, y_in), (door_x, 6.0)]


OFFICE_LOOP: list[tuple[float, float]] = [
    (1.0, 6.0),
    *_room(3.5, [(5.5, 2.0), (1.5, 2.5)], south=True),
    *_room(6.5, [(3.0, 10.0), (7.5, 10.5)], south=False),
    *_room(10.5, [(12.5, 2.0), (8.5, 1.5)], south=True),
    *_room(13.5, [(15.5, 10.5), (10.5, 10.0)], south=False),
    *_room(17.5, [(19.0, 3.5), (19.0, 1.2), (15.2, 1.2), (15.2, 3.8)], south=True),
    *_room(20.5, [(23.5, 9.0), (19.0, 10.5)], south=False),
    *_room(23.5, [(24.5, 1.5), (21.5, 1.5)], south=True),
    (25.0, 6.0),
    # and back west along the corridor to the start, closing the loop
]


@dataclass(frozen=True)
class Route:
    """A polyline of waypoints (M×2); with ``loop`` the last waypoint joins the first."""

    waypoints: FloatArray
    loop: bool

    def legs(self) -> tuple[FloatArray, FloatArray]:
        """Start and end of every leg, including the closing one of a loop."""
        w = self.waypoints
        if self.loop:
            return w, np.roll(w, -1, axis=0)
        return w[:-1], w[1:]

    def polyline(self) -> FloatArray:
        """The waypoints as a path (a loop repeats its first waypoint at the end)."""
        w = self.waypoints
        return np.vstack((w, w[:1])) if self.loop else w

    def start_pose(self) -> FloatArray:
        """First waypoint, heading along the first leg."""
        a, b = self.waypoints[0], self.waypoints[1]
        return np.array([a[0], a[1], np.arctan2(b[1] - a[1], b[0] - a[0])])


def _is_robocup(m: SegmentMap) -> bool:
    return m.name.startswith("robocup")


def _is_office(m: SegmentMap) -> bool:
    return m.name == "office-floor"


def make_route(m: SegmentMap, cfg: RouteConfig, rng: np.random.Generator, length: float) -> Route:
    """The route of a scenario; random routes are drawn until they are ``length`` metres long."""
    if cfg.kind == "waypoints":
        return Route(np.asarray(cfg.waypoints, dtype=float), cfg.loop)
    if cfg.kind == "auto" and _is_office(m):
        return Route(np.asarray(OFFICE_LOOP, dtype=float), loop=True)
    region = cfg.region
    if region is None and _is_robocup(m):
        region = ROBOCUP_FIELD
    return random_route(m, rng, length, cfg.clearance, cfg.min_leg, region)


def random_route(m: SegmentMap, rng: np.random.Generator, length: float, clearance: float,
                 min_leg: float, region: tuple[float, float, float, float] | None) -> Route:
    """Random waypoints whose straight legs keep ``clearance`` from every wall."""
    ws, we = wall_segments(m)
    fs = free_space(m)
    points = [fs.sample(rng, ws, we, clearance, region)]
    total, failures = 0.0, 0
    while total < length:
        p = fs.sample(rng, ws, we, clearance, region)
        leg = float(np.hypot(*(p - points[-1])))
        ok = leg >= min_leg and segment_segment_distance(
            points[-1][None, :], p[None, :], ws, we).min() >= clearance
        if not ok:
            failures += 1
            if failures > 10_000:
                raise ValueError("cannot draw a random route: free space too cramped")
            continue
        points.append(p)
        total += leg
    return Route(np.asarray(points), loop=False)

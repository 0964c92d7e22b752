"""Single-scan scenes for accuracy tests: obstacles placed where a sensor at a pose sees them.

Typical use::

    pose = random_free_pose(m, rng)
    discs = place_obstacles_near(m, pose, rng, n=3)
    scan = laser_scan(m, pose, rng, obstacles=discs)
    obstacle_fraction(scan.labels)   # ≥ 0.23 with 3 robots 0.8–2 m away, 180° 361-beam laser

(each disc of radius 0.25 m at ≤ 2 m covers ≥ 14.4° of the scan, and none hides another).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.sim.config import CameraConfig, LaserConfig
from fusion.sim.laser import MOVING_OBSTACLE, NO_RETURN, true_ranges
from fusion.sim.raycast import min_distance
from fusion.sim.world import obstacle_segments
from houghloc.geometry import Pose
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]

_ROBOT_RADIUS = 0.25


def place_obstacles_near(
    m: SegmentMap,
    pose: Pose,
    rng: np.random.Generator,
    n: int,
    sensor: LaserConfig | CameraConfig | None = None,
    radius: float = 0.25,
    min_dist: float = 0.8,
    max_dist: float = 2.0,
    clutter: FloatArray | None = None,
    max_tries: int = 500,
) -> FloatArray:
    """``n`` discs (n×3 rows ``[x, y, r]``) inside the sensor's field of view from ``pose``.

    Bearings are spread over the field of view (one slot per disc, jittered inside it) and no
    disc hides another; distances are uniform in [min_dist, max_dist] (capped by the
    sensor's range). Each disc stays ``radius + 5 cm`` clear of walls and clutter, does not
    overlap the others and stands in front of the first wall along its bearing, so the sensor
    sees it; where a wall is too close, a disc may leave its slot and come as close as the
    robot's body allows. Raises ``ValueError`` if there is still no room for ``n`` discs.
    """
    sensor = sensor or LaserConfig()
    x, y, th = (float(v) for v in pose)
    usable = 0.9 * math.radians(sensor.fov_deg)
    far = min(max_dist, sensor.max_range - radius)
    # Closest a disc may come: clear of the robot's body (r ≈ 0.25 m) and the sensor's blind zone.
    floor = max(_ROBOT_RADIUS + radius + 0.05, sensor.min_range + radius)
    near = max(min_dist, floor)
    if far <= near:
        raise ValueError("min_dist/max_dist leave no room inside the sensor's range")
    starts, ends = obstacle_segments(m, clutter)
    discs: list[tuple[float, float, float]] = []
    shadows: list[tuple[float, float]] = []  # (bearing, angular half-width) of each disc
    for slot in rng.permutation(n).tolist():
        for attempt in range(max_tries):
            # Facing a wall there may be no room in this slot beyond min_dist: after half the
            # attempts, come closer and accept any bearing in the field of view.
            relaxed = attempt >= max_tries // 2
            lo = floor if relaxed else near
            frac = rng.uniform(0.0, n) if relaxed else slot + rng.uniform(0.2, 0.8)
            bearing = th - 0.5 * usable + frac * usable / n
            wall_r, _ = true_ranges(m, (x, y, bearing), np.zeros(1), np.inf, clutter=clutter)
            hi = min(far, float(wall_r[0]) - radius - 0.05)
            if hi <= lo:
                continue
            d = rng.uniform(lo, hi)
            cx, cy = x + d * math.cos(bearing), y + d * math.sin(bearing)
            if min_distance(np.array([[cx, cy]]), starts, ends)[0] < radius + 0.05:
                continue
            # Keep every disc wholly visible: no overlap in bearing with the ones placed.
            half = math.asin(min(1.0, radius / d))
            if any(abs(math.remainder(bearing - ob, 2 * math.pi)) < half + oh
                   for ob, oh in shadows):
                continue
            discs.append((cx, cy, radius))
            shadows.append((bearing, half))
            break
        else:
            raise ValueError(f"cannot place {n} obstacles of radius {radius} m in view of {pose}")
    return np.array(discs, dtype=float).reshape(-1, 3)


def obstacle_fraction(labels: ArrayLike) -> float:
    """Fraction of the returned points (laser beams with a return, or camera points) that come
    from moving obstacles."""
    lab = np.asarray(labels)
    valid = lab != NO_RETURN
    return float(np.mean(lab[valid] == MOVING_OBSTACLE)) if valid.any() else 0.0

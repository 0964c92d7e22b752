"""Single-scan scenes for accuracy tests: obstacles placed where a sensor at a pose sees them.

Typical use::

    pose = random_free_pose(m, rng)
    discs = place_obstacles_near(m, pose, rng, n=3)
    scan = laser_scan(m, pose, rng, obstacles=discs)
    obstacle_fraction(scan.labels)          # ≥ 0.2 with 3 robots 0.8–2.5 m away
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.sim.config import CameraConfig, LaserConfig
from fusion.sim.laser import MOVING_OBSTACLE, NO_RETURN, true_ranges
from fusion.sim.raycast import min_distance
from fusion.sim.world import obstacle_segments
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]


def place_obstacles_near(
    m: SegmentMap,
    pose: ArrayLike,
    rng: np.random.Generator,
    n: int,
    sensor: LaserConfig | CameraConfig | None = None,
    radius: float = 0.25,
    min_dist: float = 0.8,
    max_dist: float = 2.5,
    clutter: FloatArray | None = None,
    max_tries: int = 500,
) -> FloatArray:
    """``n`` discs (n×3 rows ``[x, y, r]``) inside the sensor's field of view from ``pose``.

    Bearings are spread over the field of view (one slot per disc, jittered inside it) so the
    discs do not hide each other; distances are uniform in [min_dist, max_dist] (capped by the
    sensor's range). Each disc stays ``radius + 5 cm`` clear of walls and clutter, does not
    overlap the others and stands in front of the first wall along its bearing, so the sensor
    sees it. Raises ``ValueError`` if the free space around the pose is too small for ``n``.
    """
    sensor = sensor or LaserConfig()
    x, y, th = (float(v) for v in pose)
    fov = math.radians(sensor.fov_deg)
    usable = 0.9 * min(fov, 2 * math.pi)
    far = min(max_dist, sensor.max_range - radius)
    near = max(min_dist, getattr(sensor, "min_range", 0.0) + radius)
    if far <= near:
        raise ValueError("min_dist/max_dist leave no room inside the sensor's range")
    starts, ends = obstacle_segments(m, clutter)
    discs: list[tuple[float, float, float]] = []
    slots = rng.permutation(n)
    for slot in slots:
        for _ in range(max_tries):
            bearing = th - 0.5 * usable + (slot + rng.uniform(0.2, 0.8)) * usable / n
            d = rng.uniform(near, far)
            cx, cy = x + d * math.cos(bearing), y + d * math.sin(bearing)
            centre = np.array([[cx, cy]])
            if min_distance(centre, starts, ends)[0] < radius + 0.05:
                continue
            wall_r, _ = true_ranges(m, (x, y, bearing), np.zeros(1), np.inf, clutter=clutter)
            if wall_r[0] < d + radius + 0.05:
                continue
            if any(math.dist((cx, cy), (ox, oy)) < radius + r + 0.05 for ox, oy, r in discs):
                continue
            discs.append((cx, cy, radius))
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

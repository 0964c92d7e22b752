"""The camera-line sensor: floor lines detected in the image and triangulated onto the floor.

What it sees: painted lines, the bottom edges of walls and clutter boxes, and (if enabled) the
near half of each moving obstacle's footprint. A sample point p at distance d is kept if it lies
in the sector (|bearing| ≤ fov/2, min_range ≤ d ≤ max_range) and no wall, clutter segment or disc
crosses the ray to it before d (painted lines hide nothing). Visible parts are sampled every
``point_spacing`` metres from a random phase per segment and frame, so successive frames do not
repeat the same floor points. Noise: isotropic ``N(0, σ(d)²)`` per axis with σ(d) = σ0 + k·d².
False points: Poisson(``false_points``) per frame, uniform over the sector's area.

Labels: map segment index ≥ 0 (painted line or wall), −2 moving obstacle, −3 clutter, −4 false.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.sim.config import CameraConfig
from fusion.sim.laser import CLUTTER, MOVING_OBSTACLE, SPURIOUS, visible_walls
from fusion.sim.raycast import ray_disc_distances
from houghloc.geometry import Pose, ray_segment_distances
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]

_OCCLUSION_EPS = 1e-6  # m: a point's own segment crosses its ray at exactly its distance


@dataclass(frozen=True)
class CameraFrame:
    """Robot-frame floor points (N×2) and the label of each."""

    points: FloatArray
    labels: NDArray[np.int16]


def _sample_segments(starts: FloatArray, ends: FloatArray, spacing: float,
                     rng: np.random.Generator) -> tuple[FloatArray, NDArray[np.intp]]:
    """Points every ``spacing`` along each segment from a random phase, and their segment index."""
    lengths = np.hypot(*(ends - starts).T)
    phase = rng.uniform(0.0, spacing, size=len(starts))
    n = np.maximum(np.floor((lengths - phase) / spacing).astype(int) + 1, 0)
    seg = np.repeat(np.arange(len(starts)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    frac = (phase[seg] + k * spacing) / lengths[seg]
    return starts[seg] + frac[:, None] * (ends - starts)[seg], seg


def _sample_disc_rims(discs: FloatArray, origin: FloatArray, spacing: float,
                      rng: np.random.Generator) -> tuple[FloatArray, NDArray[np.intp]]:
    """Points every ``spacing`` along each disc's rim, keeping the half that faces the camera."""
    n = np.maximum(np.ceil(2 * np.pi * discs[:, 2] / spacing).astype(int), 3)
    disc = np.repeat(np.arange(len(discs)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    ang = rng.uniform(0.0, 2 * np.pi, size=len(discs))[disc] + 2 * np.pi * k / n[disc]
    normal = np.column_stack((np.cos(ang), np.sin(ang)))
    pts = discs[disc, :2] + discs[disc, 2:3] * normal
    facing = np.einsum("ij,ij->i", normal, origin - pts) > 0.0
    return pts[facing], disc[facing]


def camera_points(m: SegmentMap, pose: Pose, rng: np.random.Generator,
                  cfg: CameraConfig | None = None, obstacles: FloatArray | None = None,
                  clutter: FloatArray | None = None) -> CameraFrame:
    """Simulate one camera frame from ``pose`` (map frame); see the module docstring.

    ``obstacles``: discs (D×3 rows ``[x, y, r]``); ``clutter``: segments (M×4 rows
    ``[x0, y0, x1, y1]``).
    """
    cfg = cfg or CameraConfig()
    x, y, th = (float(v) for v in pose)
    origin = np.array([x, y])
    discs = np.empty((0, 3)) if obstacles is None else np.asarray(obstacles, float).reshape(-1, 3)
    boxes = np.empty((0, 4)) if clutter is None else np.asarray(clutter, float).reshape(-1, 4)

    # Candidate features: map segments in range (walls and painted lines), clutter, disc rims.
    if len(m) < 64:
        near = np.arange(len(m))
    else:
        near = m.segments_near(origin, cfg.max_range)
    seg_pts, seg_idx = _sample_segments(
        np.vstack((m.starts[near], boxes[:, :2])), np.vstack((m.ends[near], boxes[:, 2:])),
        cfg.point_spacing, rng)
    seg_labels = np.concatenate((near, np.full(len(boxes), CLUTTER))).astype(np.int16)
    pts, labels = seg_pts, seg_labels[seg_idx]
    if cfg.see_obstacles and len(discs):
        rim_pts, _ = _sample_disc_rims(discs, origin, cfg.point_spacing, rng)
        pts = np.vstack((pts, rim_pts))
        labels = np.concatenate((labels, np.full(len(rim_pts), MOVING_OBSTACLE, np.int16)))

    # Sector test.
    rel = pts - origin
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = (np.arctan2(rel[:, 1], rel[:, 0]) - th + np.pi) % (2 * np.pi) - np.pi
    half_fov = 0.5 * np.radians(cfg.fov_deg)
    inside = (dist >= cfg.min_range) & (dist <= cfg.max_range) & (np.abs(bearing) <= half_fov)
    pts, labels, dist, rel = pts[inside], labels[inside], dist[inside], rel[inside]

    # Occlusion: anything solid crossing the ray before the point hides it.
    if len(pts):
        dirs = rel / dist[:, None]
        walls = visible_walls(m, origin, cfg.max_range)
        occ_s = np.vstack((m.starts[walls], boxes[:, :2]))
        occ_e = np.vstack((m.ends[walls], boxes[:, 2:]))
        t = ray_segment_distances(origin, dirs, occ_s, occ_e)
        first = t.min(axis=1) if t.shape[1] else np.full(len(pts), np.inf)
        if len(discs):
            first = np.minimum(first, ray_disc_distances(origin, dirs, discs).min(axis=1))
        seen = first >= dist - _OCCLUSION_EPS
        pts, labels, dist = pts[seen], labels[seen], dist[seen]

    # Triangulation noise grows with the square of the distance.
    sigma = cfg.sigma0 + cfg.k * dist**2
    pts = pts + sigma[:, None] * rng.standard_normal(pts.shape)

    # Isolated false points, uniform over the sector's area.
    n_false = rng.poisson(cfg.false_points)
    r = np.sqrt(rng.uniform(cfg.min_range**2, cfg.max_range**2, size=n_false))
    b = th + rng.uniform(-half_fov, half_fov, size=n_false)
    false_pts = origin + np.column_stack((r * np.cos(b), r * np.sin(b)))
    pts = np.vstack((pts, false_pts))
    labels = np.concatenate((labels, np.full(n_false, SPURIOUS, np.int16)))

    # To the robot frame: R(−θ)·(p − o).
    c, s = np.cos(th), np.sin(th)
    rel = pts - origin
    robot = np.column_stack((c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]))
    return CameraFrame(robot, labels.astype(np.int16))

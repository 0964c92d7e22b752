"""Run a scenario: route → true trajectory → odometry → moving obstacles → sensors.

Randomness: one ``numpy.random.SeedSequence(cfg.seed)`` spawns an independent generator per
subsystem (route, clutter, obstacles, odometry, laser, camera), so a run is a pure function of its
config, and switching one sensor on or off does not change what the others produce.

Clocks: odometry at ``t0 + k/odom_rate``, laser scans at ``t0 + k/laser.rate``, camera frames
captured at ``t0 + k/camera.rate`` and arriving ``latency`` later, ``t0 = cfg.start_time``.
Poses between integration steps are interpolated linearly.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.events import Event, Odometry, PointSet, Scan, Truth
from fusion.sim.camera import camera_points
from fusion.sim.config import ScenarioConfig
from fusion.sim.laser import LaserRecording, Occluders, beam_angles
from fusion.sim.odometry import simulate_odometry
from fusion.sim.poses import interpolate_poses
from fusion.sim.raycast import segments_cross
from fusion.sim.robot import drive
from fusion.sim.routes import Route, make_route
from fusion.sim.world import (
    discs_at,
    make_clutter,
    place_discs,
    resolve_map_path,
    simulate_obstacles,
    wall_segments,
)
from houghloc.geometry import compose, relative
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]


class SimulationError(RuntimeError):
    """A scenario that cannot be simulated as asked (a kidnap that leaves the route blocked)."""


@dataclass
class SimRun:
    """Everything a run produced. Poses are rows (x, y, θ); ``*_truth`` in the map frame,
    ``odom_pose``/``scan_odom`` in the odometry frame. Laser arrays are empty (K = 0) without a
    laser, camera lists empty without a camera.

    The scans themselves are cast on demand (:attr:`laser`), so a long run is written and
    replayed in memory bounded by one block of scans; :attr:`ranges` and :attr:`scan_labels`
    hold them all, for short runs."""

    config: ScenarioConfig
    map: SegmentMap
    map_path: Path
    route: Route
    clutter: FloatArray  # M×4 segments
    obstacle_radii: FloatArray  # D
    odom_t: FloatArray  # N
    odom_pose: FloatArray  # N×3, odometry frame
    odom_truth: FloatArray  # N×3, map frame
    kidnapped: NDArray[np.bool_]  # N−1: a kidnap between odometry records k and k+1
    odom_missing: NDArray[np.bool_]  # N: records not delivered (ScenarioConfig.odometry_gaps)
    scan_t: FloatArray  # K
    laser: LaserRecording | None  # the K scans, cast on demand; None without a laser
    angles: FloatArray  # B
    scan_truth: FloatArray  # K×3
    scan_odom: FloatArray  # K×3, odometry pose at the scan's time (for CARMEN FLASER)
    scan_obstacles: FloatArray  # K×D×2, obstacle centres at the scan times
    cam_t: FloatArray  # F, capture times
    cam_arrival: FloatArray  # F
    cam_points: list[FloatArray] = field(default_factory=list)  # F arrays of n_i×2, robot frame
    cam_labels: list[NDArray[np.int16]] = field(default_factory=list)
    cam_truth: FloatArray = field(default_factory=lambda: np.empty((0, 3)))  # F×3

    @cached_property
    def _all_scans(self) -> tuple[FloatArray, NDArray[np.int16]]:
        if self.laser is None:
            return np.empty((0, 0)), np.empty((0, 0), dtype=np.int16)
        return self.laser.all()

    @property
    def ranges(self) -> FloatArray:
        """K×B ranges of every scan (cast once, then kept)."""
        return self._all_scans[0]

    @property
    def scan_labels(self) -> NDArray[np.int16]:
        """K×B labels of what each beam hit (see :mod:`fusion.sim.laser`)."""
        return self._all_scans[1]

    @property
    def truth_t(self) -> FloatArray:
        """Times of the ground-truth records: every scan and every camera capture."""
        return np.union1d(self.scan_t, self.cam_t)

    @property
    def truth(self) -> FloatArray:
        """True poses at :attr:`truth_t`."""
        return interpolate_poses(self.truth_t, self.odom_t, self.odom_truth)

    def odom_in_map(self) -> FloatArray:
        """The odometry-only path in the map frame, anchored at the true start pose:
        ``truth₀ ⊕ (⊖odom₀ ⊕ odomₖ)``."""
        rel = relative(np.repeat(self.odom_pose[:1], len(self.odom_pose), axis=0),
                            self.odom_pose)
        return compose(self.odom_truth[0], rel)

    def events(self) -> Iterator[Event]:
        """All records in the order a localizer receives them: by arrival time (point sets by
        ``arrival``, everything else by ``t``); at equal times Odometry, Scan, Truth, PointSet."""
        max_range = self.config.laser.max_range if self.config.laser else np.inf

        def odometry() -> Iterator[tuple[float, int, int, Event]]:
            for k, (t, p, gone) in enumerate(zip(self.odom_t.tolist(), self.odom_pose.tolist(),
                                                 self.odom_missing.tolist(), strict=True)):
                if not gone:
                    yield t, 0, k, Odometry(t, p[0], p[1], p[2])

        def scans() -> Iterator[tuple[float, int, int, Event]]:
            if self.laser is None:
                return
            for k, (t, (r, _)) in enumerate(zip(self.scan_t.tolist(), self.laser.scans(),
                                                strict=True)):
                yield t, 1, k, Scan(t, r, self.angles, max_range=max_range)

        def truths() -> Iterator[tuple[float, int, int, Event]]:
            for k, (t, p) in enumerate(zip(self.truth_t.tolist(), self.truth.tolist(),
                                           strict=True)):
                yield t, 2, k, Truth(t, p[0], p[1], p[2])

        def point_sets() -> Iterator[tuple[float, int, int, Event]]:
            order = np.argsort(self.cam_arrival, kind="stable")
            for k in order.tolist():
                t, a = float(self.cam_t[k]), float(self.cam_arrival[k])
                yield a, 3, k, PointSet(t, self.cam_points[k], arrival=a)

        for *_, event in heapq.merge(odometry(), scans(), truths(), point_sets()):
            yield event


def _times(t0: float, duration: float, rate: float) -> FloatArray:
    return t0 + np.arange(math.floor(duration * rate + 1e-9) + 1) / rate


def simulate(cfg: ScenarioConfig, map_base: Path | None = None) -> SimRun:
    """Simulate the scenario. ``map_base``: directory to resolve a relative map path against
    first (a scenario file's directory); then the working directory and ``fusion/configs/maps``."""
    map_path = resolve_map_path(cfg.map, map_base)
    m = SegmentMap.from_yaml(map_path)
    seeds = np.random.SeedSequence(cfg.seed).spawn(6)
    # The laser's generator (seeds[4]) is made by the recording each time it is read.
    rng_route, rng_clutter, rng_obst, rng_odom, _, rng_cam = (
        np.random.default_rng(s) for s in seeds)

    dt = 1.0 / cfg.odom_rate
    n_steps = math.floor(cfg.duration * cfg.odom_rate + 1e-9) + 1
    odom_t = cfg.start_time + np.arange(n_steps, dtype=np.float64) * dt

    route = make_route(m, cfg.route, rng_route, length=1.2 * cfg.robot.v_max * cfg.duration + 5)
    _check_kidnaps(cfg)
    traj = drive(route, cfg.robot, dt, n_steps, cfg.kidnaps)
    _check_path(m, traj.poses, traj.kidnapped)
    odom = simulate_odometry(traj.motion, cfg.odometry, rng_odom)

    clutter = make_clutter(m, rng_clutter, cfg.clutter, avoid_paths=route.polyline())
    groups = [g for g in cfg.obstacles if g.count]
    discs0 = place_discs(m, rng_obst, groups, clutter, keep_away=traj.poses[0])
    per_disc = [(g.speed, g.turn_noise) for g in groups for _ in range(g.count)]
    speeds = np.array([s for s, _ in per_disc])
    turn_noise = np.array([n for _, n in per_disc])
    n_obst_steps = math.ceil(cfg.duration / cfg.obstacle_dt) + 2
    robot_xy = interpolate_poses(np.arange(n_obst_steps) * cfg.obstacle_dt + cfg.start_time,
                                 odom_t, traj.poses)[:, :2]
    track = simulate_obstacles(m, rng_obst, discs0, speeds, turn_noise, clutter, cfg.obstacle_dt,
                               n_obst_steps, robot_xy, cfg.robot.radius)
    radii = discs0[:, 2]

    # Laser.
    if cfg.laser is not None:
        scan_t = _times(cfg.start_time, cfg.duration, cfg.laser.rate)
        angles = beam_angles(cfg.laser)
        scan_truth = interpolate_poses(scan_t, odom_t, traj.poses)
        scan_discs = discs_at(scan_t - cfg.start_time, cfg.obstacle_dt, track, radii)
        laser: LaserRecording | None = LaserRecording(
            m, cfg.laser, angles, Occluders.build(m, clutter, cfg.transparent), scan_truth,
            scan_discs,
            seed=seeds[4])
        scan_odom = interpolate_poses(scan_t, odom_t, odom)
        scan_obstacles = scan_discs[:, :, :2].copy()
    else:
        scan_t, angles = np.empty(0), np.empty(0)
        laser = None
        scan_truth = scan_odom = np.empty((0, 3))
        scan_obstacles = np.empty((0, len(radii), 2))

    # Camera.
    cam_points: list[FloatArray] = []
    cam_labels: list[NDArray[np.int16]] = []
    if cfg.camera is not None:
        cam_t = _times(cfg.start_time, cfg.duration, cfg.camera.rate)
        cam_arrival = cam_t + cfg.camera.latency
        cam_truth = interpolate_poses(cam_t, odom_t, traj.poses)
        cam_discs = discs_at(cam_t - cfg.start_time, cfg.obstacle_dt, track, radii)
        for k in range(len(cam_t)):
            frame = camera_points(m, cam_truth[k], rng_cam, cfg.camera, cam_discs[k], clutter)
            cam_points.append(frame.points)
            cam_labels.append(frame.labels)
    else:
        cam_t = cam_arrival = np.empty(0)
        cam_truth = np.empty((0, 3))

    return SimRun(
        config=cfg, map=m, map_path=map_path, route=route, clutter=clutter,
        obstacle_radii=radii, odom_t=odom_t, odom_pose=odom, odom_truth=traj.poses,
        kidnapped=traj.kidnapped, odom_missing=_missing(cfg, odom_t), scan_t=scan_t,
        laser=laser, angles=angles,
        scan_truth=scan_truth, scan_odom=scan_odom,
        scan_obstacles=scan_obstacles, cam_t=cam_t, cam_arrival=cam_arrival,
        cam_points=cam_points, cam_labels=cam_labels, cam_truth=cam_truth,
    )


def path_crosses_walls(m: SegmentMap, poses: FloatArray,
                       skip: NDArray[np.bool_] | None = None, chunk: int = 4096
                       ) -> NDArray[np.bool_]:
    """For each step k→k+1 of a path, whether it touches or crosses a wall (skipped steps —
    kidnaps — are reported False)."""
    ws, we = wall_segments(m)
    out = np.zeros(max(len(poses) - 1, 0), dtype=bool)
    for i in range(0, len(out), chunk):
        a0, a1 = poses[i:i + chunk, :2], poses[i + 1:i + chunk + 1, :2]
        out[i:i + len(a1)] = segments_cross(a0[:len(a1)], a1, ws, we).any(axis=1)
    if skip is not None:
        out &= ~skip
    return out


def _check_path(m: SegmentMap, poses: FloatArray, kidnapped: NDArray[np.bool_]) -> None:
    bad = np.flatnonzero(path_crosses_walls(m, poses, kidnapped))
    if len(bad):
        x, y = poses[bad[0], :2]
        raise SimulationError(
            f"the robot's path crosses a wall near ({x:.2f}, {y:.2f}) at step {bad[0]}; "
            "after a kidnap the robot drives straight back to its route, so choose a kidnap that "
            "leaves the way back free")


def _missing(cfg: ScenarioConfig, odom_t: FloatArray) -> NDArray[np.bool_]:
    """Which odometry records fall in a gap (never the first: it anchors the frame)."""
    out = np.zeros(len(odom_t), dtype=bool)
    since = odom_t - cfg.start_time
    for gap in cfg.odometry_gaps:
        out |= (since >= gap.t) & (since < gap.t + gap.duration)
    if len(out):
        out[0] = False
    return out


def _check_kidnaps(cfg: ScenarioConfig) -> None:
    """Kidnaps must happen within the run; where they land is checked with the path."""
    for k in cfg.kidnaps:
        if k.t > cfg.duration:
            raise SimulationError(f"kidnap at t = {k.t} s is after the end of the run "
                                  f"({cfg.duration} s)")

"""The localizers the benchmark compares, each fed a :class:`~fusion.bench.data.Piece` the same
way: its events in order, its start pose, its map source. Each returns the pose at every scan
(at the scan's stamp) and the CPU time spent localizing (reading the log and building the map
excluded).

* ``houghloc``: :func:`fusion.run_log.run_log`, as ``houghloc run`` does.
* ``odometry``: dead reckoning from the start pose.
* ``icp``: scan-to-map point-to-point ICP (``small_gicp``) on the map's points, each scan
  started from the last estimate moved by the odometry since.
* ``amcl``/``amcl-tuned``/``amcl-beam``: nav2's AMCL (:mod:`fusion.bench.nav2_amcl`: nav2_amcl's
  own particle filter, motion model and likelihood field, or its beam model for ``amcl-beam``;
  the pose is the heaviest cluster's mean, as nav2 publishes) run as the nav2 node runs
  it: the filter is updated only once the odometry moved ``update_min_d`` or turned
  ``update_min_a`` since the last update (and on the first scan), resampling on every update
  (nav2's ``resample_interval: 1``), and between updates the pose is the last estimate carried
  forward by the odometry.
* ``mrpt``: MRPT's ``pf-localization`` (:mod:`fusion.bench.mrpt`), likelihood field.

The peers live in the optional extra ``houghloc[peers]``; a method whose package is missing
raises :class:`MissingPeer`, which the task records as its error.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.bench.data import Piece, scan_stamp
from fusion.bench.spec import Method
from fusion.config import LocalizerConfig, SensorConfig
from fusion.evaluation import Trajectory
from fusion.events import Odometry, Scan
from fusion.integrity import localized_probability
from houghloc.geometry import compose, ranges_to_points, relative, transform_points


class MissingPeer(RuntimeError):
    """A peer method whose package is not installed."""


@dataclass(frozen=True)
class Localized:
    trajectory: Trajectory
    cpu_seconds: float
    statuses: dict[str, int] | None = None
    scan_cpu: NDArray[np.float64] | None = None  # each scan's CPU seconds, when measured
    probability: NDArray[np.float64] | None = None
    """each pose's reported probability of being right, for a method that reports one"""


def localize(method: Method, piece: Piece, config: LocalizerConfig) -> Localized:
    """Run ``method`` on ``piece``; ``config`` is houghloc's (the peers read only its sensor)."""
    runner = {Method.HOUGHLOC: _houghloc, Method.ODOMETRY: _odometry, Method.ICP: _icp,
              Method.AMCL: _amcl, Method.AMCL_TUNED: _amcl, Method.AMCL_BEAM: _amcl,
              Method.MRPT: _mrpt}[method]
    return runner(piece, config, method)


def supports(method: Method, global_start: bool) -> bool:
    """Whether the method can start without a pose (dead reckoning and ICP cannot)."""
    return not global_start or method not in (Method.ODOMETRY, Method.ICP)


def laser(config: LocalizerConfig) -> SensorConfig:
    """The configuration's laser (its first sensor when none is called so)."""
    return config.sensors.get("laser") or next(iter(config.sensors.values()))


def base_points(scan: Scan, sensor: SensorConfig) -> NDArray[np.float64]:
    """The scan's returns in the robot frame, as the localizer sees them: beams beyond the
    sensor's or the scan's range dropped, then moved by the sensor's mount."""
    pts = ranges_to_points(scan.ranges, scan.angles, min(sensor.max_range, scan.max_range),
                           sensor.min_range)
    return pts if sensor.mount == (0.0, 0.0, 0.0) else transform_points(sensor.mount, pts)


def _houghloc(piece: Piece, config: LocalizerConfig, _method: Method) -> Localized:
    from fusion.localizer import compile_kernels
    from fusion.run_log import run_log

    segment_map = piece.map_source.segment_map
    # compiled before the clock starts, as a node compiles at start-up: the first run of a
    # worker would otherwise charge tens of seconds of compiling to its scans, where the
    # peers' start-up (AMCL's likelihood field) is not charged either
    compile_kernels(scan_matching=config.scan_odometry_sensor is not None)
    cpu = time.process_time()
    run = run_log(piece.events, segment_map, config, initial_pose=piece.start, progress=False,
                  time_scans=True)
    cpu = time.process_time() - cpu
    return Localized(run.result.trajectory, cpu, dict(run.localizer.stats.statuses),
                     run.result.scan_cpu, run.result.localized_probability)


class _DeadReckoning:
    """The odometry's motion since the previous call (the raw frame is arbitrary)."""

    def __init__(self) -> None:
        self.last: NDArray[np.float64] | None = None
        self.at_scan: NDArray[np.float64] | None = None

    def on_odometry(self, e: Odometry) -> None:
        pose = np.array((e.x, e.y, e.theta))
        if np.all(np.isfinite(pose)):
            self.last = pose

    def step(self) -> NDArray[np.float64]:
        """The odometry's motion since the previous scan, in the robot frame of that scan."""
        if self.last is None:
            return np.zeros(3)
        previous = self.at_scan if self.at_scan is not None else self.last
        self.at_scan = self.last
        return relative(previous, self.last)


def _predict_and_correct(piece: Piece, correct: Callable[[NDArray[np.float64], Scan],
                                                         NDArray[np.float64]]) -> Localized:
    """Each scan's pose: the last estimate moved by the odometry since, then ``correct``-ed."""
    assert piece.start is not None
    odom = _DeadReckoning()
    pose = piece.start.copy()
    t, poses = [], []
    cpu = time.process_time()
    for e in piece.events:
        if isinstance(e, Odometry):
            odom.on_odometry(e)
        elif isinstance(e, Scan):
            pose = correct(compose(pose, odom.step()), e)
            t.append(scan_stamp(e))
            poses.append(pose)
    return Localized(Trajectory(np.array(t), np.asarray(poses).reshape(-1, 3)),
                     time.process_time() - cpu)


def _odometry(piece: Piece, _config: LocalizerConfig, _method: Method) -> Localized:
    return _predict_and_correct(piece, lambda pose, _scan: pose)


ICP_MAX_CORRESPONDENCE = 0.5
"""m: a scan point pairs with a map point at most this far (1 m pairs across doorways: seattle
then loses 83 % of its first 400 poses instead of 17 %)."""
ICP_MAX_ITERATIONS = 100
"""Point-to-point ICP turns slowly: with small_gicp's default of 20, steps of 1 m and 15° (scans
kept as keyframes, 2–5 s apart) end mid-way (fhw's first 400 scans: 72 cm ATE, 4.3 cm with
100). The pose after the last iteration is taken even when not converged: each iteration
lowers the error."""


def _icp(piece: Piece, config: LocalizerConfig, _method: Method) -> Localized:
    try:
        import small_gicp
    except ImportError:
        raise MissingPeer("icp needs small_gicp: pip install 'houghloc[peers]'") from None
    sensor = laser(config)
    target_xy = piece.map_source.points
    target = small_gicp.PointCloud(np.column_stack((target_xy, np.zeros(len(target_xy)))))
    tree = small_gicp.KdTree(target)

    def align(pose: NDArray[np.float64], scan: Scan) -> NDArray[np.float64]:
        pts = base_points(scan, sensor)
        if len(pts) < 10:
            return pose
        source = small_gicp.PointCloud(np.column_stack((pts, np.zeros(len(pts)))))
        result = small_gicp.align(target, source, tree, _se2_to_matrix(pose),
                                  registration_type="ICP",
                                  max_correspondence_distance=ICP_MAX_CORRESPONDENCE,
                                  max_iterations=ICP_MAX_ITERATIONS)
        found = _matrix_to_se2(result.T_target_source)
        return found if np.all(np.isfinite(found)) else pose

    return _predict_and_correct(piece, align)


def _se2_to_matrix(pose: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    m = np.eye(4)
    m[:2, :2] = ((c, -s), (s, c))
    m[:2, 3] = pose[:2]
    return m


def _matrix_to_se2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array((m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])))


AMCL_NAV2: dict[str, Any] = {
    "laser_model_type": "likelihood_field", "min_particles": 500, "max_particles": 2000,
    "recovery_alpha_slow": 0.0, "recovery_alpha_fast": 0.0, "pf_err": 0.05, "pf_z": 0.99,
    "alpha": (0.2, 0.2, 0.2, 0.2, 0.2), "z_hit": 0.5, "z_short": 0.05, "z_max": 0.05,
    "z_rand": 0.5, "sigma_hit": 0.2, "lambda_short": 0.1, "chi_outlier": 0.05,
    "laser_likelihood_max_dist": 2.0, "max_beams": 60, "resample_interval": 1,
    "update_min_d": 0.25, "update_min_a": 0.2, "initial_sigma_xy": 0.5,
    "initial_sigma_theta": math.radians(15.0),
}
"""nav2_amcl's defaults (nav2_bringup's nav2_params.yaml, by nav2's names; the initial covariance
is RViz's 2D Pose Estimate default)."""

AMCL_TUNED = AMCL_NAV2 | {
    "alpha": (0.02, 0.02, 0.02, 0.02, 0.02), "z_hit": 0.9, "z_rand": 0.1, "sigma_hit": 0.1,
    "max_beams": 90, "update_min_d": 0.1, "update_min_a": 0.1, "min_particles": 1000,
    "max_particles": 5000,
}
"""One set for every building: finer updates, a sharper likelihood field (the maps' walls are
within centimetres), quieter odometry than nav2's conservative defaults, more particles. Chosen
among a few such sets on the same-run maps of all six buildings together (docs/benchmark.md)."""

AMCL_BEAM = AMCL_NAV2 | {"laser_model_type": "beam"}
"""nav2's defaults with its beam model (nav2's other laser model)."""

AMCL_SETS = {Method.AMCL: AMCL_NAV2, Method.AMCL_TUNED: AMCL_TUNED, Method.AMCL_BEAM: AMCL_BEAM}

AMCL_SEED = 1
"""The particle filter's random seed: a benchmark run repeats."""


def _amcl(piece: Piece, config: LocalizerConfig, method: Method) -> Localized:
    from fusion.bench.nav2_amcl import Nav2AmclUnavailable

    p = AMCL_SETS[method]
    sensor = laser(config)
    try:
        filt = _make_amcl(p, piece, sensor)
    except Nav2AmclUnavailable as error:
        raise MissingPeer(str(error)) from None
    odometry = iter(_odometry_at_scans(piece.events))
    last_update_odom: NDArray[np.float64] | None = None
    at_update = np.zeros(3)
    probability = 0.0
    t, poses, probabilities = [], [], []
    cpu = time.process_time()
    for e in piece.events:
        if not isinstance(e, Scan):
            continue
        odom = next(odometry)
        # nav2's test: the odometry-frame difference, per axis
        moved = None if last_update_odom is None else odom - last_update_odom
        if moved is None or (abs(moved[0]) > p["update_min_d"] or abs(moved[1]) > p["update_min_d"]
                             or abs(math.remainder(moved[2], math.tau)) > p["update_min_a"]):
            ranges, bearings, range_max = _amcl_scan(e, sensor)
            filt.update(odom, ranges, bearings, range_max)
            mean, cov, weighted = filt.estimate()
            if weighted or last_update_odom is None:
                at_update = mean
            last_update_odom = odom
            probability = localized_probability(cov, 1.0)
        # between updates, nav2 publishes the last estimate moved by the odometry since
        assert last_update_odom is not None
        t.append(scan_stamp(e))
        poses.append(compose(at_update, relative(last_update_odom, odom)))
        probabilities.append(probability)
    return Localized(Trajectory(np.array(t), np.asarray(poses).reshape(-1, 3)),
                     time.process_time() - cpu, probability=np.array(probabilities))


def _odometry_at_scans(events: tuple[Any, ...]) -> NDArray[np.float64]:
    """The odometry pose at each scan's stamp, interpolated between the readings around it, as
    nav2's AMCL looks up ``odom → base`` in tf at a scan's stamp (its message filter holds the
    scan until tf has it); with no reading at all, the odometry frame's origin."""
    from fusion.sim.poses import interpolate_poses

    scans = np.array([e.t for e in events if isinstance(e, Scan)], dtype=float)
    readings = np.array([(e.t, e.x, e.y, e.theta) for e in events
                         if isinstance(e, Odometry) and math.isfinite(e.x + e.y + e.theta)],
                        dtype=float).reshape(-1, 4)
    if len(readings) == 0:
        return np.zeros((len(scans), 3))
    return interpolate_poses(scans, readings[:, 0], readings[:, 1:])


def _make_amcl(p: dict[str, Any], piece: Piece, sensor: SensorConfig) -> Any:
    """nav2's AMCL on the piece's grid, started as its users start it: RViz's 2D Pose Estimate
    at the start pose, or ``reinitialize_global_localization`` (particles over the free cells)
    for a global start. The covariance it publishes with ``amcl_pose`` (its particles' spread)
    is what its users judge localization by; the benchmark scores it as houghloc's spread
    (:func:`fusion.integrity.localized_probability`, mode 1)."""
    from fusion.bench.nav2_amcl import Nav2Amcl

    filt = Nav2Amcl(min_particles=p["min_particles"], max_particles=p["max_particles"],
                    alpha_slow=p["recovery_alpha_slow"], alpha_fast=p["recovery_alpha_fast"],
                    alpha=p["alpha"], pf_err=p["pf_err"], pf_z=p["pf_z"],
                    resample_interval=p["resample_interval"], seed=AMCL_SEED)
    grid = piece.map_source.grid
    data = np.full(grid.shape, -1, dtype=np.int8)
    data[grid.free] = 0
    data[grid.occupied] = 100
    filt.set_map(data, grid.resolution, (grid.origin[0], grid.origin[1]),
                 p["laser_model_type"], p, p["max_beams"])
    filt.set_laser_pose(np.asarray(sensor.mount, dtype=float))
    if piece.start is None:
        filt.init_global()
    else:
        filt.init_pose(np.asarray(piece.start, dtype=float),
                       np.diag((p["initial_sigma_xy"] ** 2, p["initial_sigma_xy"] ** 2,
                                p["initial_sigma_theta"] ** 2)))
    return filt


def _mrpt(piece: Piece, config: LocalizerConfig, _method: Method) -> Localized:
    from fusion.bench.mrpt import MrptUnavailable, run_pf_localization

    try:
        trajectory, cpu = run_pf_localization(piece, laser(config))
    except MrptUnavailable as error:
        raise MissingPeer(str(error)) from None
    return Localized(trajectory, cpu)


def _amcl_scan(scan: Scan, sensor: SensorConfig
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The scan as nav2 gives it to the filter: ranges beyond the laser's range (or not finite)
    become its maximum, which the models ignore or score as max readings."""
    max_range = float(min(sensor.max_range, scan.max_range))
    ranges = np.asarray(scan.ranges, dtype=float)
    ranges = np.where(np.isfinite(ranges) & (ranges < max_range), ranges, max_range)
    return ranges, np.asarray(scan.angles, dtype=float), max_range

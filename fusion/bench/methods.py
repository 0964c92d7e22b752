"""The localizers the benchmark compares, each fed a :class:`~fusion.bench.data.Piece` the same
way: its events in order, its start pose, its map source. Each returns the pose at every scan
(at the scan's stamp) and the CPU time spent localizing (reading the log and building the map
excluded).

* ``houghloc``: :func:`fusion.run_log.run_log`, as ``houghloc run`` does.
* ``odometry``: dead reckoning from the start pose.
* ``icp``: scan-to-map point-to-point ICP (``small_gicp``) on the map's points, each scan
  started from the last estimate moved by the odometry since.
* ``amcl``/``amcl-tuned``: nav2's AMCL (the ``amcl`` wheel: nav2_amcl's particle filter, motion
  model and *beam* sensor model; the wheel has no likelihood field) run as the nav2 node runs
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
              Method.AMCL: _amcl, Method.AMCL_TUNED: _amcl, Method.MRPT: _mrpt}[method]
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
    from fusion.run_log import run_log

    segment_map = piece.map_source.segment_map
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
    "min_particles": 500, "max_particles": 2000, "alpha_slow": 0.0, "alpha_fast": 0.0,
    "alpha": (0.2, 0.2, 0.2, 0.2, 0.2), "z_hit": 0.5, "z_short": 0.05, "z_max": 0.05,
    "z_rand": 0.5, "sigma_hit": 0.2, "lambda_short": 0.1, "chi_outlier": 0.05, "max_beams": 60,
    "update_min_d": 0.25, "update_min_a": 0.2, "initial_sigma_xy": 0.5,
    "initial_sigma_theta": math.radians(15.0),
}
"""nav2_amcl's defaults (nav2_params.yaml; the initial covariance is RViz's 2D Pose Estimate
default), with the beam model's defaults since the wheel has no likelihood field."""

AMCL_TUNED = AMCL_NAV2 | {
    "alpha": (0.1, 0.05, 0.1, 0.05, 0.1), "z_hit": 0.9, "z_rand": 0.05, "sigma_hit": 0.05,
    "max_beams": 90, "update_min_d": 0.1, "update_min_a": 0.1,
}
"""One set for every building: finer updates and a sharper beam model (cm-accurate walls),
quieter odometry than nav2's conservative defaults."""


def _amcl(piece: Piece, config: LocalizerConfig, method: Method) -> Localized:
    try:
        import amcl
    except ImportError:
        raise MissingPeer("amcl needs the amcl wheel: pip install 'houghloc[peers]'") from None
    p = AMCL_TUNED if method is Method.AMCL_TUNED else AMCL_NAV2
    sensor = laser(config)
    filt = _make_amcl(amcl, p, piece, sensor)
    last_update_odom: NDArray[np.float64] | None = None
    at_update = np.zeros(3)
    probability = 0.0
    odom = np.zeros(3)  # no reading yet: the odometry frame's origin
    t, poses, probabilities = [], [], []
    cpu = time.process_time()
    for e in piece.events:
        if isinstance(e, Odometry):
            if math.isfinite(e.x + e.y + e.theta):
                odom = np.array((e.x, e.y, e.theta))
            continue
        if not isinstance(e, Scan):
            continue
        # nav2's test: the odometry-frame difference, per axis
        moved = None if last_update_odom is None else odom - last_update_odom
        if moved is None or (abs(moved[0]) > p["update_min_d"] or abs(moved[1]) > p["update_min_d"]
                             or abs(math.remainder(moved[2], math.tau)) > p["update_min_a"]):
            filt.update(_amcl_scan(amcl, e, sensor), amcl.Vector3D(*odom))
            m = filt.get_pose_mean()
            at_update, last_update_odom = np.array((m.x, m.y, m.theta)), odom
            probability = localized_probability(_amcl_covariance(filt), 1.0)
        # between updates, nav2 publishes the last estimate moved by the odometry since
        assert last_update_odom is not None
        t.append(scan_stamp(e))
        poses.append(compose(at_update, relative(last_update_odom, odom)))
        probabilities.append(probability)
    return Localized(Trajectory(np.array(t), np.asarray(poses).reshape(-1, 3)),
                     time.process_time() - cpu, probability=np.array(probabilities))


def _amcl_covariance(filt: Any) -> NDArray[np.float64]:
    """The covariance nav2 publishes with ``amcl_pose`` (that of its particles' pose), as a
    3×3 array: a user of AMCL judges whether the robot is localized from it, and the benchmark
    scores it as houghloc's spread (:func:`fusion.integrity.localized_probability`, mode 1)."""
    c = filt.get_pose_covariance()
    return np.array([[c.get(i, j) for j in range(3)] for i in range(3)], dtype=float)


def _make_amcl(amcl: Any, p: dict[str, Any], piece: Piece, sensor: SensorConfig) -> Any:
    motion = amcl.MotionParameters(*p["alpha"])
    beams = amcl.LaserParameters(p["z_hit"], p["z_short"], p["z_max"], p["z_rand"],
                                 p["sigma_hit"], p["lambda_short"], p["chi_outlier"],
                                 p["max_beams"])
    filt = amcl.AMCL(p["min_particles"], p["max_particles"], p["alpha_slow"], p["alpha_fast"],
                     motion, beams, "differential")
    grid = piece.map_source.grid
    rows, cols = grid.shape
    occ = amcl.OccupancyGrid(cols, rows, grid.resolution, grid.origin[0], grid.origin[1])
    data = np.full(grid.shape, -1, dtype=np.int8)
    data[grid.free] = 0
    data[grid.occupied] = 100
    occ.data = data.ravel().tolist()  # row-major with x fastest: nav2's cell order
    filt.set_map(occ)
    filt.set_laser_pose(amcl.Vector3D(*sensor.mount))
    cov = amcl.Matrix3D()
    if piece.start is None:  # global start: a Gaussian as wide as the map, headings uniform-ish
        x0, x1, y0, y1 = grid.extent
        mean = amcl.Vector3D(0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0)
        for i, v in enumerate((((x1 - x0) / 2) ** 2, ((y1 - y0) / 2) ** 2, math.pi**2)):
            cov.set(i, i, v)
    else:
        mean = amcl.Vector3D(*piece.start)
        for i, v in enumerate((p["initial_sigma_xy"] ** 2, p["initial_sigma_xy"] ** 2,
                               p["initial_sigma_theta"] ** 2)):
            cov.set(i, i, v)
    filt.set_initial_pose(mean, cov)
    return filt


def _mrpt(piece: Piece, config: LocalizerConfig, _method: Method) -> Localized:
    from fusion.bench.mrpt import MrptUnavailable, run_pf_localization

    try:
        trajectory, cpu = run_pf_localization(piece, laser(config))
    except MrptUnavailable as error:
        raise MissingPeer(str(error)) from None
    return Localized(trajectory, cpu)


def _amcl_scan(amcl: Any, scan: Scan, sensor: SensorConfig) -> Any:
    max_range = float(min(sensor.max_range, scan.max_range))
    ranges = np.asarray(scan.ranges, dtype=float)
    ranges = np.where(np.isfinite(ranges) & (ranges < max_range), ranges, max_range)
    return amcl.create_laser_scan_from_list(
        np.column_stack((ranges, np.asarray(scan.angles, dtype=float))).tolist(), max_range)

"""The streaming localizer: odometry predicts, Hough fixes correct (docs/architecture.md).

    on_odometry ─▶ tracker.predict                    (EKF, history for late data)
    on_scan ─▶ points ─▶ admit ─▶ predict ─▶ localize ─▶ decide ─▶ apply ─▶ manage ─▶ estimate
                           └─▶ (scan odometry: ICP to the previous scan ─▶ tracker.correct_odometry)

Follow one scan: :meth:`Localizer.on_points` is the whole story.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.ambiguity.manager import AmbiguityManager
from fusion.config import LocalizerConfig, SensorConfig
from fusion.corridor import CorridorMeasurement
from fusion.decision import FixDecider, FixDecision, TrackingScan
from fusion.ekf import UpdateOutcome
from fusion.estimate import Estimate, LocalizerStats
from fusion.events import MAX_POSE_COORDINATE
from fusion.io.timing import MAX_TIME_STEP, HeldOdometry, OdometryReading
from fusion.motion import OdometryCalibration
from fusion.points_fix import PointsMeasurement
from fusion.scan_odometry import ScanOdometry
from fusion.scan_odometry import warm_up as warm_up_scan_matching
from fusion.status import ScanStatus, State
from fusion.tracker import PoseTracker
from fusion.tracker import warm_up as warm_up_filter
from fusion.visualize import Logger, NullLogger
from fusion.wheel_noise import WheelNoiseLearner
from fusion.wheel_scale import WheelScaleLearner
from houghloc import ScanCorrection, SegmentMap, localize_scan
from houghloc.geometry import ranges_to_points, transform_points, within_range
from houghloc.scan_points import clean_points
from houghloc.warm_up import warm_up

log = logging.getLogger(__name__)
LOGGED_WARNINGS = 20  # of each kind, as they happen; metrics.json counts them all


def compile_kernels(scan_matching: bool = True) -> None:
    """Compile every kernel a localizer runs per scan, or load it from Numba's cache, once per
    process, as a node does at start-up: the Hough path's, the filter's and, with scan
    odometry (``scan_matching``), the scan matcher's."""
    warm_up()
    warm_up_filter()
    if scan_matching:
        warm_up_scan_matching()


class Localizer:
    """Wheel odometry fused with Hough-transform pose fixes in an EKF, one event at a time.

    Longer than most classes here (about 370 lines) because it is the one place where bad
    input meets the filter: every entry point (odometry, scans, points, landmarks) states and
    applies its rule for stray stamps, non-finite values and unknown sensors before the steps
    of :meth:`on_points`, which read as the algorithm."""

    def __init__(self, map: SegmentMap, config: LocalizerConfig | None = None,
                 initial_pose: ArrayLike | None = None, logger: Logger | None = None) -> None:
        self.map = map
        self.config = config or LocalizerConfig()
        self.logger = logger or NullLogger()
        # the compiled kernels, before the first scan rather than on it
        compile_kernels(scan_matching=self.config.scan_odometry_sensor is not None)
        fc = self.config.filter
        if initial_pose is None:
            initial_pose = self.config.initial_pose
        pose = np.zeros(3) if initial_pose is None else np.asarray(initial_pose, dtype=float)
        # the pose the run started from (None: global localization), for metrics.json
        self.initial_pose = None if initial_pose is None else pose.copy()
        if initial_pose is not None:
            self._check_initial_pose(pose)
        self.tracker = PoseTracker.from_config(fc, pose)
        self.stats = LocalizerStats()
        calibration = OdometryCalibration(fc.motion.translation_scale, fc.motion.rotation_scale)
        # the wheels' scale learned from full fixes (None: the configured one, as it is)
        self.wheel_scale = (None if fc.wheel_scale.sigma is None else WheelScaleLearner(
            fc.wheel_scale, fc.motion.translation_scale))
        self._calibrate = (None if calibration.identity and self.wheel_scale is None
                           else calibration)
        self._scan_odometry_sensor = self.config.scan_odometry_sensor
        # the wheels' random noise learned from the scan matches (None: as configured)
        self.wheel_noise = (None if self._scan_odometry_sensor is None
                            or not fc.wheel_noise.enabled
                            else WheelNoiseLearner(fc.wheel_noise, fc.motion,
                                                   fc.wheel_scale.wheel_noise))
        self.scan_odometry = (None if self._scan_odometry_sensor is None else
                              ScanOdometry(self.config.scan_odometry, self.tracker.motion,
                                           self.wheel_noise))
        self.manager = AmbiguityManager(map, self.config.ambiguity, logger=self.logger,
                                        make_tracker=self._tracker_at)
        self.decider = FixDecider(map, self.manager.fit, self.config.ambiguity.hypotheses)
        # the map's look-ups for global matching, now rather than on the scan that first needs
        # them (the angle index and distance transform of a building take tens of ms)
        for kinds in {s.hough.reference_kinds for s in self.config.sensors.values()}:
            self.manager.prepare(kinds)
        self.logger.log_map(map)
        self._held_odometry = HeldOdometry()
        self._start_reason = "initial pose given"
        if initial_pose is None:
            self.manager.start_lost(0.0, "no initial pose: global localization")
            self._start_reason = "no initial pose: global localization"

    def _tracker_at(self, pose: NDArray[np.float64], cov: NDArray[np.float64],
                    t: float) -> PoseTracker:
        """A filter with this localizer's settings and odometry whose estimate at ``t`` is the
        pose (a followed hypothesis's)."""
        return self.tracker.branch(pose, cov, t)

    def _check_initial_pose(self, pose: NDArray[np.float64]) -> None:
        """A ValueError for a pose that is no pose, or so far from the map that no sensor of
        the robot could see any of it (a typo, or another map's frame)."""
        if pose.shape != (3,) or not np.isfinite(pose).all():
            raise ValueError(f"initial pose {pose.tolist()}: expected three finite numbers")
        reach = max(s.max_range for s in self.config.sensors.values())
        self.map.check_within_reach(pose[:2], reach, "initial pose")

    @classmethod
    def from_config(cls, config: str | Path | LocalizerConfig | None, map: SegmentMap,
                    initial_pose: ArrayLike | None = None,
                    logger: Logger | None = None) -> Localizer:
        cfg = config if isinstance(config, LocalizerConfig) else LocalizerConfig.from_yaml(config)
        return cls(map, cfg, initial_pose, logger)

    @property
    def localized(self) -> bool:
        """Tracking at the end, and for at least half of the scans: the run can be trusted."""
        return self.manager.state is State.TRACKING and self.stats.tracked_fraction >= 0.5

    def summary(self) -> dict[str, Any]:
        """What became of every input so far, by the parts that decided it: the filter's
        updates and refusals, the fixes' statuses, the manager's states and counts, the wheel
        scale learned and scan odometry's matches; the configuration last (``metrics.json``
        reports this beside the run's own figures)."""
        config = self.config.as_dict()
        start = self.initial_pose
        config["initial_pose"] = None if start is None else [float(v) for v in start]
        doc: dict[str, Any] = {"initial_pose": config["initial_pose"],
                               **self.stats.summary(self.tracker.counts),
                               "localized": self.localized, "ambiguity": self.manager.summary()}
        if self.wheel_scale is not None:
            doc["wheel_scale"] = self.wheel_scale.summary()
        if self.wheel_noise is not None:
            doc["wheel_noise"] = self.wheel_noise.summary()
        if self.scan_odometry is not None:
            doc["scan_odometry"] = {"matched": self.scan_odometry.matched,
                                    "unmatched": self.scan_odometry.unmatched}
        doc["config"] = config
        return doc

    @property
    def pose(self) -> NDArray[np.float64]:
        return self.tracker.pose

    @property
    def cov(self) -> NDArray[np.float64]:
        return self.tracker.cov

    def on_odometry(self, t: float, x: float, y: float, theta: float,
                    unmeasured: float = 0.0) -> None:
        """Predict with the odometry increment since the last reading (its frame is arbitrary),
        after removing the configured scale errors (``filter.motion.*_scale``) and, with scan
        odometry, in the frame the scan matches corrected. ``unmeasured``: seconds before t whose
        motion the increment misses (:class:`fusion.events.Odometry`).

        Time (:class:`fusion.io.timing.HeldOdometry`): a reading more than ``MAX_TIME_STEP``
        after the previous one is held until the next confirms it (at or after it) or shows it
        a stray stamp (before it: dropped and counted in ``stats.stray_timestamps``). A reading
        that cannot be a pose (non-finite, or beyond ``MAX_POSE_COORDINATE``) is dropped and
        counted; the chain continues from the last good reading."""
        if not (all(map(math.isfinite, (t, x, y, theta)))
                and max(abs(x), abs(y), abs(theta)) <= MAX_POSE_COORDINATE):
            self.stats.invalid_odometry += 1
            if self.stats.invalid_odometry <= LOGGED_WARNINGS:
                log.warning("odometry at t = %s cannot be a pose (%s, %s, %s): dropped, the chain "
                            "goes on from the last good reading", t, x, y, theta)
            return
        reading = OdometryReading(t, x, y, theta, unmeasured if math.isfinite(unmeasured) else 0.0)
        confirmed, stray = self._held_odometry.next_reading(t)
        if confirmed is not None:
            self._use_odometry(*confirmed)
        if stray is not None:
            self.stats.stray_timestamps += 1
            if self.stats.stray_timestamps <= LOGGED_WARNINGS:
                log.warning("odometry at t = %s jumped ahead of the readings before and "
                            "after it (t = %s): dropped", stray.t, t)
        if not self._held_odometry.hold(reading, self.tracker.odometry_time):
            self._use_odometry(*reading)

    def _use_odometry(self, t: float, x: float, y: float, theta: float,
                      unmeasured: float = 0.0) -> None:
        learner = self.wheel_scale
        if learner is not None:
            learner.on_wheels(t, x, y, theta, broken=unmeasured > 0.0)
        if self._calibrate is not None:
            if learner is not None:
                self._calibrate.translation_scale = learner.value
                self.tracker.motion.scale_variance = (learner.sigma / learner.value) ** 2
            x, y, theta = self._calibrate(x, y, theta)
        if self.scan_odometry is not None and math.isfinite(x + y + theta):
            x, y, theta = self.scan_odometry.on_wheels(x, y, theta, unmeasured, t)
        jumps = self.tracker.counts.odometry_jumps
        self.tracker.on_odometry(t, x, y, theta, unmeasured)
        self.manager.on_odometry(t, x, y, theta, unmeasured)
        if learner is not None and self.tracker.counts.odometry_jumps > jumps:
            learner.forget()  # the wheels' path across a jump is no chord of the robot's
        self.logger.log_odometry(t, (x, y, theta))

    def on_scan(self, t: float, ranges: ArrayLike, angles: ArrayLike,
                sensor: str = "laser", max_range: float = math.inf) -> Estimate:
        """A range scan: beams to points (NaN, infinite and no-return beams dropped), then fused.

        ``max_range``: the scan's own no-return range (e.g. a LaserScan's ``range_max``); returns
        at or beyond it, or beyond the sensor's configured ``max_range``, are no returns.
        """
        cfg = self._sensor(sensor)
        points = ranges_to_points(ranges, angles, min(cfg.max_range, max_range), cfg.min_range)
        return self.on_points(t, points, sensor)

    def on_points(self, t: float, points: ArrayLike, sensor: str = "camera") -> Estimate:
        """Points in the sensor frame taken at time ``t`` (possibly in the past): fuse them.

        0. admit: the scan's stamp is checked against the odometry's clock, its points cleaned
           and moved to the robot frame; with scan odometry, the motion since the previous scan
           is corrected by matching them (:meth:`_admit`). Unless tracking, the scan is a view
           for global localization (:meth:`_global_step`).
        1. predict: the estimate at ``t`` is the guess; its covariance sets the matching gates;
        2. localize: the Hough method turns the points into a pose fix with its covariance and
           rank (:func:`houghloc.localize_scan`);
        3. decide: whether the fix becomes a measurement, and which one
           (:class:`fusion.decision.FixDecider`);
        4. apply: the filter takes it at ``t`` (late ones re-propagate the odometry since),
           gated by its normalised innovation;
        5. manage: a local re-search where the scan fits worse than usual, whether tracking
           is given up, and the estimate (:meth:`_manage`).
        """
        cfg = self._sensor(sensor)
        admitted = self._admit(t, points, sensor, cfg)
        if isinstance(admitted, Estimate):
            return admitted  # a stray stamp: not used
        if self.manager.state is not State.TRACKING:
            self._forget_chord()
            return self._global_step(t, admitted, sensor)
        scan = self._predict(t, admitted, sensor, cfg)
        if scan is None:
            return self._finish(t, ScanStatus.DROPPED, None, None, sensor, admitted)
        with self.stats.timed("hough"):
            fix = localize_scan(scan.points, self.map, scan.guess, scan.hough,
                                pose_cov=scan.guess_cov)
        with self.stats.timed("update"):
            decision = self.decider.decide(scan, fix)
            status, outcome = self._apply_decision(scan, fix, decision)
        return self._manage(scan, fix, decision, status, outcome)

    def _admit(self, t: float, points: ArrayLike, sensor: str, cfg: SensorConfig
               ) -> NDArray | Estimate:
        """The scan's finite points in the robot frame within the sensor's range, after the
        odometry it confirms and scan odometry's correction; or the estimate of a scan that
        is not used (its stamp far ahead of the odometry)."""
        if self.stats.scans == 0:  # the recording starts with the state and why
            self.logger.log_state(t, self.manager.state.value, self._start_reason)
        self.stats.scans += 1
        confirmed = self._held_odometry.scan_at(t)
        if confirmed is not None:
            self._use_odometry(*confirmed)
        clock = self.tracker.odometry_time
        if not math.isfinite(t) or (clock is not None and t - clock > MAX_TIME_STEP):
            # a scan far ahead of the odometry is a stray stamp (or the odometry stopped): its
            # pose is unknown, and applying it would move the filter's clock past every later
            # reading
            self.stats.stray_timestamps += 1
            if self.stats.stray_timestamps <= LOGGED_WARNINGS:
                log.warning("scan at t = %s is %s s ahead of the odometry: not used", t,
                            t - clock if clock is not None else "inf")
            return self._finish(t if math.isfinite(t) else (clock or 0.0), ScanStatus.DROPPED, None,
                                None, sensor, np.empty((0, 2)))
        # NaN/inf points are no returns; every stage below (scan odometry too) gets finite ones
        cleaned = clean_points(np.asarray(points, dtype=float).reshape(-1, 2))[0]
        # a point beyond the sensor's range is no measurement of it (and 1e300 would overflow
        # every stage after): the same rule as for a scan's ranges
        cleaned = _to_base(within_range(cleaned, cfg.max_range), cfg)
        if self.scan_odometry is not None and sensor == self._scan_odometry_sensor:
            with self.stats.timed("scan odometry"):
                self._correct_odometry(t, cleaned)
        return cleaned

    def _predict(self, t: float, points: NDArray, sensor: str, cfg: SensorConfig
                 ) -> TrackingScan | None:
        """The scan as the stages after the prediction see it: the filter's guess at ``t`` with
        its covariance (None when the filter has no pose at ``t``)."""
        prior = self.tracker.pose_at(t)
        if prior is None:
            return None
        scans_broke = (self.scan_odometry is not None and sensor == self._scan_odometry_sensor
                       and self.scan_odometry.broke)
        return TrackingScan(t, points, sensor, cfg.hough, cfg.min_fix_lines, prior[0], prior[1],
                            scans_broke)

    def _apply_decision(self, scan: TrackingScan, fix: ScanCorrection, decision: FixDecision
                        ) -> tuple[ScanStatus, UpdateOutcome | None]:
        """Offer the decision's measurement to the filter: the scan's status (the filter's
        outcome's for a used fix, the verdict's otherwise) and the outcome (None when nothing
        was offered). A full fix accepted as it is ends a chord of the wheels' scale."""
        verdict, measurement = decision.verdict, decision.measurement
        outcome = (None if measurement is None else
                   self._apply(scan.t, measurement.pose, measurement.cov, measurement.basis))
        if not verdict.use:
            assert verdict.status is not None
            self.stats.points_fixes += decision.by_points is not None
            return verdict.status, outcome
        assert outcome is not None  # a used fix is always offered
        self.stats.placed_along += decision.along is not None
        self.stats.partial_rank += decision.partial
        if (self.wheel_scale is not None and outcome.accepted and fix.rank == 3
                and decision.along is None):
            self.wheel_scale.on_fix(scan.t, fix.pose, fix.cov)  # a full fix: a chord's end
        return ScanStatus(outcome.status), outcome

    def _manage(self, scan: TrackingScan, fix: ScanCorrection, decision: FixDecision,
                status: ScanStatus, outcome: UpdateOutcome | None) -> Estimate:
        """The manager's turn after the filter's: a local re-search where the scan fits worse
        than usual (its pose re-initialises the filter), then whether tracking is given up,
        then the estimate, whose probability so holds what this scan said against tracking."""
        t, verdict = scan.t, decision.verdict
        along, by_points = decision.along, decision.by_points
        with self.stats.timed("local"):
            re_searched = self.manager.re_search(scan, status, verdict, fix,
                                                 lambda: self.tracker.odometry_at(t))
        if (re_searched is not None and re_searched.reset_pose is not None
                and re_searched.reset_cov is not None
                and self.tracker.reset(re_searched.reset_pose, re_searched.reset_cov, t)):
            status, outcome, along, by_points = ScanStatus.RE_SEARCHED, None, None, None
            self._forget_chord()
        pose, cov = self._filter_at(t)
        refs = fix.references
        # the manager gives tracking up here, when the scans stop giving usable fixes; the
        # estimate is made after, so that its probability holds this scan's evidence too
        self.manager.tracking_step(t, status, cov, pose, self.tracker.odometry_at(t),
                                   None if refs is None else (refs.theta, refs.rho),
                                   verdict.guess_fit, scan.points, scan.kinds)
        return self._finish(t, status, fix, outcome, scan.sensor, scan.points, (pose, cov),
                            along=along, by_points=by_points)

    def _forget_chord(self) -> None:
        """The belief jumped or was given up: a fix before it and one after are no chord."""
        if self.wheel_scale is not None:
            self.wheel_scale.forget()

    def _correct_odometry(self, t: float, points: NDArray) -> None:
        """The odometry at the scan corrected by matching it to the previous scan."""
        scan_odometry = self.scan_odometry
        assert scan_odometry is not None  # called only with scan odometry on
        correction = scan_odometry.match(t, points)
        if self.wheel_noise is not None:
            self.tracker.motion.translation_factor = self.wheel_noise.factor
        if correction is not None:
            if self.tracker.correct_odometry(t, correction.pose, correction.since,
                                             correction.step_cov, correction.step_scale):
                self.manager.correct_odometry(t, correction.pose, correction.since,
                                              correction.step_cov, correction.step_scale)
                scan_odometry.commit(correction)
                self.logger.log_odometry(t, correction.pose)  # the odometry path shows it
            else:
                scan_odometry.skip(t, points)
        # the next scan's match replaces the wheels' noise since this one: the filter keeps
        # its history back to here
        since = scan_odometry.reference_time
        self.tracker.hold(since, since + self.config.scan_odometry.max_interval)

    def _apply(self, t: float, pose: NDArray, cov: NDArray, basis: NDArray | None
               ) -> UpdateOutcome:
        """Offer a pose measurement taken at ``t`` to the filter, counting it late when the
        filter has a newer reading."""
        newest = self.tracker.time
        if newest is not None and t < newest:
            self.stats.late += 1
        return self.tracker.apply(t, pose, cov, basis)

    def on_landmark(self, t: float, label: str, bearing: float) -> None:
        """A recognised landmark (e.g. a goal by its colour) at a bearing: while the map's
        symmetry leaves several poses, it tells them apart; while tracking it is not used."""
        position = self.map.landmarks.get(label)
        odom = self.tracker.odometry_at(t)
        if position is None or odom is None or self.manager.state is State.TRACKING:
            return
        decision = self.manager.landmark_step(t, odom, position, bearing, label)
        if decision.reset_pose is not None and decision.reset_cov is not None:
            self.tracker.reset(decision.reset_pose, decision.reset_cov, t)

    def _global_step(self, t: float, points: NDArray, sensor: str) -> Estimate:
        """Strategy (ii): accumulate this view; the manager may find the pose and re-initialise
        the filter; until then the estimate is odometry only, reported with the state."""
        odom = self.tracker.odometry_at(t)
        if odom is None:  # no odometry yet: views cannot be related, wait for it
            return self._finish(t, ScanStatus.of_state(self.manager.state), None, None, sensor,
                                points)
        hough = self._sensor(sensor).hough
        with self.stats.timed("global"):
            decision = self.manager.collecting_step(t, odom, points, hough.reference_kinds, hough)
        if decision.reset_pose is not None and decision.reset_cov is not None:
            self.tracker.reset(decision.reset_pose, decision.reset_cov, t)
            return self._finish(t, ScanStatus.RELOCALIZED, None, None, sensor, points)
        return self._finish(t, ScanStatus.of_state(self.manager.state), None, None, sensor, points,
                            self.manager.leading_hypothesis)

    def _finish(self, t: float, status: ScanStatus, fix: ScanCorrection | None,
                outcome: UpdateOutcome | None, sensor: str, points: NDArray,
                reported: tuple[NDArray, NDArray] | None = None,
                along: CorridorMeasurement | None = None,
                by_points: PointsMeasurement | None = None) -> Estimate:
        """The estimate at ``t``: the ``reported`` pose and covariance (while several hypotheses
        are followed, the leading one's: the likeliest pose, its status says it is not yet
        taken), else the filter's."""
        self.stats.statuses[status] = self.stats.statuses.get(status, 0) + 1
        pose, cov = reported if reported is not None else self._filter_at(t)
        estimate = Estimate(t, pose, cov, status, fix, outcome, along, by_points,
                            self.manager.mode_probability)
        self.logger.log_scan(t, self.stats.scans - 1, sensor, points, fix, estimate)
        return estimate

    def _filter_at(self, t: float) -> tuple[NDArray, NDArray]:
        """The filter's pose and covariance at ``t`` (its newest when it holds none at t)."""
        at_t = self.tracker.pose_at(t)
        return at_t if at_t is not None else (self.tracker.pose, self.tracker.cov)

    def _sensor(self, name: str) -> SensorConfig:
        try:
            return self.config.sensors[name]
        except KeyError:
            known = ", ".join(self.config.sensors)
            raise KeyError(f"sensor {name!r} is not configured (configured: {known})") from None


def _to_base(points: NDArray, cfg: SensorConfig) -> NDArray:
    """Sensor-frame points to the robot frame (the Hough method works about the robot's origin)."""
    if cfg.mount == (0.0, 0.0, 0.0) or len(points) == 0:
        return points
    return transform_points(np.asarray(cfg.mount), points)

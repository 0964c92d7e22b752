"""The poses a benchmark run lost, each read against the other witnesses of the robot's motion.

A reference built by a SLAM system (the corrected logs' GMapping poses) has errors of its own, so
a pose scored lost may be the reference's error rather than the localizer's. Beside each lost
pose this prints:

* the step from the scan before, as the reference, the estimate, the wheels and a scan-to-scan
  match see it (:func:`fusion.scan_icp.point_to_line_icp` started at the wheels' step: it uses
  no map and no reference);
* the share of the scan's points on the map's walls at the reference pose and at the estimate
  (:meth:`fusion.ambiguity.fit.ScanFit.fractions`, the measure the localizer judges fixes by).

A reference step that both the wheels and the match contradict, or an estimate that puts more
of the scan on the walls than the reference pose does, points at the reference; an estimate whose
own step is the odd one out points at the localizer. Nothing is decided here: the evidence is
printed, and read by whoever judges the run.

    python -m fusion.bench.losses --spec benchmarks/real.yaml --sweep runs/bench-real

Each task of the sweep is read with its own settings (a spec's ``grid``), which change the fit
and the scan match as they changed the run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.bench.methods import base_points, laser
from fusion.bench.task import LOST_HEADING_DEG, LOST_POSITION
from fusion.config import LocalizerConfig, SensorConfig
from fusion.evaluation.metrics import ATE, LostFraction
from fusion.evaluation.trajectory import Trajectory
from fusion.events import Event, Odometry, Scan
from fusion.motion import interpolate
from fusion.scan_icp import point_to_line_icp
from houghloc.geometry import relative
from houghloc.segment_map import SegmentMap


@dataclass(frozen=True, slots=True)
class Step:
    """A motion between two scans in the robot frame of the first: (dx, dy, dθ)."""

    delta: NDArray[np.float64]

    @property
    def distance(self) -> float:
        return math.hypot(self.delta[0], self.delta[1])

    @property
    def turn_deg(self) -> float:
        return math.degrees(self.delta[2])

    def __str__(self) -> str:
        return f"{100 * self.distance:.1f} cm, {self.turn_deg:+.1f}°"


@dataclass(frozen=True, slots=True)
class LostPose:
    """One lost pose and what else measured the robot there."""

    t: float
    position_error: float
    """m between the estimate and the reference"""
    heading_error_deg: float
    """estimate − reference, wrapped to ±180°"""
    reference_step: Step | None
    """from the scan before (None for a run's first scan)"""
    estimate_step: Step | None
    wheel_step: Step | None
    match_step: Step | None
    """the scan-to-scan match's (None where it did not converge)"""
    match_overlap: float
    on_walls_reference: float
    on_walls_estimate: float


def wheel_poses(events: Iterable[Event]) -> Trajectory:
    """The odometry readings of ``events`` in time order (non-finite ones dropped)."""
    readings = sorted((e.t, e.x, e.y, e.theta) for e in events if isinstance(e, Odometry)
                      and all(map(math.isfinite, (e.t, e.x, e.y, e.theta))))
    data = np.array(readings, dtype=float).reshape(-1, 4)
    return Trajectory(data[:, 0], data[:, 1:])


def wheels_at(wheels: Trajectory, t: float) -> NDArray[np.float64] | None:
    """The odometry pose at ``t``, interpolated between the readings around it (None outside
    them)."""
    k = int(np.searchsorted(wheels.t, t))
    if k < len(wheels) and wheels.t[k] == t:
        return wheels.poses[k]
    if k == 0 or k == len(wheels):
        return None
    t0, t1 = wheels.t[k - 1], wheels.t[k]
    return interpolate(wheels.poses[k - 1], wheels.poses[k], (t - t0) / (t1 - t0))


def lost_poses(scans: Sequence[Scan], estimate: Trajectory, reference: Trajectory,
               wheels: Trajectory, segment_map: SegmentMap,
               config: LocalizerConfig | None = None, max_dt: float = 0.006,
               from_first_right: bool = False) -> list[LostPose]:
    """The scans whose estimate (pose ``i`` of ``estimate`` for ``scans[i]``, at the time the
    localizer wrote it) the benchmark scores lost (:func:`fusion.bench.task.score`'s ATE and
    lost test: paired one to one within ``max_dt``, lost beyond ``LOST_POSITION`` or
    ``LOST_HEADING_DEG``), each with the steps from the judged scan before and its shares on
    ``segment_map``'s walls. ``from_first_right``: only the losses after the estimate was first
    right (a global start's; those before are its search for a first pose)."""
    config = config or LocalizerConfig()
    if len(estimate) != len(scans):
        raise ValueError(f"{len(estimate)} estimated poses for {len(scans)} scans")
    ate = ATE(max_dt=max_dt).compute(estimate, reference)
    lost = LostFraction(LOST_POSITION, LOST_HEADING_DEG, max_dt).from_ate(ate).lost
    pairs = ate.association
    first_right = (_first_right(estimate.t[pairs.est_index], lost) if from_first_right
                   else -math.inf)
    sensor = laser(config)
    fit = ScanFit(segment_map, config.ambiguity)
    out: list[LostPose] = []
    previous: _Judged | None = None
    for n, (i, j) in enumerate(zip(pairs.est_index.tolist(), pairs.ref_index.tolist(),
                                   strict=True)):
        judged = _Judged(scans[i], reference.poses[j], estimate.poses[i])
        if lost[n] and estimate.t[i] > first_right:
            points = base_points(judged.scan, sensor)
            on_ref, on_est = fit.fractions(np.stack([judged.reference, judged.estimate]),
                                           points, sensor.hough.reference_kinds)
            steps = _steps(previous, judged, points, wheels, sensor, config)
            out.append(LostPose(float(estimate.t[i]), float(ate.position_errors[n]),
                                math.degrees(ate.heading_errors[n]), *steps, float(on_ref),
                                float(on_est)))
        previous = judged
    return out


def _first_right(times: NDArray[np.float64], lost: NDArray[np.bool_]) -> float:
    """The time of the first judged pose that is not lost (∞ when none is)."""
    right = times[~lost]
    return float(right.min()) if len(right) else math.inf


@dataclass(frozen=True, slots=True)
class _Judged:
    """A scan with both a reference pose and an estimate."""

    scan: Scan
    reference: NDArray[np.float64]
    estimate: NDArray[np.float64]


def _steps(previous: _Judged | None, current: _Judged, points: NDArray[np.float64],
           wheels: Trajectory, sensor: SensorConfig, config: LocalizerConfig
           ) -> tuple[Step | None, Step | None, Step | None, Step | None, float]:
    """The reference's, the estimate's, the wheels' and the scan match's steps from the judged
    scan before, and the match's overlap."""
    if previous is None:
        return None, None, None, None, math.nan
    reference = Step(relative(previous.reference, current.reference))
    estimated = Step(relative(previous.estimate, current.estimate))
    w0, w1 = wheels_at(wheels, previous.scan.t), wheels_at(wheels, current.scan.t)
    if w0 is None or w1 is None:
        return reference, estimated, None, None, math.nan
    wheel = relative(w0, w1)
    match = point_to_line_icp(base_points(previous.scan, sensor), points, wheel,
                              config.scan_odometry)
    if match is None:
        return reference, estimated, Step(wheel), None, math.nan
    return reference, estimated, Step(wheel), Step(match.delta), match.overlap


def markdown(losses: Sequence[LostPose], t0: float) -> str:
    """A table of ``losses``, times in seconds after ``t0`` (the run's first scan) and of log."""
    rows = ["| t (s after the first scan; of log) | estimate − reference | steps from the scan "
            "before: reference · estimate · wheels · scan match (overlap) | on walls: reference "
            "· estimate |", "|---|---|---|---|"]
    for p in losses:
        match = "–" if p.match_step is None else f"{p.match_step} ({p.match_overlap:.2f})"
        steps = " · ".join([str(s) if s is not None else "–"
                            for s in (p.reference_step, p.estimate_step, p.wheel_step)] + [match])
        rows.append(f"| {p.t - t0:.2f}; {p.t:.2f} | {100 * p.position_error:.1f} cm, "
                    f"{p.heading_error_deg:+.1f}° | {steps} | {p.on_walls_reference:.2f} · "
                    f"{p.on_walls_estimate:.2f} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    from fusion.bench.data import RunData
    from fusion.bench.spec import (
        Method,
        Protocol,
        SpecError,
        apply_settings,
        load_spec,
        settings_label,
    )
    from fusion.bench.sweep import read_results

    parser = argparse.ArgumentParser(
        prog="python -m fusion.bench.losses",
        description="The poses a sweep's runs lost, each beside the reference's, the wheels' and "
        "a scan-to-scan match's step from the scan before, and the scan's share on the map's "
        "walls at the reference and at the estimate.")
    parser.add_argument("--spec", type=Path, required=True, help="the sweep's spec (YAML)")
    parser.add_argument("--sweep", type=Path, required=True,
                        help="the sweep's output directory (results.csv, trajectories/)")
    parser.add_argument("--method", default=Method.HOUGHLOC.value,
                        choices=[m.value for m in Method])
    parser.add_argument("--protocol", action="append", choices=[p.value for p in Protocol],
                        help="repeatable (default: same-run and global-start)")
    parser.add_argument("--run", action="append", help="only these runs (repeatable)")
    parser.add_argument("--limit", type=int, default=20,
                        help="at most this many losses a task, the first ones (default 20)")
    args = parser.parse_args(argv)
    protocols = args.protocol or [Protocol.SAME_RUN.value, Protocol.GLOBAL_START.value]
    try:
        spec = load_spec(args.spec)
    except SpecError as error:
        print(error, file=sys.stderr)
        return 2
    rows = [r for r in read_results(args.sweep) if r["method"] == args.method
            and r["protocol"] in protocols and r["status"] == "ok"
            and (args.run is None or r["run"] in args.run)]
    if not rows:
        print(f"{args.sweep}: no finished {args.method} task of {', '.join(protocols)}",
              file=sys.stderr)
        return 1
    for run in spec.runs:
        mine = [r for r in rows if r["run"] == run.name]
        if not mine:
            continue
        data = RunData.load(run, spec.max_dt)
        first = min(e.t for e in data.events if isinstance(e, Scan))
        for row in sorted(mine, key=lambda r: (r["protocol"], r["settings"])):
            protocol = Protocol(row["protocol"])
            # each task is read with its own settings: they change the fit and the scan match
            settings = json.loads(row["settings"] or "{}")
            config = apply_settings(run.config, settings)
            estimate = Trajectory.from_tum(args.sweep / "trajectories" / f"{row['task_id']}.tum")
            found: list[LostPose] = []
            done = 0  # the trajectory holds each piece's poses in turn, one a scan
            for piece in data.pieces(protocol):
                scans = piece.scans
                poses = Trajectory(estimate.t[done:done + len(scans)],
                                   estimate.poses[done:done + len(scans)])
                done += len(scans)
                found += lost_poses(scans, poses, data.reference, wheel_poses(piece.events),
                                    piece.map_source.segment_map, config, spec.max_dt,
                                    from_first_right=protocol is Protocol.GLOBAL_START)
            title = f"## {run.name}, {protocol.value}"
            if settings:
                title += f", {settings_label(settings)}"
            title += f": {len(found)} lost"
            if protocol is Protocol.GLOBAL_START:
                title += " after the estimate was first right"
            print(title + "\n")
            if found:
                print(markdown(found[:args.limit], first) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

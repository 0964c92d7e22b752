"""Faults that real logs and robots produce: signals, runs that end lost, timestamps that jump,
repeat or go back, values that cannot be poses, initial poses at the first scan."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion.cli import main
from fusion.evaluation import ATE, Trajectory
from fusion.sim import scenario_preset, simulate, write_run
from tests.data.faults.make_corpus import restamp

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def office(tmp_path_factory) -> dict:
    run = simulate(scenario_preset("office-laser", seed=4, duration=40.0))
    out = tmp_path_factory.mktemp("office")
    paths = write_run(run, out)
    return {"log": paths["log"], "map": paths["map"], "gt": paths["gt"],
            "start": [str(v) for v in run.odom_truth[0].tolist()],
            "lines": paths["log"].read_text().splitlines()}


def _run(office: dict, log: Path, out: Path, *extra: str) -> list[str]:
    return ["run", "--map", str(office["map"]), "--log", str(log), "--out", str(out),
            "--no-rerun", "--no-progress", "--initial-pose", *office["start"], *extra]


def _ate(out: Path, gt: Path) -> float:
    est = Trajectory.from_tum(out / "trajectory.tum")
    return ATE(max_dt=0.02).compute(est, Trajectory.from_tum(gt)).position["rmse"]


@pytest.mark.parametrize(("sent", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_mid_run_leaves_valid_outputs_and_exits_128_plus_its_number(
        tmp_path, sent, status):
    # a log long enough to be mid-run when the signal comes (3000 scans: a few seconds); the
    # signal lands in compiled code as often as not, and must still stop the run cleanly
    run = simulate(scenario_preset("office-laser", seed=4, duration=300.0))
    paths = write_run(run, tmp_path / "log")
    out = tmp_path / "out"
    args = ["run", "--map", str(paths["map"]), "--log", str(paths["log"]), "--out", str(out),
            "--no-progress", "--initial-pose", *(str(v) for v in run.odom_truth[0].tolist())]
    # a shell without job control starts background jobs with SIGINT ignored, and Python keeps
    # it so: the run gets the default disposition, as in a terminal
    proc = subprocess.Popen([str(BIN / "houghloc"), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 180  # a cold start compiles the kernels first
    while not ((out / "trajectory.tum").exists()
               and (out / "trajectory.tum").stat().st_size > 2000):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(sent)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert "Traceback" not in err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] is True
    lines = (out / "trajectory.tum").read_text().splitlines()
    assert len(lines) == metrics["scans"] > 0
    assert all(len(line.split()) == 8 for line in lines)
    assert (out / "run.rrd").stat().st_size > 0


def test_the_summary_counts_scans_without_ground_truth(office, tmp_path, capsys):
    assert main(_run(office, office["log"], tmp_path / "o")) == 0
    printed, err = capsys.readouterr()
    scans = sum(line.startswith("ROBOTLASER1") for line in office["lines"])
    assert printed.startswith(f"{scans} scans in ")
    assert "by status: accepted" in printed
    assert "warning" not in err


def test_a_run_that_ends_lost_says_so_and_strict_fails_it(office, tmp_path, capsys):
    """The office log in the RoboCup map: nothing fits."""
    robocup = Path(__file__).resolve().parents[1] / "fusion" / "configs" / "maps" / "robocup.yaml"
    args = ["run", "--map", str(robocup), "--log", str(office["log"]), "--no-rerun",
            "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "not localized at the end" in err or "of the scans were localized" in err
    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["localized"] is False
    assert main([*args, "--out", str(tmp_path / "b"), "--strict"]) == 3
    assert "--strict" in capsys.readouterr().err
    assert main(_run(office, office["log"], tmp_path / "c", "--strict")) == 0


# -- time: stray, repeated, coarse, zero and negative stamps ------------------------------------
def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def clean_ate(office, tmp_path_factory) -> float:
    out = tmp_path_factory.mktemp("clean")
    assert main(_run(office, office["log"], out)) == 0
    return _ate(out, office["gt"])


def _record(lines: list[str], kind: str, n: int) -> int:
    return [k for k, line in enumerate(lines) if line.startswith(kind + " ")][n]


def test_one_future_timestamp_is_dropped_with_its_line(office, clean_ate, tmp_path, capsys,
                                                       caplog):
    lines = office["lines"]
    odom, laser = _record(lines, "ODOM", 250), _record(lines, "ROBOTLASER1", 100)
    damaged = restamp(lines, lambda k, kind, t: t + 100.0 if k == odom
                       else ("1e300" if k == laser else None))
    out = tmp_path / "o"
    assert main(_run(office, _write(tmp_path / "f.log", damaged), out)) == 0
    err = capsys.readouterr().err + caplog.text
    assert f"line {odom + 1}: Odometry stamped" in err and f"line {laser + 1}: Scan" in err
    assert "2 × stray timestamp" in err  # the total, whatever the cap on warnings
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stray_timestamps"] == 2
    assert metrics["log"]["warnings_by_kind"]["stray timestamp"]["count"] == 2
    stamps = Trajectory.from_tum(out / "trajectory.tum").t
    assert stamps.max() < 100 and np.all(np.diff(stamps) > 0)
    assert _ate(out, office["gt"]) <= 1.2 * clean_ate


def test_a_stray_reading_through_the_api_never_moves_the_clock(office):
    from fusion.io import open_log
    from fusion.localizer import Localizer
    from houghloc import SegmentMap

    def replay(stray: bool) -> np.ndarray:
        loc = Localizer(SegmentMap.from_yaml(office["map"]), None,
                        [float(v) for v in office["start"]])
        events, _ = open_log(office["log"])
        poses = []
        odometry = 0
        for e in events:
            if hasattr(e, "ranges"):
                if stray and len(poses) == 100:
                    loc.on_scan(e.t + 25.0, e.ranges, e.angles)  # one scan 25 s ahead
                poses.append(loc.on_scan(e.t, e.ranges, e.angles, e.sensor, e.max_range).pose)
            else:
                odometry += 1
                if stray and odometry == 500:
                    loc.on_odometry(e.t + 25.0, e.x, e.y, e.theta)  # one reading 25 s ahead
                loc.on_odometry(e.t, e.x, e.y, e.theta)
        assert not stray or loc.stats.stray_timestamps == 2
        return np.asarray(poses)

    np.testing.assert_allclose(replay(True), replay(False), atol=1e-9)


@pytest.mark.parametrize("kind", ["repeated", "coarse"])
def test_repeated_and_coarse_odometry_stamps_keep_their_motion(office, clean_ate, tmp_path,
                                                               kind):
    lines = office["lines"]
    first = _record(lines, "ODOM", 300)
    last = _record(lines, "ODOM", 400)
    t0 = float(lines[first].split()[7])

    def change(k: int, rec: str, t: float) -> float | None:
        if kind == "repeated":  # 100 readings share one stamp
            return t0 if rec == "ODOM" and first <= k < last else None
        return round(t, 1)  # every stamp rounded to 0.1 s, as %g logs do late in a run

    out = tmp_path / "o"
    assert main(_run(office, _write(tmp_path / f"{kind}.log", restamp(lines, change)),
                     out)) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["odometry_jumps"] == 0
    # coarse: 1.3× the clean run's 1.3 mm; repeated: 9 mm (0.93 m when the motion was dropped),
    # the readings' own times being unknown over those 2 s
    assert _ate(out, office["gt"]) <= (1.5 * clean_ate if kind == "coarse" else 0.015)


def test_all_zero_stamps_still_carry_the_odometry(office, tmp_path):
    zero = restamp(office["lines"], lambda k, rec, t: 0.0)
    out = tmp_path / "o"
    assert main(_run(office, _write(tmp_path / "zero.log", zero), out)) == 0
    poses = np.loadtxt(out / "trajectory.tum")[:, 1:3]
    travelled = np.linalg.norm(poses[-1] - poses[0])
    truth = np.loadtxt(office["gt"])[:, 1:3]
    assert travelled == pytest.approx(np.linalg.norm(truth[-1] - truth[0]), abs=0.2)


def test_negative_stamps_are_ordinary_times(office, clean_ate, tmp_path):
    shifted = restamp(office["lines"], lambda k, rec, t: t - 1000.0)
    gt = np.loadtxt(office["gt"])
    gt[:, 0] -= 1000.0
    np.savetxt(tmp_path / "gt.tum", gt)
    out = tmp_path / "o"
    assert main(_run(office, _write(tmp_path / "neg.log", shifted), out)) == 0
    # the same run to rounding: the wheels are carried to a scan's time by a ratio of time
    # differences, whose last bits differ when every stamp is 1000 s less
    assert _ate(out, tmp_path / "gt.tum") == pytest.approx(clean_ate, rel=1e-4)


def test_one_absurd_odometry_value_is_dropped_and_counted(office, clean_ate, tmp_path, caplog):
    lines = list(office["lines"])
    k = _record(lines, "ODOM", 500)
    tokens = lines[k].split()
    tokens[1] = "-1e300"
    lines[k] = " ".join(tokens)
    out = tmp_path / "o"
    assert main(_run(office, _write(tmp_path / "absurd.log", lines), out)) == 0
    assert f"line {k + 1}: ODOM record skipped: pose -1e+300" in caplog.text  # the reader's
    assert json.loads((out / "metrics.json").read_text())["log"]["skipped"] == 1
    assert _ate(out, office["gt"]) <= 1.2 * clean_ate


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e300])
def test_api_with_odometry_calibration_survives_a_bad_heading(office, bad):
    from fusion.config import LocalizerConfig
    from fusion.localizer import Localizer
    from houghloc import SegmentMap

    config = LocalizerConfig.from_dict({"filter": {"motion": {"translation_scale": 0.96}}})
    loc = Localizer(SegmentMap.from_yaml(office["map"]), config, [0.0, 0.0, 0.0])
    for k in range(10):
        loc.on_odometry(0.1 * k, 0.1 * k, 0.0, 0.0)
    loc.on_odometry(1.0, 1.0, 0.0, bad)
    for k in range(11, 20):
        loc.on_odometry(0.1 * k, 0.1 * k, 0.0, 0.0)
    assert loc.pose[0] == pytest.approx(0.96 * 1.9, abs=1e-9)
    assert loc.stats.invalid_odometry == 1


def test_the_initial_pose_is_the_pose_at_the_first_scan(office, tmp_path):
    """A log whose odometry moves before its first scan (most real logs do): the pose a user
    knows is where the robot was at that scan."""
    lines = office["lines"]
    late = _record(lines, "ROBOTLASER1", 30)  # the robot has moved for 3 s before it
    trimmed = [line for k, line in enumerate(lines)
               if not (k < late and line.startswith("ROBOTLASER1"))]
    t_first = float(lines[late].split()[-3])
    gt = np.loadtxt(office["gt"])
    start = gt[np.argmin(np.abs(gt[:, 0] - t_first))]
    from scipy.spatial.transform import Rotation

    yaw = Rotation.from_quat(start[4:8]).as_euler("xyz")[2]
    out = tmp_path / "o"
    args = ["run", "--map", str(office["map"]), "--log", str(_write(tmp_path / "t.log", trimmed)),
            "--out", str(out), "--no-rerun", "--no-progress", "--initial-pose",
            str(start[1]), str(start[2]), str(yaw)]
    assert main(args) == 0
    assert _ate(out, office["gt"]) < 0.02


def test_a_gzip_corrupted_mid_stream_says_so_whatever_the_warning_cap(office, tmp_path, capsys,
                                                                     caplog):
    import gzip

    lines = list(office["lines"])
    for k in range(1, 60):  # sixty bad records first: the cap on warnings is long spent
        lines.insert(100 * k, "ODOM not a number at all")
    data = gzip.compress(("\n".join(lines) + "\n").encode())
    path = tmp_path / "cut.log.gz"
    path.write_bytes(data[: len(data) // 2] + bytes(64) + data[len(data) // 2 + 64:])
    out = tmp_path / "o"
    assert main(_run(office, path, out)) == 0
    text = capsys.readouterr().err + caplog.text
    assert "stream ends early" in text and "the rest is lost" in text
    kinds = json.loads((out / "metrics.json").read_text())["log"]["warnings_by_kind"]
    assert kinds["stream ends early"]["count"] == 1
    assert kinds["bad record"]["count"] >= 20


def test_map_build_takes_negative_stamps(office, tmp_path):
    import dataclasses

    from fusion.events import Scan
    from fusion.io import open_log
    from fusion.mapping import segment_map_from_scans

    gt = Trajectory.from_tum(office["gt"])
    shifted = _write(tmp_path / "neg.log",
                     restamp(office["lines"], lambda k, rec, t: t - 1000.0))
    events, _ = open_log(shifted)
    scans = [dataclasses.replace(e, reference=tuple(gt.poses[np.argmin(np.abs(gt.t - e.t - 1000))]))
             for e in events if isinstance(e, Scan)]
    assert min(s.t for s in scans) < -900
    _, segment_map = segment_map_from_scans(scans)
    assert len(segment_map) > 10


# -- inputs that would need unbounded memory, values no config can mean --------------------------
def _scaled_map(office, tmp_path, factor: float) -> Path:
    import yaml

    raw = yaml.safe_load(Path(office["map"]).read_text())
    for seg in raw["segments"]:
        seg["from"] = [v * factor for v in seg["from"]]
        seg["to"] = [v * factor for v in seg["to"]]
    path = tmp_path / f"map-x{factor:g}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(("factor", "says"), [(1000.0, "coordinates must be in metres"),
                                              (100.0, "cells")])
def test_a_map_in_other_units_is_one_line_naming_it(office, tmp_path, capsys, factor, says):
    import resource

    path = _scaled_map(office, tmp_path, factor)
    args = ["run", "--map", str(path), "--log", str(office["log"]), "--out",
            str(tmp_path / "o"), "--no-rerun", "--no-progress", "--initial-pose",
            str(float(office["start"][0]) * factor), str(float(office["start"][1]) * factor), "0"]
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and says in err, err
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 500_000  # kB


def test_ten_thousand_random_segments_are_refused_before_allocating(office, tmp_path):
    from houghloc import SegmentMap
    from houghloc.segment_map import MapError

    rng = np.random.default_rng(0)
    starts = rng.uniform(0, 100, (10_000, 2))
    m = SegmentMap(starts, starts + rng.uniform(-3, 3, (10_000, 2)), name="random")
    from fusion.localizer import Localizer

    # the map's look-ups for global matching are built with the localizer: refused there, at
    # the start of a run rather than at its first relocalization
    with pytest.raises(MapError, match="oriented pairs"):
        Localizer(m, None, (50.0, 50.0, 0.0))


def test_map_build_with_a_pose_ten_km_off_names_the_scan(tmp_path):
    from fusion.events import Scan
    from fusion.mapping import GridMapError, occupancy_from_scans
    from houghloc.segment_map import MapError

    angles = np.linspace(-np.pi / 2, np.pi / 2, 91)
    scans = [Scan(float(k), np.full(91, 3.0), angles, reference=(0.1 * k, 0.0, 0.0), line=k + 1)
             for k in range(20)]
    scans[7] = Scan(7.0, np.full(91, 3.0), angles, reference=(10_000.0, 10_000.0, 0.0), line=8)
    with pytest.raises((MapError, GridMapError), match="line 8"):
        occupancy_from_scans(scans)


@pytest.mark.parametrize(("setting", "field"), [
    ({"filter": {"motion": {"alpha1": math.inf}}}, "filter.motion.alpha1"),
    ({"sensors": {"laser": {"mount": [0, math.nan, 0]}}}, "sensors.laser.mount.1"),
    ({"sensors": {"laser": {"hough": {"rho_step": math.inf}}}}, "sensors.laser.hough.rho_step"),
    ({"sensors": {"laser": {"hough": {"theta_step_deg": 1e-6}}}}, "sensors.laser.hough"),
    ({"sensors": {"laser": {"hough": {"nms_theta_cells": 60}}}}, "nms_theta_cells = 60"),
])
def test_configs_refuse_non_finite_and_absurd_values_by_field(setting, field):
    from fusion.config import ConfigError, LocalizerConfig

    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        LocalizerConfig.from_dict(setting, source="c.yaml")


@pytest.mark.parametrize("duration", ["0", "inf", "nan", "-1", "1e9"])
def test_sim_duration_is_one_clear_line(tmp_path, capsys, duration):
    with pytest.raises(SystemExit) as stop:
        main(["sim", "--out", str(tmp_path / "s"), "--duration", duration])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--duration" in err[-1] and "Traceback" not in "\n".join(err)


def test_an_initial_pose_far_outside_the_map_is_refused(office, tmp_path, capsys):
    args = ["run", "--map", str(office["map"]), "--log", str(office["log"]), "--out",
            str(tmp_path / "o"), "--no-rerun", "--initial-pose", "1000", "6", "0"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "outside the map" in err and str(office["map"]) in err


@given(st.lists(st.floats(-100.0, 100.0), max_size=30))
def test_the_localizer_holds_odometry_stamps_as_the_readers_do(stamps: list[float]) -> None:
    """One policy, two forms: the readings the Localizer's :class:`HeldOdometry` lets through
    (its clock the newest used) are the records a reader's :class:`StrayStampFilter` keeps, in
    the same order (a reading still held at the end is the reader's last)."""
    from fusion.events import Odometry, ReadStats
    from fusion.io.timing import HeldOdometry, OdometryReading, StrayStampFilter

    held, used, clock = HeldOdometry(), [], None
    for t in stamps:
        confirmed, _ = held.next_reading(t)
        for reading in ([] if confirmed is None else [confirmed]) + [OdometryReading(t, 0, 0, 0)]:
            if reading is confirmed or not held.hold(reading, clock):
                used.append(reading.t)
                clock = reading.t if clock is None else max(clock, reading.t)
    if held.reading is not None:
        used.append(held.reading.t)
    kept = StrayStampFilter([Odometry(t, 0.0, 0.0, 0.0) for t in stamps], ReadStats())
    assert used == [event.t for event in kept]

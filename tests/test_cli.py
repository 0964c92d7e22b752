"""Tests of the ``houghloc`` command line: damaged logs and the demo.

A damaged log must give warnings and a valid trajectory — never a NaN pose, a traceback or a
half-written output file (docs/architecture.md, formats). Each damage is applied to a short
simulated CARMEN log whose ground truth is known, so the tests also check that the trajectory
is still *right*, not just well-formed.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import main
from fusion.sim import scenario_preset, simulate, write_run

REPO = Path(__file__).resolve().parents[1]
LOG_SECONDS = 20.0
# A damaged log may cost a little accuracy where records are missing, but the robot must stay
# well localized: a regression in the handling of any damage shows up as metres or degrees.
MAX_POSITION_RMSE_M = 0.03
MAX_HEADING_RMSE_DEG = 0.5


@dataclass(frozen=True)
class CleanLog:
    """A simulated CARMEN log (lines without their newline), its map, truth and start pose."""

    lines: list[str]
    map_path: Path
    gt_path: Path
    start_pose: tuple[float, float, float]

    def record_indices(self, kind: str) -> list[int]:
        return [i for i, line in enumerate(self.lines) if line.startswith(kind + " ")]


@pytest.fixture(scope="module")
def clean_log(tmp_path_factory: pytest.TempPathFactory) -> CleanLog:
    run = simulate(scenario_preset("robocup-laser", seed=3, duration=LOG_SECONDS))
    out = tmp_path_factory.mktemp("sim")
    paths = write_run(run, out)
    lines = paths["log"].read_text().splitlines()
    x, y, theta = run.odom_truth[0].tolist()
    return CleanLog(lines, paths["map"], paths["gt"], (x, y, theta))


# ------------------------------------------------------------------------------- damaging a log
# ROBOTLASER1 fields: kind type start fov res max_range accuracy remission_mode n r1 … rn m …
RANGES_START = 9


def _scan_fields(line: str) -> tuple[list[str], int]:
    fields = line.split()
    return fields, int(fields[8])


def set_ranges(value: str, beams: slice) -> Callable[[str], str]:
    def damage(line: str) -> str:
        fields, n = _scan_fields(line)
        ranges = fields[RANGES_START:RANGES_START + n]
        ranges[beams] = [value] * len(ranges[beams])
        return " ".join([*fields[:RANGES_START], *ranges, *fields[RANGES_START + n:]])
    return damage


def empty_scan(line: str) -> str:
    fields, n = _scan_fields(line)
    return " ".join([*fields[:8], "0", *fields[RANGES_START + n:]])


def with_nan_ranges(log: CleanLog) -> list[str]:
    """Five scans with NaN ranges: corrupt records, skipped with a warning."""
    return _damage_scans(log, [40, 41, 90, 150, 151], set_ranges("nan", slice(100, 110)))


def with_infinite_ranges(log: CleanLog) -> list[str]:
    """Ten scans where a quarter of the beams read +inf ("no return" in converted logs)."""
    return _damage_scans(log, list(range(50, 60)), set_ranges("inf", slice(0, 90)))


def with_empty_scans(log: CleanLog) -> list[str]:
    """Ten scans of zero beams: nothing to correct with, odometry carries the pose."""
    return _damage_scans(log, [30, 31, 32, 33, 34, 100, 120, 140, 160, 180], empty_scan)


def with_duplicate_records(log: CleanLog) -> list[str]:
    """Odometry and scans repeated verbatim (same timestamps) right after themselves."""
    lines = list(log.lines)
    repeated = set(log.record_indices("ODOM")[200:210] + log.record_indices("ROBOTLASER1")[60:70])
    out: list[str] = []
    for i, line in enumerate(lines):
        out.append(line)
        if i in repeated:
            out.append(line)
    return out


def with_backwards_timestamps(log: CleanLog) -> list[str]:
    """Blocks of records out of order: a scan after the odometry that followed it, and an
    odometry reading late by a few readings."""
    lines = list(log.lines)
    for scan in log.record_indices("ROBOTLASER1")[70:150:20]:
        lines[scan], lines[scan + 1] = lines[scan + 1], lines[scan]
    odom = log.record_indices("ODOM")
    for k in (300, 500, 700):
        i, j = odom[k], odom[k + 3]
        lines.insert(j, lines.pop(i))
    return lines


def with_odometry_jump(log: CleanLog) -> list[str]:
    """From mid-log on, the odometry reads 2 m further along x (a reset or a glitch)."""
    lines = list(log.lines)
    odom = log.record_indices("ODOM")
    for i in odom[len(odom) // 2:]:
        fields = lines[i].split()
        fields[1] = f"{float(fields[1]) + 2.0:.6f}"
        lines[i] = " ".join(fields)
    return lines


def with_truncated_last_line(log: CleanLog) -> list[str]:
    """The writer was killed mid-line: the last scan stops after half its ranges."""
    lines = list(log.lines)
    last_scan = log.record_indices("ROBOTLASER1")[-1]
    lines = lines[:last_scan + 1]
    lines[-1] = lines[-1][: len(lines[-1]) // 2]
    return lines


def _damage_scans(log: CleanLog, scan_numbers: list[int],
                  damage: Callable[[str], str]) -> list[str]:
    lines = list(log.lines)
    scans = log.record_indices("ROBOTLASER1")
    for k in scan_numbers:
        lines[scans[k]] = damage(lines[scans[k]])
    return lines


def write_log(path: Path, lines: list[str], final_newline: bool = True) -> Path:
    path.write_text("\n".join(lines) + ("\n" if final_newline else ""))
    return path


def run_args(log: CleanLog, log_path: Path, out: Path) -> list[str]:
    return ["run", "--map", str(log.map_path), "--log", str(log_path), "--out", str(out),
            "--gt", str(log.gt_path), "--initial-pose", *map(str, log.start_pose),
            "--no-rerun", "--no-progress"]


# ------------------------------------------------------------------------------ output checks
def read_complete_trajectory(path: Path) -> np.ndarray:
    """The TUM file's rows; fails on any incomplete, non-numeric or non-finite line."""
    text = path.read_text()
    assert text.endswith("\n"), "the last trajectory line is incomplete"
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        assert len(fields) == 8, f"trajectory line {number} has {len(fields)} fields: {line!r}"
        values = [float(v) for v in fields]
        assert all(math.isfinite(v) for v in values), f"non-finite trajectory line {number}"
        assert math.isclose(np.hypot(values[6], values[7]), 1.0, abs_tol=1e-6)
        rows.append(values)
    return np.array(rows)


def reader_statistics(metrics: dict) -> dict:
    """The log reader's counts in metrics.json (records, skipped, backwards, warnings)."""
    stats = metrics.get("log")
    assert isinstance(stats, dict), (
        f"metrics.json has no reader statistics: 'log' is {stats!r} (cmd_run's extra "
        "{'log': path} overwrites metrics_document's 'log' section)")
    return stats


def check_outputs(out: Path, scan_records: int) -> dict:
    """Both outputs complete and consistent with each other; returns metrics.json.
    ``scan_records``: laser lines in the log (a few may be unusable and skipped)."""
    metrics = json.loads((out / "metrics.json").read_text())  # valid JSON, written whole
    trajectory = read_complete_trajectory(out / "trajectory.tum")
    assert metrics["interrupted"] is False
    assert len(trajectory) == metrics["scans"]
    assert 0.9 * scan_records <= metrics["scans"] <= scan_records
    assert metrics["invalid_inputs"] == 0
    ate = metrics["ate"]
    assert ate["matched"] >= 0.9 * metrics["scans"]
    assert ate["position_rmse_m"] <= MAX_POSITION_RMSE_M
    assert ate["heading_rmse_deg"] <= MAX_HEADING_RMSE_DEG
    assert metrics["lost"]["lost"] == 0
    return metrics


DAMAGES = {
    "nan-ranges": with_nan_ranges,
    "infinite-ranges": with_infinite_ranges,
    "empty-scans": with_empty_scans,
    "duplicate-records": with_duplicate_records,
    "backwards-timestamps": with_backwards_timestamps,
    "odometry-jump": with_odometry_jump,
    "truncated-last-line": with_truncated_last_line,
}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_run_survives_a_damaged_log(damage: str, clean_log: CleanLog, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str],
                                    caplog: pytest.LogCaptureFixture) -> None:
    lines = DAMAGES[damage](clean_log)
    truncated = damage == "truncated-last-line"
    log_path = write_log(tmp_path / f"{damage}.log", lines, final_newline=not truncated)
    out = tmp_path / "out"

    code = main(run_args(clean_log, log_path, out))

    err = capsys.readouterr().err
    assert code == 0, err
    assert "Traceback" not in err
    scans_in_log = len(clean_log.record_indices("ROBOTLASER1"))
    metrics = check_outputs(out, sum(line.startswith("ROBOTLASER1 ") for line in lines))
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    # Each damage is noticed where it can be, and counted, not silently absorbed.
    if damage == "nan-ranges":  # a NaN beam is no return (as ROS has it); the scan is used
        assert len(warned) == 5 and all("NaN" in w and "line " in w for w in warned)
        assert metrics["scans"] == scans_in_log
        assert reader_statistics(metrics)["warnings_by_kind"]["invalid range"]["count"] == 5
    elif damage == "truncated-last-line":
        assert len(warned) == 1 and f"line {len(lines)}:" in warned[0]
        assert metrics["scans"] == scans_in_log - 1
        assert reader_statistics(metrics)["skipped"] == 1
    elif damage == "backwards-timestamps":
        assert metrics["odometry_backwards"] == 3
        assert reader_statistics(metrics)["backwards_timestamps"] >= 4 + 3
    elif damage == "odometry-jump":
        assert metrics["odometry_jumps"] == 1
    elif damage == "empty-scans":
        assert metrics["statuses"].get("no-fix", 0) >= 10
    else:
        assert not warned
        assert metrics["scans"] == scans_in_log + (10 if damage == "duplicate-records" else 0)


def test_every_damage_at_once_in_a_subprocess_gives_warnings_not_a_traceback(
        clean_log: CleanLog, tmp_path: Path) -> None:
    """The installed entry point, as a user runs it: warnings on stderr, complete outputs."""
    log = clean_log
    for damage in DAMAGES.values():  # apply one after the other to the same lines
        log = CleanLog(damage(log), log.map_path, log.gt_path, log.start_pose)
    log_path = write_log(tmp_path / "damaged.log", log.lines, final_newline=False)
    out = tmp_path / "out"

    done = subprocess.run([sys.executable, "-m", "fusion", *run_args(log, log_path, out)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)

    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert "warning" in done.stderr and "NaN or negative range" in done.stderr
    check_outputs(out, len(clean_log.record_indices("ROBOTLASER1")) + 15)


def test_run_refuses_a_log_without_records_cleanly(clean_log: CleanLog, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    log_path = write_log(tmp_path / "comments.log", ["# CARMEN Logfile", "PARAM robot_x 1"])
    out = tmp_path / "out"

    code = main(run_args(clean_log, log_path, out))

    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err and str(log_path) in err
    assert not (out / "metrics.json").exists()


def test_demo_prints_the_accuracy_table(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"

    code = main(["demo", "--duration", "15", "--seed", "2", "--out", str(out), "--no-rerun"])

    printed = capsys.readouterr().out
    assert code == 0
    rows = {line.split("  ")[0].strip(): line for line in printed.splitlines()
            if line.startswith(("odometry only", "houghloc (fused)"))}
    assert set(rows) == {"odometry only", "houghloc (fused)"}
    assert "ATE RMSE" in printed and "heading RMSE" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    fused, dead_reckoning = metrics["ate"], metrics["odometry_only"]["ate"]
    assert fused["position_rmse_m"] < 0.01
    assert dead_reckoning["position_rmse_m"] > 5 * fused["position_rmse_m"]
    assert f"{fused['position_rmse_m'] * 100:7.2f} cm" in rows["houghloc (fused)"]
    trajectory = read_complete_trajectory(out / "trajectory.tum")
    assert len(trajectory) == metrics["scans"] == 151
    assert (out / "sim" / "log.carmen").is_file()
    assert not (out / "run.rrd").exists()


@pytest.mark.parametrize(("content", "problem"), [
    ("name: [unclosed\n", "not valid YAML"),
    ("- a list\n", "expected a mapping"),
    ("name: x\nduration: -5\n", "duration: Input should be greater than 0"),
    (None, "file not found"),
])
def test_sim_names_the_scenario_file_and_its_problem(content: str | None, problem: str,
                                                     tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    scenario = tmp_path / "scenario.yaml"
    if content is not None:
        scenario.write_text(content)

    code = main(["sim", "--scenario", str(scenario), "--out", str(tmp_path / "out")])

    err = capsys.readouterr().err
    assert code == 2
    assert f"scenario {scenario}: {problem}" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ reproducing a run, version
def test_version_is_the_installed_packages(capsys: pytest.CaptureFixture[str]) -> None:
    from importlib.metadata import version

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"houghloc {version('houghloc')}\n"


def test_metrics_record_what_reproduces_the_run(clean_log: CleanLog, tmp_path: Path) -> None:
    """metrics.json holds the version, the whole effective config and the initial pose; given
    back as --config (nothing else but the map and log), it gives the same trajectory. A
    config's initial_pose starts a run as --initial-pose does."""
    from importlib.metadata import version

    log_path = write_log(tmp_path / "run.log", clean_log.lines)
    config = tmp_path / "start.yaml"
    config.write_text(f"initial_pose: {list(clean_log.start_pose)}\n"
                      "filter: {motion: {alpha1: 0.07}}\n")
    first = tmp_path / "first"
    assert main(["run", "--map", str(clean_log.map_path), "--log", str(log_path), "--out",
                 str(first), "--config", str(config), "--gt", str(clean_log.gt_path),
                 "--no-rerun", "--no-progress"]) == 0
    metrics = check_outputs(first, len(clean_log.record_indices("ROBOTLASER1")))
    assert metrics["houghloc_version"] == version("houghloc")
    assert metrics["initial_pose"] == pytest.approx(list(clean_log.start_pose))
    assert metrics["config"]["filter"]["motion"]["alpha1"] == 0.07
    assert metrics["config"]["ambiguity"] and metrics["config"]["sensors"]["laser"]["hough"]
    again = tmp_path / "again"
    assert main(["run", "--map", str(clean_log.map_path), "--log", str(log_path), "--out",
                 str(again), "--config", str(first / "metrics.json"), "--no-rerun",
                 "--no-progress"]) == 0
    np.testing.assert_array_equal(read_complete_trajectory(again / "trajectory.tum"),
                                  read_complete_trajectory(first / "trajectory.tum"))
    global_start = tmp_path / "global"  # the same config without its pose: not the same run
    config.write_text("filter: {motion: {alpha1: 0.07}}\n")
    assert main(["run", "--map", str(clean_log.map_path), "--log", str(log_path), "--out",
                 str(global_start), "--config", str(config), "--no-rerun", "--no-progress"]) == 0
    assert json.loads((global_start / "metrics.json").read_text())["initial_pose"] is None


def test_packaged_configs_and_maps_are_found_by_name(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from fusion.config import LocalizerConfig
    from fusion.resources import configs_dir, find_config, find_map, maps_dir, packaged_names

    assert {"office-laser", "robocup-laser", "intel-laser"} <= set(packaged_names(configs_dir()))
    assert find_map("office") == maps_dir() / "office.yaml"
    assert find_config("office-laser.yaml") == configs_dir() / "office-laser.yaml"
    assert LocalizerConfig.from_yaml("intel-laser").sensors["laser"].max_range == 20.0
    assert find_map(tmp_path / "office") == tmp_path / "office"  # a path stays a path
    assert main(["run", "--map", "no-such-map", "--log", str(tmp_path), "--out",
                 str(tmp_path / "o"), "--no-rerun"]) == 2
    err = capsys.readouterr().err
    assert "map no-such-map: file not found" in err and "robocup" in err  # the packaged ones
    assert main(["run", "--map", "office", "--config", "no-such-config", "--log",
                 str(tmp_path), "--out", str(tmp_path / "o"), "--no-rerun"]) == 2
    assert "office-laser" in capsys.readouterr().err


def test_eval_scores_against_a_corrected_carmen_log(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """``--gt`` takes the corrected log a map was built from (its scans' poses), as a user who
    maps a building and localizes its raw data has it: an estimate 5 cm off every corrected
    pose scores 5 cm."""
    from fusion.io import write_tum

    poses = np.array([[1.0, 2.0, 0.1], [1.5, 2.1, 0.2], [2.0, 2.3, 0.4]])
    lines = []
    for k, pose in enumerate(poses):
        t = 10.0 + k
        p = " ".join(f"{v:.9g}" for v in (*pose, *pose))
        lines += [f"ODOM {pose[0]} {pose[1]} {pose[2]} 0 0 0 {t} host {t}",
                  f"FLASER 3 1 2 3 {p} {t} host {t}",
                  f"ODOM {pose[0]} {pose[1]} {pose[2]} 0 0 0 0 host {t}"]  # re-anchoring
    corrected = write_log(tmp_path / "corrected.log", lines)
    est = write_tum(tmp_path / "est.tum", 10.0 + np.arange(3), poses + [0.05, 0.0, 0.0])
    assert main(["eval", "--est", str(est), "--gt", str(corrected)]) == 0
    out = capsys.readouterr().out
    assert "matched 3 of 3 poses" in out and "RMSE     5.00 cm" in out

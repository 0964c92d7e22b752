"""Faults that real logs and robots produce: signals, runs that end lost, timestamps that jump,
repeat or go back, values that cannot be poses, initial poses at the first scan."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fusion.cli import main
from fusion.evaluation import ATE, Trajectory
from fusion.sim import scenario_preset, simulate, write_run

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


def test_sigterm_leaves_valid_outputs_and_exits_143(office, tmp_path):
    out = tmp_path / "out"
    args = ["run", "--map", str(office["map"]), "--log", str(office["log"]), "--out", str(out),
            "--no-progress", "--initial-pose", *office["start"]]
    proc = subprocess.Popen([str(BIN / "houghloc"), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not ((out / "trajectory.tum").exists()
               and (out / "trajectory.tum").stat().st_size > 2000):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "Traceback" not in err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] is True
    lines = (out / "trajectory.tum").read_text().splitlines()
    assert len(lines) == metrics["scans"] > 0
    assert all(len(line.split()) == 8 for line in lines)
    assert (out / "run.rrd").stat().st_size > 0


def test_the_summary_counts_scans_without_ground_truth(office, tmp_path, capsys):
    assert main(_run(office, office["log"], tmp_path / "o")) == 0
    printed = capsys.readouterr().out
    scans = sum(line.startswith("ROBOTLASER1") for line in office["lines"])
    assert printed.startswith(f"{scans} scans in ")
    assert "by status: accepted" in printed and "warning" not in printed


def test_a_run_that_ends_lost_says_so_and_strict_fails_it(office, tmp_path, capsys):
    """The office log in the RoboCup map: nothing fits."""
    robocup = Path(__file__).resolve().parents[1] / "configs" / "maps" / "robocup.yaml"
    args = ["run", "--map", str(robocup), "--log", str(office["log"]), "--no-rerun",
            "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    printed = capsys.readouterr().out
    assert "not localized at the end" in printed or "of the scans were localized" in printed
    assert main([*args, "--out", str(tmp_path / "b"), "--strict"]) == 3
    assert "--strict" in capsys.readouterr().err
    assert main(_run(office, office["log"], tmp_path / "c", "--strict")) == 0

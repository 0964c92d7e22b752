"""The fault corpus (``tests/data/faults``, written by its ``make_corpus.py``) through the
installed ``houghloc run``: each file ends with the exit status its manifest gives, messages
that name the file and the line, complete outputs, and — for the recoverable faults — an
accuracy close to the clean run's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.evaluation import ATE, Trajectory

CORPUS = Path(__file__).resolve().parent / "data" / "faults"
MANIFEST = yaml.safe_load((CORPUS / "corpus.yaml").read_text())
BIN = Path(sys.executable).parent


def _run(name: str, out: Path) -> subprocess.CompletedProcess:
    start = (CORPUS / "start.txt").read_text().split()
    return subprocess.run(
        [str(BIN / "houghloc"), "run", "--map", str(CORPUS / "map.yaml"),
         "--log", str(CORPUS / f"{name}.log.gz"), "--out", str(out), "--no-rerun",
         "--no-progress", "--initial-pose", *start],
        capture_output=True, text=True, timeout=120, check=False)


def _ate(out: Path) -> float:
    est = Trajectory.from_tum(out / "trajectory.tum")
    return ATE(max_dt=0.02).compute(est, Trajectory.from_tum(CORPUS / "gt.tum")).position["rmse"]


@pytest.fixture(scope="module")
def clean_ate(tmp_path_factory) -> float:
    out = tmp_path_factory.mktemp("clean")
    assert _run("clean", out).returncode == 0
    return _ate(out)


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_fault_corpus(name: str, clean_ate: float, tmp_path: Path) -> None:
    expected = MANIFEST[name]
    out = tmp_path / "out"
    done = _run(name, out)
    assert done.returncode == expected["exit"], done.stderr
    assert "Traceback" not in done.stderr
    assert "\x1b" not in done.stderr + done.stdout  # nothing from a log reaches the terminal raw
    for text in expected["stderr"]:
        assert text.format(file=f"{name}.log.gz") in done.stderr, done.stderr
    if done.returncode != 0:
        assert len(done.stderr.strip().splitlines()) == 1
        assert not (out / "metrics.json").exists()
        return
    metrics = json.loads((out / "metrics.json").read_text())
    lines = (out / "trajectory.tum").read_text().splitlines()
    assert len(lines) == metrics["scans"] > 0
    poses = np.loadtxt(out / "trajectory.tum", ndmin=2)
    assert np.isfinite(poses).all() and np.all(np.abs(poses[:, 0]) < 1e4)
    if expected["ate"] is not None:
        assert _ate(out) <= expected["ate"] * clean_ate + 1e-9

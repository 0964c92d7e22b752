"""``docker build .`` gives an image whose ``houghloc ros2 --help`` runs (the node and its ROS 2
wheels inside). Needs a Docker engine: skipped, saying so, where ``docker info`` fails (no
engine runs on the machines the default suite is run on)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _engine() -> str | None:
    """None when an engine answers, else why not."""
    if shutil.which("docker") is None:
        return "docker is not installed"
    info = subprocess.run(["docker", "info"], capture_output=True, text=True, check=False)
    if info.returncode != 0:
        return f"no Docker engine answers (docker info: {info.stderr.strip()[-200:]})"
    return None


@pytest.mark.slow  # builds an image: several minutes
def test_the_image_runs_the_node_command() -> None:
    why = _engine()
    if why is not None:
        pytest.skip(why)
    tag = "houghloc-test:latest"
    build = subprocess.run(["docker", "build", "-q", "-t", tag, str(REPO)], capture_output=True,
                           text=True, timeout=3600, check=False)
    assert build.returncode == 0, build.stderr[-3000:]
    run = subprocess.run(["docker", "run", "--rm", tag, "houghloc", "ros2", "--help"],
                         capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "drop-in for nav2's AMCL" in run.stdout or "nav2's AMCL" in run.stdout
    assert "--managed" in run.stdout


def test_the_dockerfile_installs_what_the_node_needs() -> None:
    """Without an engine, at least the recipe: the ros2 extra, tf2_msgs, the node's help."""
    text = (REPO / "Dockerfile").read_text()
    assert "'.[ros2]'" in text and "fusion.ros2.tf2_msgs" in text
    assert 'CMD ["houghloc", "ros2", "--help"]' in text
    ignored = (REPO / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored

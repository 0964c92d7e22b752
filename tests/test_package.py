"""The package as a user installs it: the wheel carries what the commands need, and installed in
a fresh virtual environment it runs from any directory."""

from __future__ import annotations

import os
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "--quiet", str(REPO), "-w", str(out)], check=True, cwd=out)
    (path,) = out.glob("houghloc-*.whl")
    return path


def test_the_wheel_carries_configs_maps_types_and_license(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    packaged = {p.relative_to(REPO).as_posix() for p in (REPO / "fusion" / "configs").rglob("*")
                if p.suffix == ".yaml"}
    assert packaged and packaged <= names
    assert {"fusion/configs/robocup-laser.yaml", "fusion/configs/maps/robocup.yaml",
            "houghloc/py.typed", "fusion/py.typed"} <= names
    dist_info = next(n.split("/")[0] for n in names if n.endswith(".dist-info/METADATA"))
    assert f"{dist_info}/licenses/LICENSE" in names
    entry_points = zipfile.ZipFile(wheel).read(f"{dist_info}/entry_points.txt").decode()
    assert "houghloc = fusion.cli:main" in entry_points
    assert not any(n.startswith(("tests/", "benchmarks/", "notebooks/")) for n in names)


@pytest.mark.slow
def test_the_installed_wheel_runs_the_demo_from_any_directory(wheel: Path,
                                                              tmp_path: Path) -> None:
    """A fresh venv, the wheel and its dependencies from the package index, then the commands
    from a directory that is not the source tree."""
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    bin_dir = env_dir / "bin"
    subprocess.run([bin_dir / "python", "-m", "pip", "install", "--quiet", str(wheel)],
                   check=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}

    def houghloc(*args: str) -> str:
        done = subprocess.run([bin_dir / "houghloc", *args], cwd=work, env=env,
                              capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr
        return done.stdout

    from importlib.metadata import version

    assert houghloc("--version") == f"houghloc {version('houghloc')}\n"
    table = houghloc("demo", "--no-rerun", "--duration", "30")
    assert "houghloc (fused)" in table and "odometry only" in table
    assert (work / "runs" / "demo" / "metrics.json").is_file()
    houghloc("sim", "--scenario", "office-laser", "--duration", "5", "--out", "office")
    assert (work / "office" / "log.carmen").is_file()
    imported = subprocess.run([bin_dir / "python", "-c", "import fusion; print(fusion.__file__)"],
                              cwd=work, env=env, capture_output=True, text=True, check=True)
    assert str(env_dir) in imported.stdout  # the installed copy, not the source tree

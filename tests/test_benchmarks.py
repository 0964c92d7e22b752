"""Every benchmark script runs end to end at a tiny size and prints its verdicts.

The figures themselves are measured by running the scripts at full size (README); these tests
only keep the scripts working as the code they measure changes (no timing is asserted).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.bench_real import DATA

REPO = Path(__file__).resolve().parents[1]


def _run(module: str, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", f"benchmarks.{module}", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    return done.stdout + done.stderr


def test_bench_fusion_every_section() -> None:
    out = _run("bench_fusion", "--duration", "10", "--seeds", "2", "--log-minutes", "0.1", "0.2")
    for section in range(1, 7):
        assert f"=== {section}." in out
    assert "target ≥ 1000 scans/s" in out and "peak RSS growth" in out and "× peer" in out


def test_bench_localize_and_global_and_rerun(tmp_path: Path) -> None:
    plot = tmp_path / "localize.png"
    assert "cv2.HoughLinesPointSet" in _run("bench_localize", "--rounds", "1", "--plot",
                                            str(plot))
    assert plot.stat().st_size > 10_000  # two panels drawn
    assert "a copy of the true pose reported" in _run("bench_global", "--rounds", "1")
    out = _run("bench_rerun", "--duration", "5", "--rounds", "1", "--intel-scans", "100")
    assert "% of off" in out
    assert ("Intel lab, 100 scans" in out) == DATA.is_dir(), out


@pytest.mark.skipif(not DATA.is_dir(), reason=f"real logs not found at {DATA}")
def test_bench_real_on_short_slices() -> None:
    # 40 scans hold no Intel reference pose: the table says so instead of failing
    out = _run("bench_real", "--scans", "40")
    for name in ("intel", "fr079", "aces"):
        assert f"{name}: 40 scans" in out
    assert "× peer" in out


def test_bench_real_overrides_settings_of_the_datasets_configs() -> None:
    from benchmarks.bench_real import overridden_config

    base = REPO / "fusion/configs/fr079-laser.yaml"
    assert overridden_config(base, []) == base
    config = overridden_config(base, ["scan_odometry.enabled=false",
                                      "ambiguity.local_search_xy=0.75"])
    assert not config.scan_odometry.enabled and config.ambiguity.local_search_xy == 0.75
    assert config.sensors["laser"].max_range == 20.0  # the rest is the file's
    assert config.ambiguity.max_scans_without_fix == 25  # and the defaults
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        overridden_config(base, ["scan_odometry.enabled"])
    with pytest.raises(ValueError, match="local_serch_xy"):  # a misspelt key is named
        overridden_config(base, ["ambiguity.local_serch_xy=0.75"])
    with pytest.raises(ValueError, match="not a group"):
        overridden_config(base, ["sensors.laser.max_range.inner=1"])

"""The witnesses beside a lost pose (``fusion.bench.losses``), on the simulated office where the
truth is known: a reference that flicks is contradicted by the wheels, the scan match and the
map; an estimate that is off is contradicted by the map, and the reference by nothing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.bench.losses import (
    lost_poses,
    main,
    markdown,
    wheels_at,
)
from fusion.bench.spec import load_spec
from fusion.bench.sweep import run_sweep
from fusion.cli import main as houghloc
from fusion.config import LocalizerConfig
from fusion.evaluation.trajectory import Trajectory
from fusion.events import Scan
from fusion.io.tum import read_tum, write_tum
from fusion.sim import scenario_preset, simulate
from houghloc.geometry import compose

OFFICE = Path(__file__).resolve().parents[1] / "fusion" / "configs" / "office-laser.yaml"


@pytest.fixture(scope="module")
def office_run():
    run = simulate(scenario_preset("office-laser", seed=2, duration=20.0))
    assert run.laser is not None
    max_range = run.config.laser.max_range if run.config.laser else math.inf
    scans = [Scan(t, r, run.angles, max_range=max_range)
             for t, (r, _) in zip(run.scan_t.tolist(), run.laser.scans(), strict=True)]
    wheels = Trajectory(run.odom_t, run.odom_pose)
    return run, scans, wheels, LocalizerConfig.from_yaml(OFFICE)


def _truth(run) -> Trajectory:
    return Trajectory(run.scan_t.copy(), run.scan_truth.copy())


def test_the_truth_against_itself_loses_nothing(office_run):
    run, scans, wheels, config = office_run
    assert lost_poses(scans, _truth(run), _truth(run), wheels, run.map, config) == []


def test_a_reference_that_flicks_is_contradicted_by_the_wheels_the_match_and_the_map(office_run):
    run, scans, wheels, config = office_run
    k = len(scans) // 2
    reference = _truth(run)
    reference.poses[k, 2] += math.radians(8.0)
    losses = lost_poses(scans, _truth(run), reference, wheels, run.map, config)
    assert [p.t for p in losses] == [scans[k].t]
    p = losses[0]
    assert p.heading_error_deg == pytest.approx(-8.0, abs=1e-6)
    assert p.reference_step is not None and p.wheel_step is not None
    assert p.match_step is not None and p.estimate_step is not None
    # the reference turned 8° more than the wheels, the match and the (true) estimate say
    assert p.reference_step.turn_deg - p.wheel_step.turn_deg == pytest.approx(8.0, abs=1.0)
    assert p.reference_step.turn_deg - p.match_step.turn_deg == pytest.approx(8.0, abs=0.5)
    assert abs(p.match_step.turn_deg - p.estimate_step.turn_deg) < 0.5
    assert p.on_walls_estimate > p.on_walls_reference + 0.2
    row = markdown(losses, scans[0].t).splitlines()[-1]
    assert row.startswith(f"| {scans[k].t - scans[0].t:.2f}; {scans[k].t:.2f} | 0.0 cm, -8.0° |")


def test_an_estimate_that_is_off_is_contradicted_by_the_map_and_the_reference_by_nothing(
        office_run):
    run, scans, wheels, config = office_run
    k = len(scans) // 3
    estimate = _truth(run)
    estimate.poses[k] = compose(estimate.poses[k], np.array([0.5, 0.0, 0.0]))
    losses = lost_poses(scans, estimate, _truth(run), wheels, run.map, config)
    assert [p.t for p in losses] == [scans[k].t]
    p = losses[0]
    assert p.position_error == pytest.approx(0.5, abs=1e-9)
    assert p.reference_step is not None and p.match_step is not None
    # the reference's step is the true one: the scan match agrees with it to a centimetre
    assert abs(p.reference_step.distance - p.match_step.distance) < 0.01
    assert abs(p.reference_step.turn_deg - p.match_step.turn_deg) < 0.5
    assert p.on_walls_reference > p.on_walls_estimate + 0.2


def test_the_estimate_must_give_a_pose_for_each_scan(office_run):
    run, scans, wheels, config = office_run
    short = Trajectory(run.scan_t[:-1], run.scan_truth[:-1])
    with pytest.raises(ValueError, match=r"\d+ estimated poses for \d+ scans"):
        lost_poses(scans, short, _truth(run), wheels, run.map, config)


def test_wheels_are_interpolated_between_readings_and_unknown_outside(office_run):
    _, _, wheels, _ = office_run
    assert wheels_at(wheels, wheels.t[0] - 1.0) is None
    assert wheels_at(wheels, wheels.t[-1] + 1.0) is None
    np.testing.assert_array_equal(wheels_at(wheels, float(wheels.t[3])), wheels.poses[3])
    middle = wheels_at(wheels, 0.5 * float(wheels.t[3] + wheels.t[4]))
    assert middle is not None
    np.testing.assert_allclose(middle[:2], 0.5 * (wheels.poses[3, :2] + wheels.poses[4, :2]),
                               atol=1e-3)


def test_a_global_starts_losses_count_after_it_was_first_right(office_run):
    run, scans, wheels, config = office_run
    estimate = _truth(run)
    off = np.array([0.5, 0.0, 0.0])
    for k in (0, 1, 2, 40):  # the search for a first pose, then one loss later
        estimate.poses[k] = compose(estimate.poses[k], off)
    later = lost_poses(scans, estimate, _truth(run), wheels, run.map, config,
                       from_first_right=True)
    assert [p.t for p in later] == [scans[40].t]
    everything = lost_poses(scans, estimate, _truth(run), wheels, run.map, config)
    assert [p.t for p in everything] == [scans[k].t for k in (0, 1, 2, 40)]
    assert everything[0].reference_step is None  # the first judged scan has none before it
    estimate.poses[:] = compose(estimate.poses, off)  # never right
    assert lost_poses(scans, estimate, _truth(run), wheels, run.map, config,
                      from_first_right=True) == []


def test_the_command_says_what_is_missing(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text("runs:\n  - name: office\n    log: office.log\n    map: office.yaml\n")
    assert main(["--spec", str(spec), "--sweep", str(tmp_path)]) == 2
    assert "runs.0.log" in capsys.readouterr().err
    (tmp_path / "office.log").touch()
    (tmp_path / "office.yaml").touch()
    assert main(["--spec", str(spec), "--sweep", str(tmp_path)]) == 1
    assert "no finished houghloc task" in capsys.readouterr().err


def test_a_sweeps_losses_are_read_task_by_task_with_each_tasks_settings(tmp_path, capsys):
    """End to end: a simulated office localized by a sweep at two settings, scored against its
    truth with one pose turned 8°: each task reports that one pose, under its settings."""
    assert houghloc(["sim", "--scenario", "office-laser", "--out", str(tmp_path / "sim"),
                     "--duration", "20"]) == 0
    t, poses = read_tum(tmp_path / "sim" / "gt.tum")
    k = len(t) // 2
    poses[k, 2] += math.radians(8.0)
    write_tum(tmp_path / "flicked.tum", t, poses)
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({
        "runs": [{"name": "office", "log": "sim", "map": "sim/map.yaml",
                  "reference": "flicked.tum"}],
        "methods": ["houghloc"], "protocols": ["same-run"],
        "grid": {"filter.gate_probability": [0.999, 0.9999]}}))
    outcome = run_sweep(load_spec(spec), tmp_path / "out", workers=2, progress=False)
    assert outcome.failed == 0
    capsys.readouterr()
    assert main(["--spec", str(spec), "--sweep", str(tmp_path / "out")]) == 0
    lines = capsys.readouterr().out.splitlines()
    titles = [line for line in lines if line.startswith("## ")]
    assert sorted(titles) == sorted([
        '## office, same-run, {"filter.gate_probability":0.999}: 1 lost',
        '## office, same-run, {"filter.gate_probability":0.9999}: 1 lost'])
    rows = [line for line in lines if line.startswith(f"| {t[k] - t[0]:.2f}; {t[k]:.2f} |")]
    assert len(rows) == 2

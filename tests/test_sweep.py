"""`houghloc sweep`: the benchmark's figures against a hand-computed case, Dask (a LocalCluster,
and a scheduler with two workers started here, one killed mid-sweep), re-runs, bad specs and
failing tasks."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.bench import Method, Protocol, expand, load_spec, run_sweep
from fusion.bench.spec import SpecError
from fusion.cli import main
from fusion.io import flaser_angles
from fusion.rerun_serve import free_port

BIN = Path(sys.executable).parent

# -- a log computed by hand ----------------------------------------------------------------------
# A robot drives along y = 3 m in a 10 m × 6 m room, heading +x, scans at x = 2, 2.7, …, 7.6
# (t = 1 … 9 s). Its wheels over-report distance by 10 %, so dead reckoning from the start pose
# is 0.07 m × k off at scan k.
ROOM = (0.0, 10.0, 0.0, 6.0)
STEP, SCALE, N = 0.7, 1.1, 9


def _ranges(x: float, y: float, angles: np.ndarray) -> np.ndarray:
    """Ranges from (x, y), heading 0, to the walls of ROOM."""
    x0, x1, y0, y1 = ROOM
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (x1 - x) / c, np.where(c < 0, (x0 - x) / c, np.inf))
        ty = np.where(s > 0, (y1 - y) / s, np.where(s < 0, (y0 - y) / s, np.inf))
    return np.minimum(tx, ty)


@pytest.fixture(scope="module")
def hand_log(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("hand")
    angles = flaser_angles(180)
    log, ref = [], []
    for k in range(N):
        t = 1.0 + k
        x = 2.0 + STEP * k
        odom_x = SCALE * STEP * k
        log.append(f"ODOM {odom_x:.6f} 0.000000 0.000000 0.0 0.0 0.0 {t:.6f} hand {t:.6f}")
        ranges = " ".join(f"{r:.4f}" for r in _ranges(x, 3.0, angles))
        log.append(f"FLASER 180 {ranges} {odom_x:.6f} 0 0 {odom_x:.6f} 0 0 {t:.6f} hand {t:.6f}")
        ref.append(f"{t:.6f} {x:.6f} 3.000000 0 0 0 0 1")
    (folder / "hand.log").write_text("\n".join(log) + "\n")
    (folder / "reference.tum").write_text("\n".join(ref) + "\n")
    return folder


def _spec(folder: Path, body: dict) -> Path:
    path = folder / f"spec-{abs(hash(yaml.safe_dump(body))) % 10**8}.yaml"
    path.write_text(yaml.safe_dump(body))
    return path


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open() as f:
        return list(csv.DictReader(f))


def test_figures_against_the_hand_computed_case(hand_log, tmp_path):
    """Dead reckoning's ATE and lost fraction are known exactly; houghloc corrects the scale
    error (two settings, both protocols, a LocalCluster of two workers)."""
    spec = _spec(hand_log, {
        "runs": [{"name": "hand", "log": "hand.log", "build_from": "hand.log",
                  "reference": "reference.tum"}],
        "grid": {"filter.gate_probability": [0.99, 0.999]},
        "methods": ["odometry", "houghloc"],
        "protocols": ["same-run", "held-out-map"]})
    outcome = run_sweep(load_spec(spec), tmp_path / "out", workers=2, progress=False)
    assert outcome.ran == 6 and outcome.failed == 0
    rows = {(r["method"], r["protocol"], r["settings"]): r for r in _rows(tmp_path / "out")}
    assert len(rows) == 6
    k = np.arange(N)
    # same run: one piece from the first reference pose; errors 0.07 k
    same = rows[("odometry", "same-run", "{}")]
    err = 0.07 * k
    assert float(same["ate_rmse_m"]) == pytest.approx(math.sqrt(np.mean(err**2)), rel=1e-5)
    assert float(same["ate_max_m"]) == pytest.approx(0.56, rel=1e-5)
    assert float(same["lost_frac"]) == pytest.approx(4 / 9)  # 0.35 … 0.56 m
    assert int(same["scans"]) == N
    # held out: halves split at t = 5 s (scans 1–4 and 5–9), each from its own reference pose
    held = rows[("odometry", "held-out-map", "{}")]
    err = 0.07 * np.r_[np.arange(4), np.arange(5)]
    assert float(held["ate_rmse_m"]) == pytest.approx(math.sqrt(np.mean(err**2)), rel=1e-5)
    assert float(held["ate_max_m"]) == pytest.approx(0.28, rel=1e-5)
    assert float(held["lost_frac"]) == 0.0
    assert float(held["covered_frac"]) == 1.0  # both halves see the same four walls
    for gate in ("0.99", "0.999"):
        for protocol in ("same-run", "held-out-map"):
            row = rows[("houghloc", protocol, f'{{"filter.gate_probability":{gate}}}')]
            assert row["status"] == "ok"
            assert float(row["ate_rmse_m"]) < 0.03, row
            assert float(row["lost_frac"]) == 0.0
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "## same-run" in summary and "## held-out-map" in summary
    assert (tmp_path / "out" / "summary.png").stat().st_size > 10_000
    # a re-run skips every task, and the rows stay one per task
    again = run_sweep(load_spec(spec), tmp_path / "out", workers=1, progress=False)
    assert (again.ran, again.skipped) == (0, 6)
    assert len(_rows(tmp_path / "out")) == 6


def test_a_failing_task_is_a_row_and_the_others_go_on(hand_log, tmp_path):
    (hand_log / "camera-only.yaml").write_text("sensors: {camera: {kind: camera}}\n")
    spec = _spec(hand_log, {
        "runs": [{"name": "hand", "log": "hand.log", "build_from": "hand.log",
                  "reference": "reference.tum"},
                 {"name": "broken", "log": "hand.log", "build_from": "hand.log",
                  "reference": "reference.tum", "config": "camera-only.yaml"}],
        "methods": ["houghloc"]})
    code = main(["sweep", "--spec", str(spec), "--out", str(tmp_path / "o"), "--workers", "1",
                 "--no-progress"])
    assert code == 0
    rows = {r["run"]: r for r in _rows(tmp_path / "o")}
    assert rows["hand"]["status"] == "ok"
    assert rows["broken"]["status"] == "error"
    assert "sensor 'laser' is not configured" in rows["broken"]["error"]
    assert "sensor 'laser' is not configured" in (tmp_path / "o" / "summary.md").read_text()


@pytest.mark.parametrize(("body", "field"), [
    ({"runs": [{"name": "a", "log": "hand.log", "build_from": "hand.log", "colour": 1}]},
     "runs.0.colour"),
    ({"runs": [{"name": "a", "log": "missing.log", "build_from": "hand.log"}]}, "runs.0.log"),
    ({"runs": [{"name": "a", "log": "hand.log", "build_from": "hand.log",
                "max_scans": "many"}]}, "runs.0.max_scans"),
    ({"runs": [{"name": "a", "log": "hand.log", "build_from": "hand.log"}],
      "methods": ["magic"]}, "methods.0"),
    ({"runs": [{"name": "a", "log": "hand.log", "build_from": "hand.log"}],
      "grid": {"filter.gate_probabilty": [0.9]}}, "grid.filter.gate_probabilty"),
    ({"runs": [{"name": "a", "log": "hand.log"}]}, "runs.0"),
])
def test_a_bad_spec_is_one_line_naming_the_file_and_the_field(hand_log, tmp_path, capsys, body,
                                                              field):
    spec = _spec(hand_log, body)
    code = main(["sweep", "--spec", str(spec), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert str(spec) in err and field in err, err
    with pytest.raises(SpecError):
        load_spec(spec)


def test_tasks_a_method_cannot_do_are_left_out(hand_log):
    spec = load_spec(_spec(hand_log, {
        "runs": [{"name": "hand", "log": "hand.log", "build_from": "hand.log",
                  "reference": "reference.tum"},
                 {"name": "given", "log": "hand.log", "map": "hand.log",
                  "reference": "reference.tum"}],
        "methods": ["houghloc", "odometry", "icp"],
        "protocols": ["same-run", "held-out-map", "global-start"]}))
    kinds = {(t.run.name, t.method, t.protocol) for t in expand(spec)}
    assert ("hand", Method.HOUGHLOC, Protocol.GLOBAL_START) in kinds
    assert ("hand", Method.ICP, Protocol.GLOBAL_START) not in kinds  # needs a start pose
    assert ("given", Method.HOUGHLOC, Protocol.HELD_OUT_MAP) not in kinds  # nothing to hold out
    assert len(kinds) == len(expand(spec)) == 3 * 3 - 2 + 3 * 2 - 2


# -- the simulated office: peers, and a cluster started here -------------------------------------


@pytest.fixture(scope="module")
def office_run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("office")
    assert main(["sim", "--scenario", "office-laser", "--out", str(folder / "sim"),
                 "--duration", "30"]) == 0
    return folder


def _office_spec(folder: Path, methods: list[str], protocols: list[str],
                 grid: dict | None = None) -> Path:
    return _spec(folder, {"runs": [{"name": "office", "log": "sim", "map": "sim/map.yaml",
                                    "reference": "sim/gt.tum"}],
                          "methods": methods, "protocols": protocols, "grid": grid or {}})


@pytest.mark.slow  # four methods, two protocols: a benchmark's worth of runs
def test_peers_localize_the_simulated_office(office_run, tmp_path):
    pytest.importorskip("small_gicp", reason="the peers extra is not installed "
                        "(pip install -e '.[peers]'; make test installs it)")
    _need_nav2_amcl()
    spec = _office_spec(office_run, ["houghloc", "icp", "amcl", "amcl-tuned"],
                        ["same-run", "global-start"])
    run_sweep(load_spec(spec), tmp_path / "o", workers=2, progress=False)
    rows = {(r["method"], r["protocol"]): r for r in _rows(tmp_path / "o")}
    assert {r["status"] for r in rows.values()} == {"ok"}
    assert float(rows[("houghloc", "same-run")]["ate_rmse_m"]) < 0.01
    assert float(rows[("icp", "same-run")]["ate_rmse_m"]) < 0.10
    assert float(rows[("amcl", "same-run")]["ate_rmse_m"]) < 0.10
    assert float(rows[("houghloc", "global-start")]["global_time_s"]) < 10.0
    assert ("icp", "global-start") not in rows


def test_a_worker_killed_mid_sweep_loses_nothing(office_run, tmp_path):
    """A scheduler and two workers on localhost; one worker (nanny and process) is killed once
    the first result is in; every task still ends with exactly one row."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "DASK_DISTRIBUTED__LOGGING__DISTRIBUTED": "error"}
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                              start_new_session=True)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(
                [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--no-dashboard"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                start_new_session=True))
        grid = {"filter.gate_probability": [0.9, 0.99, 0.999, 0.9999]}
        spec = _office_spec(office_run, ["houghloc"], ["same-run", "global-start"], grid)
        out = tmp_path / "o"
        sweep = subprocess.Popen([str(BIN / "houghloc"), "sweep", "--spec", str(spec), "--out",
                                  str(out), "--scheduler", address, "--no-progress"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120
        while not ((out / "results.csv").exists() and _rows(out)):
            assert sweep.poll() is None, sweep.communicate()
            assert time.monotonic() < deadline, "no result within 120 s"
            time.sleep(0.2)
        assert len(_rows(out)) < 8, "the sweep ended before a worker could be killed"
        os.killpg(procs[1].pid, signal.SIGKILL)
        _, stderr = sweep.communicate(timeout=300)
        assert sweep.returncode == 0, stderr
        rows = _rows(out)
        assert len(rows) == 8 and len({r["task_id"] for r in rows}) == 8
        assert {r["status"] for r in rows} == {"ok"}, rows
        assert all(float(r["ate_rmse_m"]) < 0.05 for r in rows if r["protocol"] == "same-run")
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


def test_mrpt_peer_on_the_hand_computed_case(hand_log, tmp_path):
    import shutil

    if shutil.which("pf-localization") is None:
        pytest.skip("MRPT's pf-localization is not installed (Debian package mrpt-apps; "
                    "make bench-real installs it)")
    spec = _spec(hand_log, {
        "runs": [{"name": "hand", "log": "hand.log", "build_from": "hand.log",
                  "reference": "reference.tum"}],
        "methods": ["mrpt"], "protocols": ["same-run"]})
    run_sweep(load_spec(spec), tmp_path / "o", workers=1, progress=False)
    (row,) = _rows(tmp_path / "o")
    assert row["status"] == "ok", row["error"]
    assert int(row["scans"]) == N
    assert float(row["ate_rmse_m"]) < 0.15  # 0.07 m × k without the map


def _need_nav2_amcl() -> None:
    from fusion.bench.nav2_amcl import LIBRARY

    if not LIBRARY.exists():
        pytest.skip(f"nav2's AMCL is not built ({LIBRARY}): `make peers` builds it (make test "
                    "runs it), from the amcl source distribution on PyPI, with a C++ compiler")


def test_amcls_integrity_is_the_spread_of_its_particles():
    """The benchmark scores AMCL's reported covariance as houghloc's spread (mode 1): the
    particles drawn around a pose with σ 0.5 m, 0.2 m and 0.1 rad give that covariance back,
    axis by axis, and a probability of being within 0.3 m and 5° well below 0.95."""
    _need_nav2_amcl()
    from fusion.bench.methods import AMCL_NAV2
    from fusion.bench.nav2_amcl import Nav2Amcl
    from fusion.integrity import localized_probability

    filt = Nav2Amcl(min_particles=500, max_particles=2000, alpha_slow=0.0, alpha_fast=0.0,
                    alpha=(0.2,) * 5)
    filt.set_map(np.zeros((100, 100), dtype=np.int8), 0.1, (-5.0, -5.0), "likelihood_field",
                 AMCL_NAV2, 60)
    filt.init_pose(np.array([1.0, 2.0, 0.3]), np.diag([0.25, 0.04, 0.01]))
    mean, got, weighted = filt.estimate()
    assert weighted
    np.testing.assert_allclose(mean, [1.0, 2.0, 0.3], atol=0.1)
    np.testing.assert_allclose(np.diag(got), [0.25, 0.04, 0.01], rtol=0.25)
    assert abs(got[0, 1]) < 0.02
    assert localized_probability(got, 1.0) < 0.5
    assert len(filt.particles()) == 2000  # pf_init draws max_particles


def test_nav2_amcl_repeats_with_its_seed():
    """The same seed gives the same particles after an initial pose and updates, whatever other
    filters the process made before (nav2's Gaussian reseeds from a process-wide count); another
    seed gives others."""
    _need_nav2_amcl()
    from fusion.bench.methods import AMCL_TUNED
    from fusion.bench.nav2_amcl import Nav2Amcl

    walls = np.zeros((120, 120), dtype=np.int8)
    walls[[0, -1], :] = walls[:, [0, -1]] = walls[40:50, 70:80] = 100
    ranges = np.random.default_rng(0).uniform(1.0, 5.0, 90)
    bearings = np.linspace(-np.pi / 2, np.pi / 2, 90)

    def particles(seed: int) -> np.ndarray:
        filt = Nav2Amcl(min_particles=500, max_particles=2000, alpha_slow=0.0, alpha_fast=0.0,
                        alpha=(0.05,) * 5, seed=seed)
        filt.set_map(walls, 0.05, (0.0, 0.0), "likelihood_field", AMCL_TUNED, 90)
        filt.set_laser_pose(np.zeros(3))
        filt.init_pose(np.array([3.0, 3.0, 0.0]), np.diag([0.25, 0.25, 0.07]))
        for k in range(5):
            filt.update(np.array([0.1 * k, 0.0, 0.02 * k]), ranges, bearings, 20.0)
        return filt.particles()

    first = particles(1)
    np.testing.assert_array_equal(first, particles(1))
    other = particles(2)
    assert other.shape != first.shape or not np.array_equal(other, first)


def test_nav2_amcl_finds_the_office_pose_with_its_likelihood_field(office_run):
    """nav2's own filter through the binding, run as the benchmark runs it, on the simulated
    office's map drawn as a grid: started 0.4 m and 10° off with RViz's spread, its heaviest
    cluster is within 5 cm of the truth from 10 s on, and its covariance has shrunk. A wrong
    map orientation, laser mount or bearing sign leaves it off."""
    _need_nav2_amcl()
    from fusion.bench.data import RunData, pose_near, scan_stamp
    from fusion.bench.methods import localize
    from fusion.bench.spec import apply_settings

    spec = load_spec(_office_spec(office_run, ["amcl-tuned"], ["same-run"]))
    data = RunData.load(spec.runs[0], spec.max_dt)
    piece = data.pieces(Protocol.SAME_RUN)[0]
    assert piece.start is not None
    off = dataclasses.replace(piece, start=piece.start + np.array([0.3, -0.25, 0.17]))
    done = localize(Method.AMCL_TUNED, off, apply_settings(spec.runs[0].config, {}))
    errors = []
    for scan, pose in zip(off.scans, done.trajectory.poses, strict=True):
        truth = pose_near(data.reference, scan_stamp(scan), spec.max_dt)
        errors.append(np.hypot(*(pose[:2] - truth[:2])))
    t = done.trajectory.t - done.trajectory.t[0]
    assert errors[0] > 0.25
    assert max(e for e, ti in zip(errors, t, strict=True) if ti >= 10.0) < 0.05
    assert done.probability is not None and done.probability[-1] > done.probability[0]


def test_a_peer_lost_from_the_known_start_is_marked_suspect():
    """The peers' sanity gate: where the tuned AMCL is lost on more than 5 % of a log's scans
    from the known start on its same-run map, every AMCL row of that log says suspect; the
    other logs' rows and houghloc's do not."""
    from fusion.bench.report import summary_markdown, suspect

    def row(run: str, method: str, protocol: str, lost: float) -> dict:
        return {"run": run, "method": method, "protocol": protocol, "settings": "{}",
                "status": "ok", "lost_frac": str(lost), "ate_rmse_m": "0.1", "scans": "10",
                "cpu_ms_per_scan": "1.0"}

    rows = [row("a", "amcl-tuned", "same-run", 0.08), row("a", "amcl", "held-out-map", 0.9),
            row("a", "houghloc", "same-run", 0.0), row("b", "amcl-tuned", "same-run", 0.05),
            row("b", "amcl", "same-run", 0.9)]
    assert suspect(rows) == {("a", "amcl"), ("a", "amcl-tuned"), ("a", "amcl-beam")}
    text = summary_markdown(rows)
    assert "**Suspect** (a)" in text
    assert text.count("· suspect") == 2  # a's amcl-tuned same-run and amcl held-out cells


def test_the_reliability_table_pools_runs_exactly():
    """Each run's reliability table travels in one results.csv cell; the summary pools a
    method's runs into the table the poses of all of them would give."""
    from fusion.bench.report import reliability_markdown
    from fusion.bench.task import reliability_cell
    from fusion.integrity import integrity_scores

    rng = np.random.default_rng(3)
    runs = []
    for n in (200, 300):
        p = rng.uniform(size=n)
        runs.append((p, rng.uniform(size=n) < p))
    rows = [{"method": "houghloc", "protocol": "same-run", "settings": "{}",
             "reliability": reliability_cell(p, right)}
            for p, right in runs]
    rows.append({"method": "odometry", "protocol": "same-run", "settings": "{}",
                 "reliability": ""})  # reports no probability: no row
    text = reliability_markdown(rows)
    pooled = integrity_scores(np.concatenate([p for p, _ in runs]),
                              np.concatenate([r for _, r in runs]))["reliability"]
    lines = [line for line in text.splitlines() if line.startswith("| houghloc")]
    assert len(lines) == 1 and "odometry" not in text
    cells = [c.strip() for c in lines[0].strip("|").split("|")][2:]
    assert len(cells) == len(pooled)
    for cell, b in zip(cells, pooled, strict=True):
        n, mean, share = cell.split(" · ")
        assert int(n.replace(",", "")) == b["scans"] > 0
        assert float(mean) == pytest.approx(b["mean_probability"], abs=6e-4)
        assert float(share) == pytest.approx(b["right"], abs=6e-4)

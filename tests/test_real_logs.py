"""Localization on short slices of the real logs, against the GMapping reference poses.

Skipped when ../shared/data is missing. The figures asserted are what houghloc's defaults reach
(fusion/configs/{intel,fr079,aces}-laser.yaml only describe each laser) with the maps of
fusion/configs/maps on these slices, with a margin; the whole logs are in
``python -m benchmarks.bench_real``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from benchmarks.bench_real import DATA, ROOT, datasets, run, score
from fusion.io.intel_mat import in_order_times

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"real datasets not in {DATA}")

DATASETS = {ds.name: ds for ds in datasets()} if DATA.is_dir() else {}


def _need(name: str):
    ds = DATASETS.get(name)
    if ds is None or not ds.log.exists() or (ds.reference and not ds.reference.exists()):
        pytest.skip(f"{name} data missing")
    return ds


def test_intel_rows_are_fed_in_order_with_their_own_stamps_kept() -> None:
    ds = _need("intel")
    from fusion.io import read_intel_mat

    mat = read_intel_mat(ds.log)
    fixed = in_order_times(mat.t)
    assert (np.diff(fixed) >= 0).all()
    changed = fixed != mat.t
    assert 0 < changed.sum() < 0.1 * len(mat.t)  # a few late stamps, not a re-timing
    scans = [e for e in mat if type(e).__name__ == "Scan"]
    stamps = np.array([s.t if s.stamp is None else s.stamp for s in scans])
    np.testing.assert_array_equal(stamps, mat.t)  # outputs line up with references/relations


def test_intel_first_600_scans_track_the_reference() -> None:
    # measured: ATE 4.9 cm RMSE, 9.5 cm max over 28 reference poses, relations 2.5 cm (47), 494
    # of 600 fixes accepted (57 scans without a usable fix, 42 fixes that would move the scan
    # off the walls refused), never out of tracking
    result = score(run(_need("intel"), limit=600))
    h = result["houghloc"]
    assert h["matched"] >= 20
    assert h["lost"] == 0.0
    assert h["ate_rmse_m"] < 0.06 and h["ate_max_m"] < 0.13
    assert h["relations"]["count"] >= 40 and h["relations"]["translation_mean_m"] < 0.035
    assert result["statuses"].get("accepted", 0) >= 0.8 * result["scans"]
    assert "collecting" not in result["statuses"] and "lost" not in result["statuses"]


def test_fr079_first_300_scans_stay_tracking() -> None:
    # measured: ATE 3.6 cm RMSE, 9.1 cm max, none lost (the tuned configuration before the
    # defaults: 3.6 cm, 10 cm; without scan odometry: 8.4 cm, 37 cm and 1.7 % of the poses
    # beyond 0.3 m / 5°)
    result = score(run(_need("fr079"), limit=300))
    h, odom = result["houghloc"], result["odometry"]
    assert h["matched"] >= 250
    assert h["lost"] == 0.0
    assert h["ate_rmse_m"] < 0.05 and h["ate_max_m"] < 0.15
    assert "collecting" not in result["statuses"] and "lost" not in result["statuses"]
    assert odom["ate_rmse_m"] > 5 * h["ate_rmse_m"]  # better than the odometry's best alignment


def test_aces_first_120_scans_stay_tracking() -> None:
    # measured: ATE 4.7 cm RMSE, 12.1 cm max, none lost (scans ~2 s apart: long odometry
    # stretches between fixes); the odometry's best alignment: 1.28 m
    result = score(run(_need("aces"), limit=120))
    h, odom = result["houghloc"], result["odometry"]
    assert h["matched"] >= 100
    assert h["lost"] == 0.0
    assert h["ate_rmse_m"] < 0.06 and h["ate_max_m"] < 0.2
    assert "collecting" not in result["statuses"] and "lost" not in result["statuses"]
    assert odom["ate_rmse_m"] > 5 * h["ate_rmse_m"]


@pytest.mark.slow
def test_intel_whole_log_never_lost() -> None:
    # measured: ATE 3.7 cm RMSE, 21.3 cm max, none lost. The max is one 1.5 s event at 296 s
    # that appeared when the wheels' scale was learned (0.965 on Intel; the same with the
    # scale set to 0.965 by hand): elsewhere the trajectory is the one before within 0.5 mm
    # (median). Before: 3.4 cm, 13.8 cm (4.05 cm, 14.3 cm before each fix was polished on the
    # scan's points; the tuned configuration before the defaults: 3.8 cm, 11.8 cm)
    result = score(run(_need("intel")))
    h = result["houghloc"]
    assert h["matched"] >= 340
    assert h["lost"] == 0.0
    assert h["ate_rmse_m"] <= 0.04 and h["ate_max_m"] < 0.25


@pytest.mark.slow
def test_fr079_whole_log_keeps_tracking() -> None:
    # measured: ATE 4.5 cm RMSE, 18.6 cm max, two poses lost (4.4 cm, none lost, before the
    # guess was polished on the points where the lines give no usable fix; 4.8 cm before each
    # fix was polished on the scan's points; two poses lost at 898 s in the benchmark's run,
    # where GMapping's own heading jumps 7.5° and back). Tracking is given up once, at 953 s in
    # a room of furniture after 18 scans without a usable fix whose points pass through the
    # map's walls, and taken again 14 scans later, right: the polished guesses before it had
    # tightened the filter, and at 951 s a second line no longer fell inside the matching gate.
    # The tuned configuration before the defaults: 4.8 cm, 21 cm, 0.1 %; without scan
    # odometry: 2.8 %. Since a taken pose must see through walls no more than a right pose
    # does, the run spends 51 scans not tracking instead of about 14: in that room the belief
    # sees 0.2 of each scan through the map's walls, and is taken back only once that falls.
    # Exempting tracking's own belief from the test takes it back as before, but Freiburg 079
    # held out then takes back a drifted belief (confident-wrong 3.7 → 6.4 %), so the belief
    # is tested too.
    result = score(run(_need("fr079")))
    h = result["houghloc"]
    assert h["matched"] >= 4700
    assert h["lost"] <= 0.003
    assert h["ate_rmse_m"] < 0.06 and h["ate_max_m"] < 0.35
    statuses = result["statuses"]
    assert "lost" not in statuses  # never given up for good
    not_tracking = sum(statuses.get(s, 0) for s in ("collecting", "relocalizing", "relocalized"))
    assert not_tracking <= 0.0125 * h["matched"]  # measured 51 of 4,791


@pytest.mark.slow
def test_aces_whole_log_keeps_tracking() -> None:
    # measured: ATE 5.0 cm RMSE, 30.8 cm max, one pose of 440 lost (at 942 s); 5.3 cm before the
    # guess was polished on the points where the lines give no usable fix, 5.5 cm before
    # each fix was polished on the scan's points, 6.9 cm before corridor fixes were placed along
    # the corridor by the scan's points (the tuned configuration before the defaults: 6.5 cm,
    # 28 cm max)
    result = score(run(_need("aces")))
    h = result["houghloc"]
    assert h["matched"] >= 430
    assert h["lost"] <= 1.5 / 440
    assert h["ate_rmse_m"] < 0.06 and h["ate_max_m"] < 0.4


@functools.cache
def _benchmark_row(name: str, protocol: str, method: str = "houghloc") -> dict:
    """A method's row of one of the benchmark's tasks on one log (houghloc: the defaults), run
    once for the tests that read it."""
    from fusion.bench.spec import Method, Protocol, load_spec
    from fusion.bench.task import Task, run_task

    spec = load_spec(ROOT / "benchmarks" / "real.yaml")
    found = next((r for r in spec.runs if r.name == name), None)
    if found is None or not found.log.exists():
        pytest.skip(f"{name} data missing")
    result = run_task(Task(found, Method(method), Protocol(protocol), {}))
    assert result.row["status"] == "ok", result.row["error"]
    return result.row


@pytest.mark.slow
def test_seattle_scans_seconds_apart_keep_the_matched_heading() -> None:
    """seattle's scans come 5 s apart, longer than the filter's 2 s history: the filter holds
    the previous scan's node so that the scan match, not the wheels' noise, carries the motion
    between them. Measured: 2.8 cm, none lost (3.4 cm before each fix was polished on the
    scan's points; 5.2 cm before the hold, when the guess's heading σ reached tens of
    degrees)."""
    row = _benchmark_row("seattle", "same-run")
    assert float(row["lost_frac"]) == 0.0
    assert float(row["ate_rmse_m"]) < 0.035


@pytest.mark.slow
def test_fhw_spin_after_a_stalled_odometry_is_followed() -> None:
    """fhw's odometry stalls for 0.3 s in a spin, then reports a 75° turn in one reading: over
    the stall it is a turn, not a jump. Measured: one pose of 488 lost (9° off at 295 s, where
    the misfit fix itself is 9.3° off), 5.16 cm; two (5.2° off, where the reference's heading
    lags the wheels and the scan match) and 5.2 cm before the guess was polished on the scan's
    points where the lines give no usable fix; one and 5.9 cm before each fix was polished on
    them; five lost and 6.7° of heading RMS when that reading was taken for a jump."""
    row = _benchmark_row("fhw", "same-run")
    assert float(row["lost_frac"]) <= 0.005
    assert float(row["heading_rmse_deg"]) < 1.5
    assert float(row["ate_rmse_m"]) < 0.06


@pytest.mark.slow
@pytest.mark.parametrize("name, lost, ate", [
    pytest.param("intel", 0.042, 0.134, marks=pytest.mark.xfail(strict=True, reason=(
        "since the wheels' scale is learned (0.965; the same with it set by hand) Intel held "
        "out follows a look-alike 17 m away for 28 s at 989 s, reported lost since a taken "
        "pose must see through walls no more than a right pose does (taken before): ATE "
        "2.41 m, 2.9 % of the covered poses lost; open in the issue on places never seen"))),
    ("fhw", 0.02, 0.12)])
def test_held_out_maps_are_not_left_for_look_alikes(name, lost, ate) -> None:
    """In the map of the other part of the run, which lacks rooms the robot passes through, the
    robot is lost no more often than nav2's tuned AMCL is there, and no further (Intel 4.2 % of
    the covered poses, 13.4 cm ATE; fhw 14 %, 1.7 m, where the bound is tighter): a look-alike is
    weighed by what the robot would see through walls there, and scans that land where the map
    has nothing are no evidence against the belief. Measured: Intel 2.6 % of the covered poses,
    ATE 9.5 cm (1.3 %, 9.6 cm before the guess was polished on the points where the lines give
    no usable fix; 1.9 %, 10 cm before each fix was polished on the scan's points; 12.5 %, 5.1 m
    when only the points on walls counted); fhw 0 %, 7.2 cm (0.2 %, 8.0 cm before the polish;
    7.5 %, 32 cm; 3.9 %, 15 cm before corridor fixes were placed along the corridor; 0.4 %,
    8.5 cm before the filter held its history back to the previous scan)."""
    row = _benchmark_row(name, "held-out-map")
    assert float(row["lost_covered_frac"]) <= lost
    assert float(row["ate_rmse_m"]) < ate


@pytest.mark.slow
def test_a_look_alike_in_a_held_out_map_is_not_reported_localized() -> None:
    """Intel in the map of the corrected scans after the run: at 990 s the robot is where that
    map lacks walls it sees, and the best pose a global match proposes is a look-alike 17 m
    away that sees more of each scan through walls than a right pose does. It is followed, and
    reported lost, not taken: a taken pose must see through walls no more than a right pose
    does (0.05 within its binomial noise). Measured: no pose reported localized while > 0.3 m
    or 5° off; 0.87 % before (the look-alike taken for 16 s)."""
    row = _benchmark_row("intel", "held-out-map")
    assert float(row["confident_wrong_frac"]) <= 0.001


@pytest.mark.slow
@pytest.mark.parametrize("name", ["aces", "freiburg-101", "intel"])
def test_the_tuned_amcl_passes_its_sanity_gate(name) -> None:
    """nav2's AMCL with its tuned set, from the known start on the map of the same run, is lost
    on at most 5 % of the scans of these logs (measured: ACES 2.3 %, Freiburg 101 1.4 %, Intel
    3.8 %); on fhw, Freiburg 079 and seattle it is not (15.4, 84.0 and 7.5 %), and summary.md
    marks its rows there suspect (fusion.bench.report.suspect)."""
    from fusion.bench.nav2_amcl import LIBRARY
    from fusion.bench.report import PEER_SANITY_LOST

    if not LIBRARY.exists():
        pytest.skip(f"nav2's AMCL is not built ({LIBRARY}): make peers")
    row = _benchmark_row(name, "same-run", "amcl-tuned")
    assert float(row["lost_frac"]) <= PEER_SANITY_LOST

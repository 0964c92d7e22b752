"""Readers and writers: real logs (skipped when the data folder is absent), malformed files, TUM,
relations, ROS bags and ``open_log``."""

from __future__ import annotations

import gzip
import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.events import Odometry, PointSet, Scan, Truth
from fusion.io import (
    INTEL_TIME_OFFSET,
    FlaserSpacing,
    LogError,
    TrajectoryValueError,
    TumWriter,
    atomic_write_json,
    atomic_write_text,
    open_log,
    read_carmen,
    read_intel_mat,
    read_reference,
    read_relations,
    read_rosbag,
    read_tum,
    write_tum,
)
from fusion.io.numbers import parse_floats
from houghloc.geometry import compose, inverse, relative, wrap_angle

DATA = Path("/work/shared/data")
INTEL_MAT = DATA / "intel" / "scan_intel.mat"
INTEL_GFS = DATA / "intel" / "intel.gfs.log"
INTEL_RELATIONS = DATA / "intel" / "intel.relations"
FR079 = DATA / "fr079" / "freiburg-079-corrected.log.gz"
ACES = DATA / "aces" / "aces-corrected.log.gz"


def needs(*paths: Path) -> pytest.MarkDecorator:
    missing = [str(p) for p in paths if not p.exists()]
    return pytest.mark.skipif(bool(missing), reason=f"real data not present: {', '.join(missing)}")


def split(events):
    odometry = [e for e in events if isinstance(e, Odometry)]
    scans = [e for e in events if isinstance(e, Scan)]
    return odometry, scans


# -- real data -------------------------------------------------------------------------------------


@needs(INTEL_MAT)
def test_intel_mat_reads_5505_scans_of_180_beams_with_odometry_first():
    log = read_intel_mat(INTEL_MAT)
    events = list(log)
    odometry, scans = split(events)
    assert len(scans) == len(odometry) == 5505
    assert all(len(s.ranges) == 180 for s in scans)
    assert isinstance(events[0], Odometry) and isinstance(events[1], Scan)
    assert events[0].t == events[1].t
    assert scans[0].angles[0] == pytest.approx(-np.pi / 2)
    assert scans[0].angles[-1] == pytest.approx(np.pi / 2)
    assert log.stats.records == 5505
    assert log.stats.backwards_timestamps > 0  # the raw data is not monotonic
    assert np.count_nonzero(np.concatenate([s.ranges for s in scans]) >= scans[0].max_range) > 0


@needs(INTEL_MAT, INTEL_GFS)
def test_intel_gfs_raw_odometry_increments_match_the_mat():
    mat = read_intel_mat(INTEL_MAT)
    odometry, _ = split(list(read_carmen(INTEL_GFS)))
    log_t = np.array([o.t for o in odometry])
    log_pose = np.array([(o.x, o.y, o.theta) for o in odometry])
    # The log prints 6 significant digits: a timestamp matches a .mat row when that row is the only
    # one within half a printed digit, and the log has no other line with the same printed time.
    tol = 0.5 * 10.0 ** (np.floor(np.log10(np.maximum(log_t, 1e-6))) - 5) + 1e-9
    order = np.argsort(mat.t)
    mat_sorted = mat.t[order]
    lo = np.searchsorted(mat_sorted, log_t - tol)
    hi = np.searchsorted(mat_sorted, log_t + tol, side="right")
    _, first, counts = np.unique(log_t, return_index=True, return_counts=True)
    unique_time = np.zeros(len(log_t), bool)
    unique_time[first[counts == 1]] = True
    ok = (hi - lo == 1) & unique_time
    log_idx = np.flatnonzero(ok)
    mat_idx = order[lo[ok]]
    assert len(log_idx) > 5000
    errors = []
    for (a, ma), (b, mb) in zip(
        zip(log_idx[:-1], mat_idx[:-1], strict=True),
        zip(log_idx[1:], mat_idx[1:], strict=True),
        strict=True,
    ):
        d = relative(log_pose[a], log_pose[b]) - relative(mat.odom[ma], mat.odom[mb])
        d[2] = wrap_angle(d[2])
        errors.append(np.abs(d))
    errors = np.array(errors)
    assert np.percentile(errors, 99, axis=0).max() < 1e-4
    assert errors.max() < 2e-4  # 6 printed digits of positions up to ~20 m


@pytest.mark.parametrize(
    ("path", "scans", "odom_lines", "beams"),
    [
        pytest.param(INTEL_GFS, 910, 14541, 180, marks=needs(INTEL_GFS)),
        pytest.param(FR079, 4791, 9725, 360, marks=needs(FR079)),
        pytest.param(ACES, 440, 7814, 180, marks=needs(ACES)),
    ],
    ids=["intel", "fr079", "aces"],
)
def test_corrected_logs_parse_with_the_documented_counts(path, scans, odom_lines, beams):
    log = read_carmen(path)
    assert log.corrected
    odometry, scan_events = split(list(log))
    assert len(scan_events) == scans
    # Every laser record is followed by one re-anchoring ODOM line, which is not motion.
    assert len(odometry) == odom_lines - scans
    assert {len(s.ranges) for s in scan_events} == {beams}
    assert all(s.reference is not None for s in scan_events)
    assert log.stats.skipped == 0
    assert log.stats.records == odom_lines + scans
    # The ODOM line before each laser record carries its timestamp: odometry exists at scan times.
    odometry_times = {o.t for o in odometry}
    assert all(s.t in odometry_times for s in scan_events)


@pytest.mark.parametrize(
    ("path", "min_drift"),
    [
        pytest.param(INTEL_GFS, 20.0, marks=needs(INTEL_GFS)),
        pytest.param(ACES, 5.0, marks=needs(ACES)),
    ],
    ids=["intel", "aces"],
)
def test_reference_never_leaks_into_odometry(path, min_drift):
    last, pairs = None, []
    for event in read_carmen(path):
        if isinstance(event, Odometry):
            last = event
        elif last is not None and last.t == event.t:
            pairs.append(((last.x, last.y, last.theta), event.reference))
    odometry = np.array([p for p, _ in pairs])
    reference = np.array([r for _, r in pairs])
    # Put the odometry into the map frame at the first scan; then only drift separates them.
    to_map = compose(reference[0], inverse(odometry[0]))
    in_map = np.array([compose(to_map, p) for p in odometry])
    drift = np.hypot(*(in_map[:, :2] - reference[:, :2]).T)
    assert drift[0] == pytest.approx(0.0, abs=1e-9)
    assert drift.max() > min_drift


@needs(INTEL_RELATIONS)
def test_intel_relations_with_time_offset():
    relations = read_relations(INTEL_RELATIONS, INTEL_TIME_OFFSET)
    assert len(relations) == 2984
    assert relations.t1.min() > 0 and relations.t2.max() < 2700
    assert relations.delta.shape == (2984, 3)
    assert np.all(np.abs(relations.delta[:, 2]) <= np.pi)


# -- synthetic CARMEN ------------------------------------------------------------------------------


def odom_line(x, y, theta, t):
    return f"ODOM {x:.9g} {y:.9g} {theta:.9g} 0 0 0 {t:.9g} host {t:.9g}"


def flaser_line(ranges, pose, odom, t):
    r = " ".join(f"{v:g}" for v in ranges)
    p = " ".join(f"{v:.9g}" for v in (*pose, *odom))
    return f"FLASER {len(ranges)} {r} {p} {t:.9g} host {t:.9g}"


def write_log(path: Path, lines, compress=False) -> Path:
    text = "\n".join(lines) + "\n"
    if compress:
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return path


RAW_LOG = [
    "# CARMEN logfile",
    "PARAM robot_use_laser on host 0",
    odom_line(0.0, 0.0, 0.0, 1.0),
    flaser_line([1.0, 2.0, 81.83, 3.0, 4.0], (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0),
    odom_line(0.1, 0.0, 0.01, 1.2),
    "SYNC something 1.3 host 1.3",
    odom_line(0.2, 0.0, 0.02, 1.4),
    flaser_line([1.0, 2.0, 3.0, 3.5, 4.0], (0.2, 0.0, 0.02), (0.2, 0.0, 0.02), 1.4),
]


def test_raw_carmen_log_values_and_angles(tmp_path):
    log = read_carmen(write_log(tmp_path / "raw.log", RAW_LOG))
    assert not log.corrected
    events = list(log)
    assert [type(e).__name__ for e in events] == [
        "Odometry",
        "Scan",
        "Odometry",
        "Odometry",
        "Scan",
    ]
    odometry, scans = split(events)
    assert (odometry[1].x, odometry[1].theta, odometry[1].t) == (0.1, 0.01, 1.2)
    assert scans[0].reference is None
    np.testing.assert_allclose(scans[0].angles, -np.pi / 2 + np.arange(5) * np.pi / 5)
    assert scans[0].ranges[2] >= scans[0].max_range  # 81.83: no return
    assert scans[0].line == 4
    assert log.stats.records == 5 and log.stats.skipped == 0


def test_flaser_spacing_is_a_parameter(tmp_path):
    log = read_carmen(write_log(tmp_path / "raw.log", RAW_LOG), spacing=FlaserSpacing.ENDPOINTS)
    _, scans = split(list(log))
    np.testing.assert_allclose(scans[0].angles, np.linspace(-np.pi / 2, np.pi / 2, 5))


def test_gzip_log_reads_like_plain(tmp_path):
    plain = list(read_carmen(write_log(tmp_path / "a.log", RAW_LOG)))
    packed = list(read_carmen(write_log(tmp_path / "a.log.gz", RAW_LOG, compress=True)))
    assert [e.t for e in plain] == [e.t for e in packed]
    np.testing.assert_array_equal(plain[1].ranges, packed[1].ranges)


def test_truncated_last_line_is_skipped_with_its_line_number(tmp_path, caplog):
    text = "\n".join(RAW_LOG)
    path = tmp_path / "cut.log"
    path.write_text(text[: len(text) - 40])  # cut inside the last FLASER's pose fields
    log = read_carmen(path)
    with caplog.at_level(logging.WARNING, logger="fusion.io.carmen"):
        events = list(log)
    assert len(events) == 4
    assert log.stats.skipped == 1
    assert "line 8" in log.stats.warnings[0] and "truncated" in log.stats.warnings[0]
    assert "line 8" in caplog.text


def test_nan_pose_and_garbage_lines_are_reported(tmp_path):
    lines = [
        *RAW_LOG[:3],
        "ODOM 0.1 nan 0 0 0 0 1.1 host 1.1",
        "ODOM 0.1 abc 0 0 0 0 1.1 host 1.1",
        "@@@ this is not a record ###",
        "FLASER 7 1 2 3 0 0 0 0 0 0 1.1 host 1.1",  # says 7 beams, has 3
        "FLASER 2 1 nan 0 0 0 0 0 0 1.1 host 1.1",  # NaN range: no return, the scan is used
        "UNKNOWNRECORD 1 2 3",  # an unknown record type: skipped silently
        *RAW_LOG[3:],
    ]
    log = read_carmen(write_log(tmp_path / "bad.log", lines))
    events = list(log)
    assert len(events) == 6
    assert events[1].ranges[1] == np.inf
    assert log.stats.skipped == 4
    for number, text in zip(
        (4, 5, 6, 7, 8), ("non-finite", "non-numeric", "not a CARMEN", "needs", "NaN"), strict=True
    ):
        assert any(f"line {number}:" in w and text in w for w in log.stats.warnings), number


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", "empty"),
        (b"\n\n   \n", "empty"),
        (bytes(range(256)) * 40, "binary"),
        (b"hello world\nthis is prose, not a robot log\n", "not a CARMEN log"),
    ],
    ids=["empty", "blank", "binary", "prose"],
)
def test_bad_files_raise_log_error(tmp_path, content, reason):
    path = tmp_path / "bad.log"
    path.write_bytes(content)
    with pytest.raises(LogError, match=reason) as info:
        list(read_carmen(path))
    assert info.value.path == path


def test_missing_file_and_no_usable_record_raise_log_error(tmp_path):
    with pytest.raises(LogError, match="not found"):
        read_carmen(tmp_path / "nope.log")
    path = write_log(
        tmp_path / "allbad.log", ["PARAM a b host 0", "ODOM 1 2", "ODOM x y z 0 0 0 1"]
    )
    log = read_carmen(path)
    with pytest.raises(LogError, match="no usable record"):
        list(log)
    assert log.stats.skipped == 2


def test_backwards_timestamps_are_kept_and_counted(tmp_path):
    lines = [odom_line(0, 0, 0, 2.0), odom_line(0, 0, 0, 1.5), odom_line(0, 0, 0, 3.0)]
    log = read_carmen(write_log(tmp_path / "back.log", lines))
    assert [e.t for e in log] == [2.0, 1.5, 3.0]
    assert log.stats.backwards_timestamps == 1


def test_old_log_without_odom_takes_odometry_from_laser_lines(tmp_path):
    lines = [
        flaser_line([1.0, 2.0, 3.0], (5.0, 5.0, 1.0), (0.1, 0.2, 0.3), 1.0),
        flaser_line([1.0, 2.0, 3.0], (5.5, 5.0, 1.0), (0.6, 0.2, 0.3), 2.0),
    ]
    log = read_carmen(write_log(tmp_path / "old.log", lines))
    assert log.conventions.laser_odometry and not log.corrected
    events = list(log)
    assert [type(e).__name__ for e in events] == ["Odometry", "Scan"] * 2
    assert (events[2].x, events[2].y, events[2].theta, events[2].t) == (0.6, 0.2, 0.3, 2.0)


def test_robotlaser1_and_truepos(tmp_path):
    ranges = [1.0, 2.0, 30.0, 4.0]
    robot = "1 2 0.5"
    record = (
        f"ROBOTLASER1 0 -1.5 3.0 1.0 30.0 0.01 0 4 {' '.join(map(str, ranges))} 2 7 8 "
        f"1.1 2.0 0.5 {robot} 0.3 0.1 0.5 0.3 0 12.5 host 12.5"
    )
    truth = "TRUEPOS 3 4 0.25 1 2 0.5 12.5 host 12.5"
    log = read_carmen(write_log(tmp_path / "rl.log", [record, truth]))
    events = list(log)
    odometry, scans = split(events)
    assert len(scans) == 1 and len(odometry) == 1  # no ODOM lines: odometry from the robot pose
    np.testing.assert_allclose(scans[0].angles, [-1.5, -0.5, 0.5, 1.5])
    assert scans[0].max_range == 30.0 and scans[0].t == 12.5
    assert (odometry[0].x, odometry[0].y, odometry[0].theta) == (1.0, 2.0, 0.5)
    assert isinstance(events[-1], Truth) and (events[-1].x, events[-1].theta) == (3.0, 0.25)


def corrected_log(rng, steps=60, scan_every=5):
    """A synthetic corrected log: raw odometry, corrections that jump at each laser record, anchors
    with the odd timestamps seen in real logs. Returns (lines, raw poses at ODOM lines t > 0)."""
    raw = [np.array([576.5, 0.1, -2.26])]
    for _ in range(steps - 1):
        raw.append(compose(raw[-1], [0.1 + 0.02 * rng.random(), 0.0, 0.05 * rng.standard_normal()]))
    lines, logged_raw = [], []
    correction = np.zeros(3)  # map ⊖ odom, changes at each laser record
    anchor_time = iter([0.0, 1.13, 8.97771e-67, -0.958593, 0.0] * 100)
    current = None
    for k, pose in enumerate(raw):
        t = 10.0 + 0.2 * k
        if current is None:
            current = pose.copy()
        else:
            current = compose(current, relative(raw[k - 1], pose))
        lines.append(odom_line(*current, t))
        logged_raw.append(pose)
        if k % scan_every == scan_every - 1:
            correction = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.normal(0, 0.05)])
            reference = compose(correction, current)
            lines.append(flaser_line([1.0, 2.0, 3.0], reference, reference, t))
            lines.append(odom_line(*reference, next(anchor_time)))
            lines.append("NEFF 12.5")
            current = np.array([float(f"{v:.9g}") for v in reference])
    return lines, np.array(logged_raw)


def test_corrected_log_rebuilds_raw_odometry_without_the_reference(tmp_path):
    lines, raw = corrected_log(np.random.default_rng(1))
    log = read_carmen(write_log(tmp_path / "corr.log", lines))
    assert log.corrected
    odometry, scans = split(list(log))
    assert len(odometry) == len(raw) and len(scans) == 12
    got = np.array([(o.x, o.y, o.theta) for o in odometry])
    # The rebuilt chain starts at the log's first pose; every increment is the raw motion.
    for k in range(1, len(raw)):
        np.testing.assert_allclose(
            relative(got[k - 1], got[k]), relative(raw[k - 1], raw[k]), atol=1e-6
        )  # the log prints 9 significant digits: ~1e-6 m at x ≈ 576 m
    np.testing.assert_allclose(got, raw, atol=1e-4)
    assert all(s.reference is not None for s in scans)
    assert log.stats.backwards_timestamps == 0  # anchors (odd timestamps) are not events


def test_motion_lost_before_a_laser_record_is_reported_unmeasured(tmp_path):
    """The ODOM line before a laser record normally carries its time. When it is 3 s older, the
    motion from it went into the re-anchoring jump (seattle at 100.87 s: an 80° turn): the
    reader says so with a reading at the record's time, and the chain goes on from the anchor."""
    raw = [np.array([2.0, 1.0, 0.3])]
    for _ in range(5):
        raw.append(compose(raw[-1], [0.1, 0.0, 0.02]))
    reference = np.array([7.0, -3.0, 1.9])  # the corrected pose after the lost turn
    after = compose(reference, [0.1, 0.0, 0.05])
    lines = [odom_line(*raw[0], 10.0), odom_line(*raw[1], 10.2),
             flaser_line([1.0, 2.0], raw[1], raw[1], 10.2), odom_line(*raw[1], 0.0),
             odom_line(*raw[2], 10.4),
             flaser_line([1.0, 2.0], reference, reference, 13.4), odom_line(*reference, 0.0),
             odom_line(*after, 13.6)]
    log = read_carmen(write_log(tmp_path / "hole.log", lines))
    assert log.corrected
    odometry, scans = split(list(log))
    assert [o.t for o in odometry] == [10.0, 10.2, 10.4, 13.4, 13.6]
    assert [o.unmeasured for o in odometry] == pytest.approx([0, 0, 0, 3.0, 0])
    got = np.array([(o.x, o.y, o.theta) for o in odometry])
    np.testing.assert_allclose(got[3], got[2])  # nothing measured over the hole
    np.testing.assert_allclose(relative(got[3], got[4]), [0.1, 0.0, 0.05], atol=1e-6)
    assert [s.t for s in scans] == [10.2, 13.4]


def test_raw_odometry_flag_overrides_detection(tmp_path):
    lines, raw = corrected_log(np.random.default_rng(2))
    log = read_carmen(write_log(tmp_path / "corr.log", lines), raw_odometry=True)
    odometry, scans = split(list(log))
    assert not log.corrected and scans[0].reference is None
    assert len(odometry) > len(raw)  # the anchors are taken as odometry: the caller asked for it



def test_a_reference_is_a_tum_file_or_the_poses_a_corrected_log_carries(tmp_path):
    """``read_reference`` (``--gt``): a corrected CARMEN log's scan poses, plain or gzip; a TUM
    file as ``read_tum`` reads it; a raw log, whose scans carry no corrected pose, is refused
    with the reason."""
    lines, raw = corrected_log(np.random.default_rng(3))
    plain = write_log(tmp_path / "corr.log", lines)
    scans = [e for e in read_carmen(plain) if isinstance(e, Scan)]
    t, poses = read_reference(plain)
    assert len(t) == 12 and t.tolist() == [s.t for s in scans]
    np.testing.assert_array_equal(poses, [s.reference for s in scans])
    t_gz, poses_gz = read_reference(write_log(tmp_path / "corr.log.gz", lines, compress=True))
    np.testing.assert_array_equal(t_gz, t)
    np.testing.assert_array_equal(poses_gz, poses)
    tum = write_tum(tmp_path / "ref.tum", t, poses)
    for got, expected in zip(read_reference(tum), read_tum(tum), strict=True):
        np.testing.assert_array_equal(got, expected)
    uncorrected = [odom_line(*pose, 10.0 + 0.2 * k) for k, pose in enumerate(raw)]
    uncorrected.insert(5, flaser_line([1.0, 2.0], raw[4], raw[4], 10.8))
    with pytest.raises(LogError, match="no corrected pose"):
        read_reference(write_log(tmp_path / "raw.log", uncorrected))


# -- TUM, atomic files, relations ------------------------------------------------------------------


def test_tum_round_trip(tmp_path):
    t = np.array([0.0, 0.5, 1.25])
    poses = np.array([[0.0, 0.0, 0.0], [1.5, -2.0, 3.1], [-4.0, 0.25, -3.1]])
    path = write_tum(tmp_path / "traj.tum", t, poses)
    fields = path.read_text().splitlines()[1].split()
    assert len(fields) == 8 and fields[3] == "0.000000"
    got_t, got = read_tum(path)
    np.testing.assert_allclose(got_t, t)
    np.testing.assert_allclose(got[:, :2], poses[:, :2], atol=1e-6)
    np.testing.assert_allclose(wrap_angle(got[:, 2] - poses[:, 2]), 0.0, atol=1e-8)


def test_tum_writer_refuses_non_finite_poses(tmp_path):
    with TumWriter(tmp_path / "t.tum") as writer:
        writer.write(0.0, 1.0, 2.0, 0.1)
        with pytest.raises(TrajectoryValueError, match="non-finite"):
            writer.write(0.1, float("nan"), 2.0, 0.1)
        with pytest.raises(TrajectoryValueError):
            writer.write_pose(0.2, [1.0, np.inf, 0.0])
    assert len((tmp_path / "t.tum").read_text().splitlines()) == 1


def test_interrupted_tum_writer_leaves_only_complete_lines(tmp_path):
    path = tmp_path / "killed.tum"
    script = (
        "import os\n"
        "from fusion.io.tum import TumWriter\n"
        f"w = TumWriter({str(path)!r}).open()\n"
        "for k in range(50):\n"
        "    w.write(k * 0.1, k * 1.0, -k * 0.5, 0.01 * k)\n"
        "os._exit(3)  # dies without closing the file or running any cleanup\n"
    )
    result = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[1])
    assert result.returncode == 3
    text = path.read_text()
    assert text.endswith("\n")
    t, poses = read_tum(path)
    assert len(t) == 50 and poses[-1, 0] == 49.0


def test_read_tum_reports_bad_lines(tmp_path):
    path = tmp_path / "bad.tum"
    path.write_text("# header\n0 0 0 0 0 0 0 1\n1 0 0 0 0 0\n")
    with pytest.raises(LogError, match="line 3"):
        read_tum(path)
    path.write_text("0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n")
    with pytest.raises(LogError, match="line 2: non-numeric"):
        read_tum(path)


def test_atomic_writes(tmp_path):
    target = tmp_path / "sub" / "metrics.json"
    atomic_write_json(target, {"rmse": np.float64(0.25), "n": np.int64(3), "v": np.arange(2)})
    assert json.loads(target.read_text()) == {"rmse": 0.25, "n": 3, "v": [0, 1]}
    with pytest.raises(ValueError):
        atomic_write_json(target, {"rmse": float("nan")})
    assert json.loads(target.read_text())["n"] == 3  # the old file is untouched
    atomic_write_text(target, "replaced")
    assert target.read_text() == "replaced"
    assert sorted(p.name for p in target.parent.iterdir()) == ["metrics.json"]


def test_relations_time_offset_and_bad_line(tmp_path):
    path = tmp_path / "r.relations"
    path.write_text("1000.5 1001.5 0.1 0.2 0 0 0 3.2\n")
    relations = read_relations(path, time_offset=1000.0)
    np.testing.assert_allclose([relations.t1[0], relations.t2[0]], [0.5, 1.5])
    assert relations.delta[0, 2] == pytest.approx(3.2 - 2 * np.pi)
    path.write_text("1000.5 1001.5 0.1 0.2 0 0 0 3.2\n1 2 3\n")
    with pytest.raises(LogError, match="line 2"):
        read_relations(path)


# -- ROS bags ----------------------------------------------------------------------------------


def _ros_messages(typestore, ros1: bool):
    types = typestore.types
    time_cls = types["builtin_interfaces/msg/Time"]

    def header(t):
        stamp = time_cls(sec=int(t), nanosec=round((t % 1) * 1e9))
        if ros1:
            return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="base")
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id="base")

    def odometry(t, x, y, theta):
        g = types
        pose = g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=g["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=np.sin(theta / 2), w=np.cos(theta / 2)
            ),
        )
        zero = g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return g["nav_msgs/msg/Odometry"](
            header=header(t),
            child_frame_id="base",
            pose=g["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=g["geometry_msgs/msg/TwistWithCovariance"](
                twist=g["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=np.zeros(36),
            ),
        )

    def scan(t):
        return types["sensor_msgs/msg/LaserScan"](
            header=header(t),
            angle_min=-1.0,
            angle_max=1.0,
            angle_increment=0.5,
            time_increment=0.0,
            scan_time=0.1,
            range_min=0.1,
            range_max=30.0,
            ranges=np.array([1.0, 30.0, np.nan, 0.05, 2.5], dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    return odometry, scan


def _check_bag_events(events):
    odometry, scans = split(events)
    assert len(odometry) == 2 and len(scans) == 2
    assert odometry[1].t == pytest.approx(101.25)
    assert (odometry[1].x, odometry[1].y) == (1.0, 2.0)
    assert odometry[1].theta == pytest.approx(2.5)
    np.testing.assert_allclose(scans[0].angles, [-1.0, -0.5, 0.0, 0.5, 1.0])
    assert scans[0].max_range == 30.0 and scans[0].sensor == "laser"
    assert scans[0].ranges[0] == 1.0 and scans[0].ranges[1] >= scans[0].max_range
    assert np.isinf(scans[0].ranges[2:4]).all()  # NaN and below range_min: no return


def test_rosbag1_round_trip(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    odometry, scan = _ros_messages(store, ros1=True)
    path = tmp_path / "run.bag"
    with Writer(path) as writer:
        c_odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        c_scan = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for k, t in enumerate((100.5, 101.25)):
            msg = odometry(t, float(k), 2.0 * k, 2.5 * k)
            writer.write(c_odom, int(t * 1e9), store.serialize_ros1(msg, msg.__msgtype__))
            msg = scan(t + 0.01)
            writer.write(c_scan, int((t + 0.01) * 1e9), store.serialize_ros1(msg, msg.__msgtype__))
    log = read_rosbag(path)
    _check_bag_events(list(log))
    assert log.stats.records == 4
    events, stats = open_log(path)
    assert len(list(events)) == 4 and stats.records == 4


def test_a_simulator_directory_brings_its_camera_points_and_their_warnings(tmp_path):
    write_log(tmp_path / "log.carmen", RAW_LOG)
    (tmp_path / "camera.points").write_text(
        "POINTS 1.1 1.3 2 0.5 0.0 0.6 0.1\n"
        "POINTS 1.5 oops\n"  # truncated: skipped, counted and named by its line
        "POINTS 1.6 1.7 1 1.0 1.0\n")
    with pytest.warns(UserWarning, match="camera.points:2"):
        events, stats = open_log(tmp_path)
        events = list(events)
    points = [e for e in events if isinstance(e, PointSet)]
    assert [(p.t, p.arrival, len(p.points)) for p in points] == [(1.1, 1.3, 2), (1.6, 1.7, 1)]
    assert stats.skipped == 1 and any("camera.points:2" in w for w in stats.warnings)
    assert stats.records == 5 + 2


def test_rosbag2_round_trip_and_open_log(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    odometry, scan = _ros_messages(store, ros1=False)
    path = tmp_path / "run2"
    with Writer(path, version=9) as writer:
        c_odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        c_scan = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for k, t in enumerate((100.5, 101.25)):
            msg = odometry(t, float(k), 2.0 * k, 2.5 * k)
            writer.write(c_odom, int(t * 1e9), store.serialize_cdr(msg, msg.__msgtype__))
            msg = scan(t + 0.01)
            writer.write(c_scan, int((t + 0.01) * 1e9), store.serialize_cdr(msg, msg.__msgtype__))
    events, stats = open_log(path)
    _check_bag_events(list(events))
    assert stats.records == 4


def test_rosbag_errors(tmp_path):
    with pytest.raises(LogError, match="not found"):
        read_rosbag(tmp_path / "none.bag")
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    with pytest.raises(LogError, match="cannot open"):
        list(read_rosbag(junk))


# -- open_log --------------------------------------------------------------------------------------


def test_open_log_dispatch_and_simulator_directory(tmp_path):
    write_log(tmp_path / "plain.log", RAW_LOG)
    events, stats = open_log(tmp_path / "plain.log")
    assert len(list(events)) == 5 and stats.records == 5

    sim = tmp_path / "sim"
    sim.mkdir()
    write_log(sim / "log.carmen", RAW_LOG)

    def camera(directory: Path):
        assert directory == sim
        return [PointSet(1.1, np.zeros((2, 2))), PointSet(1.5, np.ones((1, 2)))]

    events, stats = open_log(sim, extra_sources=[camera])
    events = list(events)
    assert [type(e).__name__ for e in events] == [
        "Odometry", "Scan", "PointSet", "Odometry", "Odometry", "Scan", "PointSet",
    ]  # fmt: skip
    assert stats.records == 5

    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(LogError, match="directory"):
        open_log(tmp_path / "empty_dir")
    with pytest.raises(LogError, match="not found"):
        open_log(tmp_path / "missing.log")
    bad_mat = tmp_path / "x.mat"
    bad_mat.write_bytes(b"garbage")
    with pytest.raises(LogError, match="MATLAB"):
        open_log(bad_mat)


@needs(INTEL_MAT)
def test_open_log_intel_mat():
    events, stats = open_log(INTEL_MAT)
    first = next(events)
    assert isinstance(first, Odometry) and stats.records == 1


@settings(max_examples=300)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=1,
                max_size=50),
       st.sampled_from(["{!r}", "{:.3f}", "{:.6f}", "{:.2e}", "{:.17g}", "{:+.1f}"]))
def test_a_records_numbers_parse_exactly_as_float_does(values, form):
    """The compiled parser's fast path (≤ 15 digits, ≤ 10²²) and its fallback give float()'s
    double, bit for bit, whatever way the numbers were written."""
    tokens = [form.format(v) for v in values]
    parsed = parse_floats(tokens)
    expected = np.array([float(t) for t in tokens])
    assert parsed.tobytes() == expected.tobytes()


def test_a_non_numeric_range_is_named_not_misread():
    with pytest.raises(ValueError, match=r"'1\.2\.3'"):
        parse_floats(["1.5", "1.2.3"])
    np.testing.assert_array_equal(parse_floats(["nan", "-inf", "7"]), [np.nan, -np.inf, 7.0])

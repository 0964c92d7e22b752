"""Logs as they come: CARMEN logs whose stamps cannot order their records are read by the
records' order, and logs whose stamps run backwards throughout are read negated
(fusion.io.carmen_conventions.StampClock); either way the run localizes as the log with true stamps
does."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from fusion.config import LocalizerConfig
from fusion.evaluation import ATE, Trajectory
from fusion.events import Odometry, Scan
from fusion.io.carmen import read_carmen
from fusion.io.carmen_conventions import NOMINAL_ODOMETRY_RATE, StampClock
from fusion.run_log import open_source, run_log
from fusion.sim import scenario_preset, simulate, write_run


@pytest.fixture(scope="module")
def office_log(tmp_path_factory):
    run = simulate(scenario_preset("office-laser", seed=4, duration=40.0))
    out = tmp_path_factory.mktemp("office")
    write_run(run, out)
    return out, run


def _restamped(src, dst, stamp):
    """The log with each record's two stamps (ipc and logger) replaced by stamp(t)."""
    lines = []
    for line in (src / "log.carmen").read_text().splitlines():
        tokens = line.split()
        if tokens and tokens[0] in ("ODOM", "ROBOTLASER1", "FLASER"):
            t = float(tokens[-3])
            tokens[-3] = tokens[-1] = stamp(t)
            line = " ".join(tokens)
        lines.append(line)
    dst.mkdir(exist_ok=True)
    (dst / "log.carmen").write_text("\n".join(lines) + "\n")
    return dst / "log.carmen"


def _localize(path, run):
    source = open_source(path, LocalizerConfig.from_yaml("office-laser"))
    done = run_log(source, run.map, initial_pose=run.scan_truth[0], progress=False)
    return done.result


@pytest.mark.parametrize(("name", "stamp", "clock"), [
    ("zeros", lambda t: "0", StampClock.ORDER),
    ("unix-g", lambda t: f"{t + 1.7e9:g}", StampClock.ORDER),  # %g: one or two stamps
    ("negated", lambda t: repr(-t) if t else "0", StampClock.NEGATED),
])
def test_a_log_whose_stamps_cannot_order_it_is_read_and_localized(office_log, tmp_path, caplog,
                                                                   name, stamp, clock):
    src, run = office_log
    path = _restamped(src, tmp_path / name, stamp)
    with caplog.at_level(logging.WARNING, logger="fusion.io.carmen"):
        log = read_carmen(path)
    assert log.conventions.clock is clock
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and str(path) in said[0]  # once, naming the file and the fallback
    assert ("records' order" in said[0]) == (clock is StampClock.ORDER)
    events = list(log)
    times = np.array([e.t for e in events if isinstance(e, Odometry | Scan)])
    assert np.all(np.diff(times) >= 0.0)  # in the records' order, never backwards
    if clock is StampClock.ORDER:  # a record a nominal interval apart, or its drive's time
        odometry = [e.t for e in events if isinstance(e, Odometry)]
        assert np.diff(odometry).min() == pytest.approx(1.0 / NOMINAL_ODOMETRY_RATE)
    # localized as well as the true stamps: ATE against the truth, pose by pose in scan order
    true = _localize(src / "log.carmen", run)
    got = _localize(path, run)
    assert len(got.poses) == len(true.poses) == len(run.scan_t)
    truth = Trajectory(run.scan_t, run.scan_truth)

    def rmse(poses):
        return ATE(max_dt=1e-3).compute(Trajectory(run.scan_t, poses), truth).position["rmse"]

    assert rmse(got.poses) <= 1.5 * rmse(true.poses) + 0.005


def test_stamps_that_order_the_log_are_kept(office_log):
    src, _ = office_log
    assert read_carmen(src / "log.carmen").conventions.clock is StampClock.STAMPS

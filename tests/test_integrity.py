"""The integrity output (fusion.integrity): the probability that a pose is right, and its
scores against the truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion.integrity import (
    LOCALIZED_HEADING_DEG,
    LOCALIZED_POSITION,
    disc_probability,
    integrity_scores,
    is_localized,
    localized_probability,
    spread_probability,
)

sigmas = st.floats(min_value=0.005, max_value=2.0)


@given(s1=sigmas, s2=sigmas, angle=st.floats(min_value=0.0, max_value=math.pi))
def test_the_disc_mass_is_the_gaussians(s1, s2, angle):
    """Against a Monte Carlo draw of 200 000 points (σ of the estimate ≤ 0.0012)."""
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    cov = rot @ np.diag([s1**2, s2**2]) @ rot.T
    draws = np.random.default_rng(0).multivariate_normal([0.0, 0.0], cov, 200_000)
    expected = np.mean(np.hypot(draws[:, 0], draws[:, 1]) <= LOCALIZED_POSITION)
    assert disc_probability(cov, LOCALIZED_POSITION) == pytest.approx(expected, abs=0.005)


def test_isotropic_closed_form():
    """For σ₁ = σ₂ = σ the mass within r is 1 − exp(−r²/2σ²) (the Rayleigh law)."""
    for sigma in (0.05, 0.2, 0.6):
        cov = np.diag([sigma**2] * 2)
        assert disc_probability(cov, 0.3) == pytest.approx(1 - math.exp(-0.09 / (2 * sigma**2)),
                                                           abs=1e-6)


@given(scale=st.floats(min_value=1.01, max_value=10.0))
def test_a_wider_estimate_is_less_likely_right(scale):
    cov = np.diag([0.1**2, 0.05**2, math.radians(2.0) ** 2])
    assert spread_probability(scale * cov) < spread_probability(cov)


def test_the_probability_is_the_mode_times_the_spread():
    cov = np.diag([0.02**2, 0.02**2, math.radians(0.5) ** 2])
    assert localized_probability(cov, 1.0) == pytest.approx(1.0, abs=1e-9)
    assert localized_probability(cov, 0.3) == pytest.approx(0.3, abs=1e-9)
    assert localized_probability(cov, 0.0) == 0.0
    # a corridor: 2 m along it, the rest sharp — the heading alone would be sure
    corridor = np.diag([2.0**2, 0.02**2, math.radians(0.5) ** 2])
    assert localized_probability(corridor, 1.0) == pytest.approx(
        math.erf(LOCALIZED_POSITION / (math.sqrt(2) * 2.0)), abs=1e-3)
    heading_only = np.diag([0.01**2, 0.01**2, math.radians(LOCALIZED_HEADING_DEG) ** 2])
    assert localized_probability(heading_only, 1.0) == pytest.approx(math.erf(1 / math.sqrt(2)),
                                                                       abs=1e-3)
    assert localized_probability(np.full((3, 3), np.nan), 1.0) == 0.0


def test_scores_against_known_outcomes():
    p = np.array([0.99, 0.99, 0.2, 0.0, 0.7, 0.96])
    right = np.array([True, False, False, False, True, True])
    s = integrity_scores(p, right)
    assert s["localized_fraction"] == pytest.approx(3 / 6)  # 0.7 is no 0.95
    assert s["confident_wrong"] == pytest.approx(1 / 6)
    assert s["brier"] == pytest.approx(np.mean((p - right) ** 2))
    bins = {(b["from"], b["to"]): b for b in s["reliability"]}
    assert bins[(0.9, 0.99)]["scans"] == 1 and bins[(0.99, 1.0)]["scans"] == 2
    assert bins[(0.99, 1.0)]["right"] == 0.5
    assert "brier" not in integrity_scores(p)  # no truth: only what was reported


def test_a_run_reports_it_per_scan_and_scores_it(tmp_path):
    """The simulated office from its true start: every pose right and reported so."""
    from fusion.config import LocalizerConfig
    from fusion.run_log import run_log
    from fusion.sim import scenario_preset, simulate

    run = simulate(scenario_preset("office-laser", seed=2, duration=30.0))
    from fusion.evaluation import Trajectory

    truth = Trajectory(run.scan_t, run.scan_truth)
    done = run_log(run.events(), run.map, LocalizerConfig.from_yaml("office-laser"),
                   initial_pose=run.scan_truth[0], reference=truth, out=tmp_path)
    p = done.result.localized_probability
    assert len(p) == len(done.result.t) == len(run.scan_t)
    assert np.all((p >= 0) & (p <= 1))
    from fusion.io.localized import read_localized

    t, p_side, status = read_localized(tmp_path / "localized.csv")
    np.testing.assert_allclose(t, done.result.t, atol=1e-6)
    np.testing.assert_allclose(p_side, p, atol=1e-6)
    assert status == list(done.result.statuses)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    integrity = metrics["integrity"]
    assert integrity["confident_wrong"] == 0.0
    assert integrity["localized_fraction"] > 0.99
    assert integrity["brier"] < 0.01
    assert sum(b["scans"] for b in integrity["reliability"]) == len(p)


def test_while_lost_it_says_so():
    """A global start: no pose is reported localized before the manager takes one."""
    from fusion.config import LocalizerConfig
    from fusion.run_log import run_log
    from fusion.sim import scenario_preset, simulate

    run = simulate(scenario_preset("office-laser", seed=2, duration=10.0))
    done = run_log(run.events(), run.map, LocalizerConfig.from_yaml("office-laser"))
    statuses = np.array(done.result.statuses)
    p = done.result.localized_probability
    searching = np.isin(statuses, ["lost", "collecting", "relocalizing"])
    assert searching.any()
    assert np.all(p[searching & (statuses == "lost")] == 0.0)


def test_a_scan_reports_the_evidence_it_gave():
    """The probability reported with a scan holds what that scan said against tracking: on the
    scan that gives tracking up after a kidnap it is already the lost robot's, not the tracked
    one's a scan before (a navigation stack acts on the scan's own estimate)."""
    from fusion.ambiguity.manager import State
    from fusion.config import LocalizerConfig
    from fusion.events import Odometry, Scan
    from fusion.localizer import Localizer
    from tests.test_ambiguity import OFFICE, kidnap_run

    run, t_kidnap = kidnap_run(seed=3)
    loc = Localizer(run.map, LocalizerConfig.from_yaml(OFFICE), run.odom_truth[0])
    given_up = None
    for ev in run.events():
        if isinstance(ev, Odometry):
            loc.on_odometry(ev.t, ev.x, ev.y, ev.theta)
        elif isinstance(ev, Scan):
            was = loc.manager.state
            est = loc.on_scan(ev.t, ev.ranges, ev.angles)
            assert est.mode == loc.manager.mode_probability, ev.t
            if was is State.TRACKING and loc.manager.state is not State.TRACKING:
                given_up = (ev.t, est.localized_probability)
    assert given_up is not None and given_up[0] >= t_kidnap
    assert not is_localized(given_up[1])

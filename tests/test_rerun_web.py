"""The recording in the Rerun web viewer, in a real browser (headless Chromium with software
WebGL): the view a user gets is drawn, the walls in their grey and the matched ones highlighted."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from benchmarks.rerun_web import VIEWPORT, chromium, screenshot
from fusion import Localizer, LocalizerConfig
from fusion.replay import replay
from fusion.rerun_logger import RerunLogger
from fusion.rerun_view import WALL_COLOUR
from fusion.resources import find_config
from fusion.sim import scenario_preset, simulate

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(chromium() is None, reason="Debian's chromium is not installed (make "
                       "test installs it when apt-get can)"),
    pytest.mark.skipif(importlib.util.find_spec("playwright") is None,
                       reason="playwright (the dev extra) is not installed"),
]


def pixels_near(image: np.ndarray, colour: tuple[int, ...], tolerance: int = 14) -> int:
    rgb = (image[..., :3] * 255.0).round()
    return int((np.abs(rgb - np.array(colour[:3])).max(axis=-1) <= tolerance).sum())


def test_the_web_viewer_draws_the_walls_and_the_matched_ones(tmp_path: Path) -> None:
    run = simulate(scenario_preset("office-laser", seed=1, duration=20.0))
    logger = RerunLogger(tmp_path / "run.rrd")
    localizer = Localizer(run.map, LocalizerConfig.from_yaml(find_config("office-laser")),
                          run.odom_truth[0], logger)
    replay(run.events(), localizer, progress=False)
    logger.close()
    image = matplotlib.image.imread(screenshot(tmp_path / "run.rrd", tmp_path / "view.png", 45.0))
    assert image.shape[:2] == (VIEWPORT["height"], VIEWPORT["width"])
    assert pixels_near(image, WALL_COLOUR) > 500, "no walls drawn: the viewer did not load"
    world = image[60:780, :880, :3]  # the world view, left of the Hough view
    rgb = world * 255.0
    saturated = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 120  # the matched walls' palette
    assert saturated.sum() > 1000, "no matched wall highlighted"

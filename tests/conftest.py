"""Shared fixtures: the repository's maps and the real-data folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from houghloc import SegmentMap

# CI replays a fixed set of examples (a red build must mean a regression, not a new draw);
# runs elsewhere explore new ones. No deadline on an example: the suites run one process per
# core, and a wall-clock limit would fail a test for the machine's load, not for its result.
settings.register_profile("ci", derandomize=True, deadline=None)
settings.register_profile("explore", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "explore")

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "fusion" / "configs" / "maps"
DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def robocup() -> SegmentMap:
    return SegmentMap.from_yaml(MAPS / "robocup.yaml")


@pytest.fixture(scope="session")
def office() -> SegmentMap:
    return SegmentMap.from_yaml(MAPS / "office.yaml")


def require_data(*parts: str) -> Path:
    """The path of a real log, or skip the test saying what is missing."""
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real-data file {path} is not present (expected beside the repository)")
    return path

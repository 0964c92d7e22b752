"""Shared fixtures: the repository's maps and the real-data folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from houghloc import SegmentMap

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "configs" / "maps"
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

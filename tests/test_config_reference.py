"""The parameter reference and `houghloc config`: generated from the models, never stale."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from fusion.cli import main
from fusion.config import LocalizerConfig
from fusion.config_reference import commented_yaml, reference_markdown, settings

REFERENCE = Path(__file__).resolve().parents[1] / "docs" / "parameters.md"


def test_the_reference_in_docs_is_the_generated_one() -> None:
    assert REFERENCE.read_text() == reference_markdown(), (
        "docs/parameters.md is stale: houghloc config --reference > docs/parameters.md")


def test_every_setting_says_what_it_means() -> None:
    found = settings()
    assert len(found) > 150
    assert [s.key for s in found if not s.description.strip()] == []
    assert len({s.key for s in found}) == len(found)
    keys = {s.key for s in found}
    assert {"sensors.laser.mount", "filter.motion.alpha1", "initial_pose"} <= keys


def test_the_commented_yaml_reads_back_to_the_same_configuration() -> None:
    for config in (LocalizerConfig(), LocalizerConfig.from_yaml("robocup-camera"),
                   LocalizerConfig.from_dict({"initial_pose": [1.0, 2.0, 0.5]})):
        assert LocalizerConfig.from_dict(yaml.safe_load(commented_yaml(config))) == config


def test_config_command_prints_defaults_or_a_files_effect(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    assert main(["config", "--defaults"]) == 0
    assert LocalizerConfig.from_dict(yaml.safe_load(capsys.readouterr().out)) == \
        LocalizerConfig()
    mine = tmp_path / "mine.yaml"
    mine.write_text("filter: {motion: {alpha1: 0.3}}\n")
    assert main(["config", "--show", str(mine)]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown["filter"]["motion"]["alpha1"] == 0.3
    defaults = LocalizerConfig().sensors["laser"].hough
    assert shown["sensors"]["laser"]["hough"] == defaults.model_dump(mode="json")
    mine.write_text("filter: {motion: {alpha1: -1}}\n")
    assert main(["config", "--show", str(mine)]) == 2
    assert "alpha1" in capsys.readouterr().err

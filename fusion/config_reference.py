"""Every localizer setting with its default and its meaning, read off the pydantic models: the
parameter reference (``docs/parameters.md``) and the commented YAML of ``houghloc config``.

Nothing here is written by hand: a setting added to a model appears in both, with the
description its ``Field`` gives (a test fails when the reference in ``docs/`` is stale, or a
setting has no description).
"""

from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from fusion.config import LocalizerConfig

COMMENT_WIDTH = 96
INTRODUCTION = (
    "Every setting of the localizer, its default and its meaning, generated from the pydantic "
    "models (`houghloc config --reference`; `houghloc config --defaults` prints the same as a "
    "commented YAML file, and `houghloc config --show FILE` what a run with that file uses). A "
    "configuration file overrides any subset, by the same nesting "
    "(`filter: {motion: {alpha1: 0.1}}`). Angles named `*_deg` are degrees; everything else "
    "is SI.")


@dataclass(frozen=True)
class Setting:
    key: str  # dotted, e.g. sensors.laser.hough.rho_step
    default: Any  # as YAML/JSON would read it
    description: str


def settings(model: BaseModel | None = None, prefix: str = "") -> list[Setting]:
    """Every leaf setting of ``model`` (default: the default LocalizerConfig), in order."""
    model = model if model is not None else LocalizerConfig()
    found = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        key = f"{prefix}{name}"
        if isinstance(value, BaseModel):
            found += settings(value, f"{key}.")
        elif _models(value):
            for sub, item in value.items():
                found += settings(item, f"{key}.{sub}.")
        else:
            found.append(Setting(key, _plain(value), field.description or ""))
    return found


def commented_yaml(model: BaseModel | None = None, indent: str = "") -> str:
    """``model`` (default: the defaults) as YAML, each setting under its meaning as a comment:
    a file ``LocalizerConfig.from_yaml`` reads back to the same configuration."""
    model = model if model is not None else LocalizerConfig()
    lines = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        if isinstance(value, BaseModel):
            lines += [f"{indent}{name}:", commented_yaml(value, indent + "  ")]
        elif _models(value):
            lines.append(f"{indent}{name}:")
            for sub, item in value.items():
                lines += [f"{indent}  {sub}:", commented_yaml(item, indent + "    ")]
        else:
            if field.description:
                lines += textwrap.wrap(field.description, COMMENT_WIDTH - len(indent),
                                       initial_indent=f"{indent}# ",
                                       subsequent_indent=f"{indent}# ")
            lines.append(f"{indent}{name}: {json.dumps(_plain(value), ensure_ascii=False)}")
    return "\n".join(lines)


def reference_markdown() -> str:
    """The parameter reference: a table per section of the configuration."""
    out = ["# Parameters", "", *textwrap.wrap(INTRODUCTION, COMMENT_WIDTH), ""]
    section = None
    for s in settings():
        top = s.key.split(".")[0]
        if top != section:
            section = top
            out += ["", f"## `{top}`", "", "| key | default | meaning |", "|---|---|---|"]
        default = json.dumps(s.default, ensure_ascii=False)
        meaning = s.description.replace("|", "\\|")
        out.append(f"| `{s.key}` | `{default}` | {meaning} |")
    return "\n".join(out) + "\n"


def _models(value: Any) -> bool:
    return (isinstance(value, dict) and bool(value)
            and all(isinstance(v, BaseModel) for v in value.values()))


def _plain(value: Any) -> Any:
    """Tuples as lists, as YAML and JSON write them."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value

"""Reading the project's YAML files with errors that name the file and the problem."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

Model = TypeVar("Model", bound=BaseModel)


def read_yaml(path: str | Path, error: type[Exception], what: str) -> object:
    """The parsed content of the YAML file ``path`` (None for an empty file).

    A missing file, an unreadable one or one that is not YAML raises ``error`` with a message
    ``"{what} {path}: …"`` that says which.
    """
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{what} {path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} {path}: cannot read ({exc})") from None
    except yaml.YAMLError as exc:
        raise error(f"{what} {path}: not valid YAML ({exc})") from None


def validated(model: type[Model], raw: object, error: type[Exception], what: str,
              source: str) -> Model:
    """``raw`` (a mapping read from ``source``) validated as ``model``; anything else raises
    ``error`` with ``"{what} {source}: field.path: problem"`` for the first problem."""
    if not isinstance(raw, dict):
        raise error(f"{what} {source}: expected a mapping, got {type(raw).__name__}")
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(part) for part in err["loc"]) or "entry"
        raise error(f"{what} {source}: {where}: {err['msg']}") from None

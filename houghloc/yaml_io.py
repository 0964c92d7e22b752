"""Reading the project's YAML files with errors that name the file and the problem."""

from __future__ import annotations

from pathlib import Path

import yaml


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

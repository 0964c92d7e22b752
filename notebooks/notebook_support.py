"""Plumbing shared by the notebooks — where the repository and the real logs are, saving figures
for the README, showing a Rerun recording inline. The method itself is only ever imported from
``houghloc`` and ``fusion``; nothing here computes anything about localization.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from fusion.resources import configs_dir


def find_repo_root(start: str | Path | None = None) -> Path:
    """The checkout that holds ``pyproject.toml`` and ``houghloc/``, from here or above.

    Notebooks run with the current directory set to ``notebooks/`` (Jupyter, nbclient), but a
    user may start them from the repository root too.
    """
    here = Path(start or Path.cwd()).resolve()
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file() and (folder / "houghloc").is_dir():
            return folder
    raise FileNotFoundError(f"no houghloc checkout at or above {here}")


try:
    REPO_ROOT: Path | None = find_repo_root()
except FileNotFoundError:  # a notebook copied elsewhere, with houghloc installed as a package
    REPO_ROOT = None
CONFIGS = configs_dir()  # the packaged configurations, wherever houghloc is installed
FIGURES_DIR = None if REPO_ROOT is None else REPO_ROOT / "docs" / "images"
SAVE_FIGURES = os.environ.get("SAVE_FIGURES", "") == "1"
"""``SAVE_FIGURES=1`` in the environment writes the README pictures to ``docs/images/``."""


def data_dir() -> Path | None:
    """The folder of real logs (intel/, fr079/, aces/), or None when it is not there.

    ``$HOUGHLOC_DATA`` when it is set; otherwise ``./data``, ``<repo>/data`` and
    ``<repo>/../shared/data``.
    """
    if os.environ.get("HOUGHLOC_DATA"):  # named: only there
        named = Path(os.environ["HOUGHLOC_DATA"])
        return named if named.is_dir() and any(named.iterdir()) else None
    candidates: list[Path] = [Path.cwd() / "data"]
    if REPO_ROOT is not None:
        candidates += [REPO_ROOT / "data", REPO_ROOT.parent / "shared" / "data"]
    for candidate in candidates:
        if candidate.is_dir() and any(candidate.iterdir()):
            return candidate
    return None


def save_figure(fig: Any, name: str) -> Path | None:
    """Write ``docs/images/<name>.png`` when ``SAVE_FIGURES=1``; otherwise do nothing."""
    if not SAVE_FIGURES or FIGURES_DIR is None or REPO_ROOT is None:
        return None
    FIGURES_DIR.mkdir(parents=True, exist_ok=True)
    path = FIGURES_DIR / f"{name}.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"saved {path.relative_to(REPO_ROOT)}")
    return path


def show_recording(logger: Any, width: int | None = None, height: int = 640) -> None:
    """Embed the Rerun viewer with everything a ``RerunLogger(path=None)`` recorded.

    The logger keeps its data in memory; ``notebook_show`` hands it to the viewer widget (and
    streams anything logged afterwards). Without a browser (a headless run) the widget is created
    but nobody draws it — that is fine. Where the widget cannot be created, it says so.
    """
    logger.flush()
    try:
        logger.stream.notebook_show(width=width, height=height)
    except Exception as exc:  # no rerun-notebook, or no widget support in this front end
        print(f"Rerun viewer not shown here ({exc}); save the recording with "
              "RerunLogger(path='run.rrd') and open it with `.venv/bin/rerun run.rrd`.")

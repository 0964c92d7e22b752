"""Plumbing shared by the notebooks — where the repository and the real logs are, saving figures
for the README, showing a Rerun recording inline. The method itself is only ever imported from
``houghloc`` and ``fusion``; nothing here computes anything about localization.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any


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


REPO_ROOT = find_repo_root()
CONFIGS = REPO_ROOT / "fusion" / "configs"
FIGURES_DIR = REPO_ROOT / "docs" / "images"
SAVE_FIGURES = os.environ.get("SAVE_FIGURES", "") == "1"
"""``SAVE_FIGURES=1`` in the environment writes the README pictures to ``docs/images/``."""


def data_dir() -> Path | None:
    """The folder of real logs (intel/, fr079/, aces/), or None when it is not there.

    Looked for in ``$HOUGHLOC_DATA``, ``<repo>/data`` and ``<repo>/../shared/data``.
    """
    candidates = [os.environ.get("HOUGHLOC_DATA"), REPO_ROOT / "data",
                  REPO_ROOT.parent / "shared" / "data"]
    for candidate in candidates:
        if candidate and Path(candidate).is_dir() and any(Path(candidate).iterdir()):
            return Path(candidate)
    return None


def save_figure(fig: Any, name: str) -> Path | None:
    """Write ``docs/images/<name>.png`` when ``SAVE_FIGURES=1``; otherwise do nothing."""
    if not SAVE_FIGURES:
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

"""The configurations and maps that ship inside the package, found by name wherever it is
installed (``importlib.resources``, not the source tree's layout).

``fusion/configs/NAME.yaml`` are localizer configurations (the simulated scenarios' and the
sensor descriptions of the real logs); ``fusion/configs/maps/NAME.yaml`` are segment maps. A
command-line ``--config``/``--map`` or an API call that names a file that does not exist, but
is the name of a packaged one (``office-laser``, ``robocup.yaml``), gets the packaged one.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def configs_dir() -> Path:
    """The packaged localizer configurations (a real directory: the package is installed
    unzipped, as pip does)."""
    return Path(str(files("fusion") / "configs"))


def maps_dir() -> Path:
    """The packaged segment maps."""
    return configs_dir() / "maps"


def packaged_names(directory: Path) -> list[str]:
    """The names (without ``.yaml``) of the files in one of the two directories above."""
    return sorted(p.stem for p in directory.glob("*.yaml"))


def find(path: str | Path, directory: Path) -> Path:
    """``path`` itself when it exists or names a folder, else the packaged file of that name
    (with or without ``.yaml``) in ``directory`` when there is one, else ``path`` unchanged (the
    reader then says it is not found)."""
    given = Path(path)
    if given.exists() or given.parent != Path("."):
        return given
    for candidate in (directory / given.name, directory / f"{given.name}.yaml"):
        if candidate.is_file():
            return candidate
    return given


def find_config(path: str | Path) -> Path:
    return find(path, configs_dir())


def find_map(path: str | Path) -> Path:
    return find(path, maps_dir())

"""Build nav2's AMCL for the benchmark: ``python -m fusion.bench.nav2_amcl``.

The sources are nav2_amcl's own, as the ``amcl`` package's source distribution carries them
(pinned by version and hash, fetched from the package index with pip); the binding is
``binding.cpp`` beside this file. The result is one shared library in this environment
(:data:`fusion.bench.nav2_amcl.LIBRARY`).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from fusion.bench.nav2_amcl import LIBRARY

SOURCE_DISTRIBUTION = "amcl==0.1.2"
SOURCE_SHA256 = "578cc16e3e0e921b44337c4a12c2ba50be262b2830471d4ba23d4eb9a150c7ff"
NAV2_SOURCES = [
    "src/map/map.c", "src/map/map_cspace.cpp", "src/map/map_range.c",
    "src/motion_model/differential_motion_model.cpp", "src/motion_model/omni_motion_model.cpp",
    "src/pf/eig3.c", "src/pf/pf.c", "src/pf/pf_kdtree.c", "src/pf/pf_pdf.c",
    "src/pf/pf_vector.c", "src/sensors/laser/beam_model.cpp", "src/sensors/laser/laser.cpp",
    "src/sensors/laser/likelihood_field_model.cpp",
    "src/sensors/laser/likelihood_field_model_prob.cpp",
]
"""nav2_amcl's filter, map and models; not the package's own wrapper (amcl.cpp)."""
ZERO_UNINITIALIZED = "-ftrivial-auto-var-init=zero"
"""nav2's map_cspace queues the obstacle cells with a priority it never sets (``CellData
cell;``): whatever the stack held, so the likelihood field, and every run after it, depended on
what the process ran before. Zero is the obstacles' own distance, the value meant; GCC ≥ 12 and
Clang ≥ 8 take this flag, which changes no source."""


def build(quiet: bool = True) -> Path:
    for tool in ("cc", "c++"):
        if shutil.which(tool) is None:
            raise SystemExit(f"houghloc: error: building nav2's AMCL needs {tool}")
    binding = Path(__file__).with_name("binding.cpp")
    with tempfile.TemporaryDirectory(prefix="nav2_amcl-") as tmp:
        work = Path(tmp)
        _run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary",
              ":all:", "--dest", str(work), SOURCE_DISTRIBUTION], quiet)
        archive = next(work.glob("amcl-*.tar.gz"))
        _check_hash(archive)
        with tarfile.open(archive) as tar:
            tar.extractall(work, filter="data")
        root = next(p for p in work.iterdir() if p.is_dir())
        objects = []
        for i, name in enumerate([*NAV2_SOURCES, str(binding)]):
            source = Path(name) if Path(name).is_absolute() else root / name
            obj = work / f"{i}.o"
            compiler = ["cc", "-std=gnu11"] if source.suffix == ".c" else ["c++", "-std=c++17"]
            _run([*compiler, "-O2", "-fPIC", ZERO_UNINITIALIZED, "-DHAVE_DRAND48", "-I",
                  str(root / "include"),
                  "-c", str(source), "-o", str(obj)], quiet)
            objects.append(str(obj))
        LIBRARY.parent.mkdir(parents=True, exist_ok=True)
        _run(["c++", "-shared", "-o", str(LIBRARY), *objects], quiet)
    return LIBRARY


def _check_hash(archive: Path) -> None:
    import hashlib

    digest = hashlib.sha256(archive.read_bytes()).hexdigest()
    if digest != SOURCE_SHA256:
        raise SystemExit(f"houghloc: error: {archive.name} has sha256 {digest}, "
                         f"expected {SOURCE_SHA256}")


def _run(command: list[str], quiet: bool) -> None:
    result = subprocess.run(command, capture_output=quiet, text=True, check=False)
    if result.returncode != 0:
        tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-15:])
        raise SystemExit(f"houghloc: error: {' '.join(command[:4])} … failed "
                         f"(exit {result.returncode})\n{tail}")


def main() -> int:
    path = build()
    print(f"nav2's AMCL built: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The house: the modules of ``houghloc`` and ``fusion`` import one another without a cycle,
the core imports nothing of the framework, and the settings import nothing but settings.

Every import counts, wherever it is written: at the top of a module, inside a function or under
``TYPE_CHECKING``. A deferred import hides a dependency from Python's import order, not from the
reader who has to understand one module before the other. The graph is built from the sources
with :mod:`ast` only, so a module that fails to import is still drawn.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("houghloc", "fusion")
SETTINGS = ("fusion.settings", "houghloc.config")
"""The settings modules: pydantic groups that configure the code, imported by it, never the
other way round. ``fusion.config`` composes them and reads YAML, so it may also import the two
modules that find and read files."""
CONFIG_READERS = ("fusion.resources", "houghloc.yaml_io")


def _modules() -> dict[str, Path]:
    """Every module of the packages by dotted name (a package by its ``__init__``)."""
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


MODULES = _modules()


def _owner(name: str) -> str | None:
    """The project module that ``name`` (a module, or a name in one) is defined in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported(module: str, path: Path) -> set[str]:
    """The project modules ``module`` imports, by any import statement anywhere in it."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: Iterable[str] = ()
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, ``level - 1`` steps up
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            names = [f"{base}.{alias.name}" for alias in node.names]
        for name in names:
            owner = _owner(name)
            if owner is not None and owner != module:
                found.add(owner)
    return found


GRAPH = {module: _imported(module, path) for module, path in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    return components


def test_the_graph_sees_every_kind_of_import(tmp_path):
    """The graph is only as good as its parser: an import inside a function, one under
    ``TYPE_CHECKING``, a relative one and a name imported from a package are all edges, to the
    module that defines what is imported."""
    source = tmp_path / "probe.py"
    source.write_text(
        "from typing import TYPE_CHECKING\n"
        "from . import status\n"
        "from .io import tum\n"
        "from houghloc import segment_map\n"
        "if TYPE_CHECKING:\n"
        "    from fusion.tracker import PoseTracker\n"
        "def f():\n"
        "    import fusion.ekf\n"
        "    from fusion.settings.motion import OdometryMotionConfig\n")
    assert _imported("fusion.probe", source) == {
        "fusion.status", "fusion.io.tum", "houghloc.segment_map", "fusion.tracker",
        "fusion.ekf", "fusion.settings.motion"}
    assert "fusion.localizer" in GRAPH["fusion"]  # the package's names, under TYPE_CHECKING
    assert len(MODULES) > 100


def test_cycles_are_found():
    """The cycle finder on a graph with two cycles and a tail."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a", "e"}, "e": {"d"}, "f": {"d"}}
    assert sorted(_cycles(graph)) == [["a", "b", "c"], ["d", "e"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    """Each module can be understood after the ones it imports: none imports itself round
    about."""
    assert _cycles(GRAPH) == []


def test_the_core_imports_nothing_of_the_framework():
    """``houghloc`` is the method, usable alone; ``fusion`` builds on it."""
    upward = {m: sorted(t for t in GRAPH[m] if t.startswith("fusion"))
              for m in GRAPH if m.startswith("houghloc")}
    assert {m: t for m, t in upward.items() if t} == {}


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith(SETTINGS)))
def test_settings_import_only_settings(module):
    """A settings group imports other groups, never the code it configures."""
    assert {t for t in GRAPH[module] if not t.startswith(SETTINGS)} == set()


def test_the_localizer_config_imports_only_settings_and_their_readers():
    assert {t for t in GRAPH["fusion.config"]
            if not t.startswith(SETTINGS + CONFIG_READERS)} == set()


def test_reading_a_config_loads_no_filter_or_manager():
    """``import fusion.config`` and a config read and checked load the settings and the core
    method, none of the framework's code (a fresh interpreter, so that nothing this test
    process imported counts)."""
    probe = ("import sys, fusion.config as c; c.LocalizerConfig.from_yaml('office-laser'); "
             "print('\\n'.join(m for m in sys.modules if m.startswith('fusion')))")
    loaded = set(subprocess.run([sys.executable, "-c", probe], check=True, capture_output=True,
                                text=True, cwd=ROOT).stdout.split())
    assert {"fusion.config", "fusion.settings.ambiguity"} <= loaded
    assert loaded <= {m for m in MODULES if m.startswith(SETTINGS + CONFIG_READERS)} | {
        "fusion", "fusion.config"}


TOOLING = ("fusion.sim", "fusion.bench", "fusion.experiment")
"""What builds and measures runs (the simulator, the benchmark, the experiments' helpers),
not what localizes a robot."""
APPLICATION = ("fusion.cli", "fusion.cli_parser", "fusion.__main__")
"""The ``houghloc`` command: its subcommands run both the runtime and the tooling."""


def test_the_runtime_imports_no_tooling():
    """The filter, the manager, the readers, the recording and the ROS 2 node import nothing of
    the simulator, the benchmark or the experiments: a robot runs without them."""
    runtime = [m for m in MODULES if not m.startswith(TOOLING + APPLICATION)]
    assert len(runtime) > 80
    assert {m: sorted(t for t in GRAPH[m] if t.startswith(TOOLING))
            for m in runtime if any(t.startswith(TOOLING) for t in GRAPH[m])} == {}

"""Every notebook in ``notebooks/`` runs headless from top to bottom and draws something.

Each notebook is executed with nbclient in a fresh kernel started from this interpreter (the
venv's: the ``python3`` kernel spec's ``python`` is resolved by jupyter_client to
``sys.executable``), with the working directory ``notebooks/`` as Jupyter would use. Outputs are
not written back: the notebooks are stored without outputs and executed here.

The notebooks' parameter cells are sized so each runs in well under a minute on two cores.
"""

from __future__ import annotations

import os
import re
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOKS_DIR.glob("*.ipynb"))
CELL_TIMEOUT = 180  # s; a cell that hangs fails its notebook instead of the whole suite
NEEDS_REAL_DATA = {"05_real_log_end_to_end.ipynb"}


def _real_data_available() -> bool:
    sys.path.insert(0, str(NOTEBOOKS_DIR))
    try:
        from notebook_support import data_dir
    finally:
        sys.path.remove(str(NOTEBOOKS_DIR))
    return data_dir() is not None


def _execute(path: Path, **env: str) -> nbformat.NotebookNode:
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=CELL_TIMEOUT, kernel_name="python3", allow_errors=False,
        resources={"metadata": {"path": str(NOTEBOOKS_DIR)}})
    client.execute(env={**os.environ, "MPLBACKEND": "module://matplotlib_inline.backend_inline",
                        "SAVE_FIGURES": "", "TQDM_MININTERVAL": "5", **env})
    return notebook


def test_there_are_notebooks() -> None:
    assert len(NOTEBOOKS) >= 5, f"expected the five notebooks in {NOTEBOOKS_DIR}"


def test_notebooks_are_stored_without_outputs() -> None:
    for path in NOTEBOOKS:
        notebook = nbformat.read(path, as_version=4)
        for cell in notebook.cells:
            if cell.cell_type == "code":
                assert not cell.outputs and cell.execution_count is None, (
                    f"{path.name}: clear the outputs before committing")


# the real-log notebook replays a whole log: a slow test, as every whole-log run
@pytest.mark.parametrize("path", [
    pytest.param(p, marks=pytest.mark.slow) if p.name in NEEDS_REAL_DATA else p
    for p in NOTEBOOKS], ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_and_plots(path: Path) -> None:
    started = time.perf_counter()
    try:
        notebook = _execute(path)
    except nbclient.exceptions.CellExecutionError as exc:
        pytest.fail(f"{path.name} failed:\n{exc}")
    elapsed = time.perf_counter() - started

    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    errors = [o for o in outputs if o.output_type == "error"]
    assert not errors, f"{path.name}: {errors[0].ename}: {errors[0].evalue}"
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    if path.name in NEEDS_REAL_DATA and not _real_data_available():
        pytest.skip(f"{path.name} ran without the real logs (nothing to plot)")
    assert images, f"{path.name} produced no figure"
    assert elapsed < 120, f"{path.name} took {elapsed:.0f} s; shrink its parameter cell"
    if path.name == "05_real_log_end_to_end.ipynb":  # the defaults track the slice
        text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
        match = re.search(r"against the reference: RMSE ([0-9.]+) cm.*?lost .*? ([0-9]+) %",
                          text)
        assert match, text
        assert float(match[1]) < 8.0 and int(match[2]) == 0, match[0]


def test_the_real_log_notebook_says_when_the_data_is_missing(tmp_path: Path) -> None:
    """Without the logs every cell of notebook 05 says it skipped, and why."""
    notebook = _execute(NOTEBOOKS_DIR / "05_real_log_end_to_end.ipynb",
                        HOUGHLOC_DATA=str(tmp_path))
    code = [c for c in notebook.cells if c.cell_type == "code"][2:]  # after the parameters
    for cell in code:
        text = "".join(o.get("text", "") for o in cell.outputs if o.output_type == "stream")
        assert "skipped: the real logs are not here" in text, cell.source[:80]

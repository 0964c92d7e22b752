"""``houghloc sweep``: every task of a spec on Dask distributed, results as they come.

Each (run, setting, method, protocol) is one Dask task, submitted under its key (a hash of the
task). The client — this process — alone writes ``DIR/results.csv``, one row per finished task,
appended and flushed as each finishes, and the trajectory of each to
``DIR/trajectories/<task_id>.tum``. So:

* a re-run with the same ``DIR`` skips the tasks whose row is there (``retry_errors`` redoes the
  failed ones);
* a worker lost mid-sweep loses nothing: the scheduler gives its tasks to another worker
  (Dask's own retry of tasks whose worker died), and a task's row is written once, when its
  result reaches the client;
* a task that fails is a row with its error; the others go on.

The cluster is a ``LocalCluster`` of one single-threaded worker process per core (``workers``
to choose), or an existing scheduler (``dask scheduler`` / ``dask worker``) by address.
"""

from __future__ import annotations

import csv
import io
import logging
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from fusion.bench.methods import supports
from fusion.bench.spec import Protocol, SweepSpec
from fusion.bench.task import COLUMNS, Task, TaskResult, run_task

RESULTS = "results.csv"


def expand(spec: SweepSpec) -> list[Task]:
    """The spec's tasks: every run × protocol × method, and houghloc once per setting of the
    grid (the peers do not read houghloc's settings). Combinations a method or a run cannot do
    (ICP or dead reckoning without a start pose, a held-out map for a run whose map is given)
    are left out."""
    from fusion.bench.spec import Method

    tasks: list[Task] = []
    for run in spec.runs:
        for protocol in spec.protocols:
            if protocol is Protocol.HELD_OUT_MAP and run.build_from is None:
                continue
            for method in spec.methods:
                if not supports(method, protocol is Protocol.GLOBAL_START):
                    continue
                grid = spec.settings() if method is Method.HOUGHLOC else [{}]
                tasks.extend(Task(run, method, protocol, settings, spec.max_dt)
                             for settings in grid)
    return tasks


def read_results(out: Path) -> list[dict[str, str]]:
    """The rows already in ``out/results.csv`` (none when there is no file)."""
    path = out / RESULTS
    if not path.exists():
        return []
    with path.open(newline="", encoding="utf-8") as f:
        return [row for row in csv.DictReader(f) if row.get("task_id")]


@dataclass
class SweepOutcome:
    rows: list[dict[str, Any]]
    ran: int
    skipped: int
    failed: int


def run_sweep(spec: SweepSpec, out: Path, *, scheduler: str | None = None,
              workers: int | None = None, progress: bool | None = None,
              retry_errors: bool = False) -> SweepOutcome:
    """Run the spec's tasks not yet in ``out`` and write results.csv, summary.md and the plot."""
    from fusion.bench.report import write_report

    out.mkdir(parents=True, exist_ok=True)
    (out / "trajectories").mkdir(exist_ok=True)
    tasks = expand(spec)
    earlier = [r for r in read_results(out) if not (retry_errors and r["status"] == "error")]
    done = {r["task_id"] for r in earlier}
    todo = [t for t in tasks if t.key not in done]
    if retry_errors:
        _rewrite(out, earlier)
    failed = 0
    if todo:
        failed = _submit(todo, out, scheduler, workers, progress)
    wanted = {t.key for t in tasks}
    rows = [r for r in read_results(out) if r["task_id"] in wanted]
    write_report(rows, out)
    return SweepOutcome(rows, len(todo), len(tasks) - len(todo), failed)


def _submit(todo: list[Task], out: Path, scheduler: str | None, workers: int | None,
            progress: bool | None) -> int:
    from distributed import Client, LocalCluster, as_completed

    for name in ("distributed", "distributed.nanny", "distributed.scheduler",
                 "distributed.worker", "distributed.core"):
        logging.getLogger(name).setLevel(logging.ERROR)
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=":0", silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout=30)
    failed = 0
    try:
        by_key = {f"sweep-{t.key}": t for t in todo}
        futures = [client.submit(run_task, t, key=key, pure=False) for key, t in by_key.items()]
        with tqdm(total=len(todo), unit="task", desc="sweep", disable=_quiet(progress),
                  dynamic_ncols=True) as bar:
            for future in as_completed(futures):
                task = by_key[future.key]
                try:
                    result: TaskResult = future.result()
                except Exception as error:  # e.g. KilledWorker: the task killed its workers
                    result = _error_result(task, f"{type(error).__name__}: {error}")
                _append(out, result)
                failed += result.row["status"] != "ok"
                bar.update()
                bar.set_postfix_str(task.label()[:60])
                future.release()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return failed


def _quiet(progress: bool | None) -> bool | None:
    return None if progress is None else not progress


def _error_result(task: Task, message: str) -> TaskResult:
    return TaskResult(task.blank_row() | {"status": "error", "error": message})


def _append(out: Path, result: TaskResult) -> None:
    """One row appended and flushed to disk; the trajectory beside it."""
    if result.trajectory is not None:
        from fusion.io import write_tum

        write_tum(out / "trajectories" / f"{result.row['task_id']}.tum",
                  result.trajectory.t, result.trajectory.poses)
    path = out / RESULTS
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        if new:
            writer.writeheader()
        writer.writerow({k: _cell(v) for k, v in result.row.items()})
        f.flush()
        os.fsync(f.fileno())


def _rewrite(out: Path, rows: Iterable[dict[str, Any]]) -> None:
    from fusion.io import atomic_write_text

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    atomic_write_text(out / RESULTS, buffer.getvalue())


def _cell(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value

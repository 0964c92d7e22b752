"""The benchmark behind ``houghloc sweep``: runs × settings × methods × protocols on Dask.

* :mod:`fusion.bench.spec` — the spec file (pydantic), its errors;
* :mod:`fusion.bench.data` — a run's events, reference and map source, cut per protocol;
  what "covered" means;
* :mod:`fusion.bench.methods` — houghloc and the peers (dead reckoning, ICP, AMCL), fed alike;
* :mod:`fusion.bench.task` — one task and its row of results;
* :mod:`fusion.bench.sweep` — the Dask driver; :mod:`fusion.bench.report` — summary and plot.
"""

from fusion.bench.spec import Method, Protocol, SpecError, SweepSpec, load_spec
from fusion.bench.sweep import expand, read_results, run_sweep
from fusion.bench.task import COLUMNS, Task, run_task

__all__ = ["COLUMNS", "Method", "Protocol", "SpecError", "SweepSpec", "Task", "expand",
           "load_spec", "read_results", "run_sweep", "run_task"]

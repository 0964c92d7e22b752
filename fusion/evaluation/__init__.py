"""Trajectory evaluation: association, ATE, RPE, "lost" fraction, Kümmerle relation errors, NEES.

In the spirit of ``evo``: each metric is a small class configured once (``ATE(alignment=...)``)
whose ``compute`` returns a result with per-sample errors, a few statistics and ``as_dict()`` for
``metrics.json``. Units: metres for positions; headings are radians in the arrays and degrees in
the reported statistics (the ``_deg`` keys), as in Kümmerle et al. 2009.

Estimated and reference trajectories are paired by timestamp (``associate``): each estimate takes
the nearest reference within ``max_dt`` (default 0.02 s), one to one. The localizer and the
reference are both in the ``map`` frame, so ATE uses no alignment by default; ``Alignment.SE2``
(closed-form 2D Kabsch/Umeyama without scale) is for paths in their own frame, like odometry.

* :mod:`~fusion.evaluation.trajectory` — trajectories, association, alignment;
* :mod:`~fusion.evaluation.metrics` — ATE, RPE, lost, relation errors;
* :mod:`~fusion.evaluation.consistency` — NEES, tables, windowed means.
"""

from fusion.evaluation.consistency import (
    NEESResult,
    chi2_band,
    nees,
    summary_table,
    window_means,
)
from fusion.evaluation.metrics import (
    ATE,
    RPE,
    ATEResult,
    LostFraction,
    LostResult,
    RelationError,
    RelationResult,
    RelativeResult,
    relative_errors,
)
from fusion.evaluation.trajectory import (
    DEFAULT_MAX_DT,
    Alignment,
    Association,
    DeltaUnit,
    Statistic,
    Trajectory,
    align_se2,
    associate,
    statistics,
)

__all__ = ["ATE", "DEFAULT_MAX_DT", "RPE", "ATEResult", "Alignment", "Association", "DeltaUnit",
           "LostFraction", "LostResult", "NEESResult", "RelationError", "RelationResult",
           "RelativeResult", "Statistic", "Trajectory", "align_se2", "associate", "chi2_band",
           "nees", "relative_errors", "statistics", "summary_table", "window_means"]

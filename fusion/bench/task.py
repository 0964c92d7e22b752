"""One benchmark task — a (run, setting, method, protocol) — and its row of ``results.csv``.

:func:`run_task` never raises: a method that fails is a row with ``status: error`` and the
message, so the other tasks of a sweep go on.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.bench.data import Piece, RunData, covered
from fusion.bench.generated import kidnap_times, outside_allowance, recovery_times, simulated
from fusion.bench.methods import Localized, MissingPeer, localize, supports
from fusion.bench.spec import Method, Protocol, RunSpec, apply_settings, settings_label
from fusion.evaluation import (
    ATE,
    ATEResult,
    LostFraction,
    RelationError,
    Trajectory,
    window_means,
)
from fusion.integrity import (
    LOCALIZED_HEADING_DEG,
    LOCALIZED_POSITION,
    integrity_scores,
    reliability_counts,
)

LOST_POSITION = LOCALIZED_POSITION
"""m: a pose farther than this from the reference is lost (as is one off by LOST_HEADING_DEG):
the bound within which the integrity output calls a pose right (fusion.integrity)."""
LOST_HEADING_DEG = LOCALIZED_HEADING_DEG

COLUMNS = ("task_id", "run", "method", "protocol", "settings", "scans", "ate_rmse_m",
           "ate_max_m", "heading_rmse_deg", "lost_frac", "covered_frac", "lost_covered_frac",
           "rel_trans_m", "rel_rot_rad", "global_time_s", "cpu_ms_per_scan", "cpu_ms_worst_10s",
           "localized_frac", "confident_wrong_frac", "brier", "reliability", "recovery_s",
           "lost_outside_kidnap_frac", "ate_outside_kidnap_m", "status", "error")
"""The columns of ``results.csv``, in order."""


@dataclass(frozen=True)
class Task:
    run: RunSpec
    method: Method
    protocol: Protocol
    settings: dict[str, Any] = field(default_factory=dict)
    max_dt: float = 0.006

    @property
    def key(self) -> str:
        """A hash of everything that decides the task's result: a re-run skips it."""
        doc = {"run": self.run.model_dump(mode="json"), "method": self.method.value,
               "protocol": self.protocol.value, "settings": settings_label(self.settings),
               "max_dt": self.max_dt}
        return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]

    def blank_row(self) -> dict[str, Any]:
        """The task's row of results.csv with only what names the task filled in."""
        row: dict[str, Any] = dict.fromkeys(COLUMNS, "")
        row.update(task_id=self.key, run=self.run.name, method=self.method.value,
                   protocol=self.protocol.value, settings=settings_label(self.settings))
        return row

    def label(self) -> str:
        return f"{self.run.name} {self.method.value} {self.protocol.value} " \
               f"{settings_label(self.settings)}"


@dataclass
class TaskResult:
    row: dict[str, Any]
    trajectory: Trajectory | None = None


def run_task(task: Task) -> TaskResult:
    """Localize and score one task; every failure becomes an error row. The readers' and the
    filter's warnings are not printed: a sweep's output is its rows."""
    for name in ("fusion", "houghloc"):
        logging.getLogger(name).setLevel(logging.ERROR)
    row = task.blank_row()
    try:
        trajectory = _run(task, row)
    except MissingPeer as error:
        row.update(status="error", error=str(error))
        return TaskResult(row)
    except Exception as error:  # the row says what went wrong; the sweep goes on
        where = traceback.extract_tb(error.__traceback__)[-1]
        row.update(status="error", error=f"{type(error).__name__}: {error} "
                   f"({where.filename.rsplit('/', 1)[-1]}:{where.lineno})")
        return TaskResult(row)
    row["status"] = "ok"
    return TaskResult(row, trajectory)


def _run(task: Task, row: dict[str, Any]) -> Trajectory:
    config = apply_settings(task.run.config, task.settings)
    run = simulated(task.run) if task.run.scenario is not None else task.run
    data = RunData.load(run, task.max_dt)
    pieces = data.pieces(task.protocol)
    global_start = task.protocol is Protocol.GLOBAL_START
    if not supports(task.method, global_start):
        raise ValueError(f"{task.method.value} cannot start without a pose")
    done = [localize(task.method, piece, config) for piece in pieces]
    for piece, result in zip(pieces, done, strict=True):
        if len(result.trajectory) != len(piece.scans):  # scoring pairs poses with scans
            raise RuntimeError(f"{task.method.value} gave {len(result.trajectory)} poses for "
                               f"{len(piece.scans)} scans")
    trajectory = Trajectory(np.concatenate([d.trajectory.t for d in done]),
                            np.concatenate([d.trajectory.poses for d in done]))
    row.update(score(trajectory, data, pieces, done, task.max_dt, global_start,
                     kidnap_times(task.run) if task.run.scenario is not None else None))
    return trajectory


def reliability_cell(probability: NDArray[np.float64], right: NDArray[np.bool_]) -> str:
    """A run's reliability table as one ``results.csv`` cell: per bin of reported probability,
    the poses, how many were right and the sum of their probabilities
    (:func:`fusion.integrity.reliability_counts`), which runs pool by adding
    (:func:`fusion.bench.report.reliability_markdown`)."""
    return json.dumps([[int(n), int(hits), round(float(total), 4)]
                       for n, hits, total in reliability_counts(probability, right)],
                      separators=(",", ":"))


def score(trajectory: Trajectory, data: RunData, pieces: list[Piece], done: list[Localized],
          max_dt: float, global_start: bool, kidnaps: list[float] | None = None
          ) -> dict[str, Any]:
    """ATE, lost fraction over all poses and over covered ones, relation errors, CPU time,
    for a global start the time until right and staying right; where the method reports how
    sure it is, the share of poses reported localized, confident-wrong and the Brier score
    (:func:`fusion.integrity.integrity_scores`); given the times of ``kidnaps``, the time to
    recover from the slowest, and the lost share and ATE outside their recovery allowance."""
    scans = sum(len(d.trajectory) for d in done)
    ate = ATE(max_dt=max_dt).compute(trajectory, data.reference)
    lost = LostFraction(LOST_POSITION, LOST_HEADING_DEG, max_dt).from_ate(ate).lost
    cover = _covered(ate, data, pieces)
    position = ate.position
    out: dict[str, Any] = {
        "scans": scans,
        "ate_rmse_m": position["rmse"],
        "ate_max_m": position["max"],
        "heading_rmse_deg": ate.heading_deg["rmse"],
        "lost_frac": float(np.mean(lost)) if len(lost) else math.nan,
        "covered_frac": float(np.mean(cover)) if len(cover) else math.nan,
        "lost_covered_frac": float(np.mean(lost[cover])) if cover.any() else math.nan,
        "cpu_ms_per_scan": 1e3 * sum(d.cpu_seconds for d in done) / max(scans, 1),
        "cpu_ms_worst_10s": 1e3 * _worst_window(done),
    }
    est_t = trajectory.t[ate.association.est_index]
    if all(d.probability is not None for d in done):
        probability = np.concatenate([d.probability for d in done])[ate.association.est_index]
        scores = integrity_scores(probability, ~lost)
        out.update(localized_frac=scores["localized_fraction"],
                   confident_wrong_frac=scores["confident_wrong"], brier=scores["brier"],
                   reliability=reliability_cell(probability, ~lost))
    if kidnaps is not None:  # a simulated run: its kidnaps (if any) are known
        if kidnaps:
            out["recovery_s"] = max(recovery_times(est_t, lost, kidnaps))
        keep = outside_allowance(est_t, kidnaps)
        if keep.any():
            out["lost_outside_kidnap_frac"] = float(np.mean(lost[keep]))
            out["ate_outside_kidnap_m"] = float(np.sqrt(np.mean(ate.position_errors[keep]**2)))
    if data.spec.relations is not None:
        out.update(_relations(trajectory, data))
    if global_start:
        out["global_time_s"] = time_to_right(ate, trajectory, lost)
    return out


WORST_WINDOW = 10.0
"""s of log over which the mean CPU time per scan is taken for the worst-window column."""


def _worst_window(done: list[Localized]) -> float:
    """The largest mean CPU time per scan over any WORST_WINDOW seconds of log (each piece on
    its own; NaN when the method does not time its scans)."""
    worst = math.nan
    for d in done:
        if d.scan_cpu is None or len(d.scan_cpu) != len(d.trajectory):
            return math.nan
        if len(d.scan_cpu):
            value = window_means(d.trajectory.t, d.scan_cpu, WORST_WINDOW).max()
            worst = value if math.isnan(worst) else max(worst, value)
    return worst


def _covered(ate: ATEResult, data: RunData, pieces: list[Piece]) -> np.ndarray:
    """Which of the scored poses the map of their piece covers: each estimate's scan, placed at
    the reference pose it was paired with."""
    scans = [scan for piece in pieces for scan in piece.scans]
    piece_of = np.concatenate([np.full(len(p.scans), k) for k, p in enumerate(pieces)])
    est, ref = ate.association.est_index, ate.association.ref_index
    out = np.zeros(len(est), dtype=bool)
    for k, piece in enumerate(pieces):
        mine = np.flatnonzero(piece_of[est] == k)
        out[mine] = covered([scans[i] for i in est[mine]], data.reference.poses[ref[mine]],
                            piece.map_source.points)
    return out


def time_to_right(ate: ATEResult, trajectory: Trajectory, lost: np.ndarray) -> float:
    """Seconds from the first scan until the estimate is right (not lost) and stays right to the
    end; ``inf`` when it is lost at the end."""
    if len(lost) == 0 or lost[-1]:
        return math.inf
    t = trajectory.t[ate.association.est_index]
    order = np.argsort(t)
    t, lost = t[order], lost[order]
    wrong = np.flatnonzero(lost)
    first_right = t[wrong[-1] + 1] if len(wrong) else t[0]
    return float(first_right - trajectory.t.min())


def _relations(trajectory: Trajectory, data: RunData) -> dict[str, float]:
    from fusion.io import Relations, read_relations

    spec = data.spec
    assert spec.relations is not None
    rel = read_relations(spec.relations, spec.time_offset)
    lo, hi = trajectory.t.min() - 0.02, trajectory.t.max() + 0.02
    keep = (rel.t1 >= lo) & (rel.t1 <= hi) & (rel.t2 >= lo) & (rel.t2 <= hi)
    result = RelationError(max_dt=0.02).compute(
        trajectory, Relations(rel.t1[keep], rel.t2[keep], rel.delta[keep])).as_dict()
    return {"rel_trans_m": result.get("translation_mean_m", math.nan),
            "rel_rot_rad": math.radians(result.get("rotation_mean_deg", math.nan))}


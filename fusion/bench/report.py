"""``summary.md`` and ``summary.png`` from the rows of ``results.csv``.

One table per protocol (log × method: ATE RMSE / max, lost % over all poses and over covered
ones, relation error where the run has relations, CPU ms per scan), one for global starts (time
until right and staying right), the failed tasks with their errors, and a plot of lost % and ATE
per run and method.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from fusion.bench.data import COVERED_DISTANCE, COVERED_SHARE
from fusion.bench.spec import Protocol
from fusion.bench.task import LOST_HEADING_DEG, LOST_POSITION
from fusion.integrity import RELIABILITY_BINS

PEER_SANITY_LOST = 0.05
"""The peers' sanity gate: a tuned peer lost on more than this share of a log's scans, from the
known start on the map built from that very run, is more likely run wrong (or fed data it cannot
take) than beaten fairly; its rows for that log are marked suspect."""
GATED_PEERS = {"amcl-tuned": ("amcl", "amcl-tuned", "amcl-beam")}
"""The tuned set the gate judges → the methods of the same peer whose rows it marks."""


def suspect(rows: Sequence[dict[str, Any]]) -> set[tuple[str, str]]:
    """(log, method) of the peers' rows that fail the sanity gate (:data:`PEER_SANITY_LOST`)."""
    marked: set[tuple[str, str]] = set()
    for r in rows:
        if (r.get("status") == "ok" and r["method"] in GATED_PEERS
                and r["protocol"] == Protocol.SAME_RUN.value
                and r.get("settings", "{}") in ("", "{}")
                and not _f(r, "lost_frac") <= PEER_SANITY_LOST):
            marked.update((r["run"], m) for m in GATED_PEERS[r["method"]])
    return marked


def _f(row: dict[str, Any], key: str) -> float:
    try:
        return float(row.get(key, "") or "nan")
    except ValueError:
        return math.nan


def _label(row: dict[str, Any]) -> str:
    settings = row.get("settings", "{}")
    return row["method"] if settings in ("", "{}") else f"{row['method']} {settings}"


def _length(v: float) -> str:
    if not math.isfinite(v):
        return "–"
    return f"{100 * v:.1f} cm" if v < 1 else f"{v:.2f} m"


def _ms(v: float) -> str:
    if not math.isfinite(v):
        return "–"
    return f"{v:.0f} ms" if v >= 10 else f"{v:.1f} ms" if v >= 1 else f"{v:.2f} ms"


def _pct(v: float) -> str:
    return "–" if not math.isfinite(v) else f"{100 * v:.1f} %"


def matrix_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The compact view: per protocol, a row per log and a column per method, each cell
    "ATE RMSE · lost % (over covered poses) · CPU ms per scan"; for global starts, the time
    until right and staying right."""
    ok = [r for r in rows if r.get("status") == "ok"]
    labels = sorted({_label(r) for r in ok}, key=lambda m: (m != "houghloc", m))
    marked = suspect(rows)
    out = io.StringIO()
    for protocol in Protocol:
        these = {(r["run"], _label(r)): r for r in ok if r["protocol"] == protocol.value}
        if not these:
            continue
        methods = [m for m in labels if any(k[1] == m for k in these)]
        runs = sorted({k[0] for k in these})
        out.write(f"\n**{protocol.value}**\n\n| log | " + " | ".join(methods) + " |\n|---|"
                  + "---|" * len(methods) + "\n")
        for run in runs:
            cells = []
            for m in methods:
                r = these.get((run, m))
                if r is None:
                    cells.append("")
                elif protocol is Protocol.GLOBAL_START:
                    t = _f(r, "global_time_s")
                    cells.append("never" if not math.isfinite(t) else f"{t:.0f} s")
                else:
                    lost = _pct(_f(r, "lost_frac"))
                    if protocol is Protocol.HELD_OUT_MAP:
                        lost += f" ({_pct(_f(r, 'lost_covered_frac'))})"
                    cells.append(f"{_length(_f(r, 'ate_rmse_m'))} · {lost} · "
                                 f"{_ms(_f(r, 'cpu_ms_per_scan'))}"
                                 + (" · suspect" if (run, r["method"]) in marked else ""))
            out.write(f"| {run} | " + " | ".join(cells) + " |\n")
    return out.getvalue()


def _worst(row: dict[str, Any]) -> str:
    """The worst 10 s window's CPU per scan, '–' for a method that does not time its scans."""
    value = _f(row, "cpu_ms_worst_10s")
    return f"{value:.2f}" if math.isfinite(value) else "–"


def summary_markdown(rows: Sequence[dict[str, Any]]) -> str:
    ok = [r for r in rows if r.get("status") == "ok"]
    out = io.StringIO()
    out.write("# Benchmark summary\n\n")
    out.write("Each cell: ATE RMSE · lost % (held out: over covered poses in brackets) · CPU "
              "per scan. Worst 10 s: the largest mean CPU per scan over any 10 s of log.\n")
    out.write(matrix_markdown(rows))
    marked = suspect(rows)
    if marked:
        logs = ", ".join(sorted({run for run, _ in marked}))
        out.write(f"\n**Suspect** ({logs}): the tuned peer is lost on more than "
                  f"{PEER_SANITY_LOST:.0%} of the log's scans from the known start on the map "
                  "built from the same run; its rows there say more about how it was run, or "
                  "what the log gives it, than about the peer.\n\n")
    out.write(f"Lost: more than {LOST_POSITION} m or {LOST_HEADING_DEG:g}° from the reference. "
              f"Covered: at least {COVERED_SHARE:.0%} of the scan's points, at the reference "
              f"pose, within {COVERED_DISTANCE * 100:.0f} cm of the points the map was built "
              "from. CPU: process time per scan, map building and log reading excluded.\n")
    for protocol in (Protocol.SAME_RUN, Protocol.HELD_OUT_MAP):
        these = [r for r in ok if r["protocol"] == protocol.value]
        if not these:
            continue
        relations = any(math.isfinite(_f(r, "rel_trans_m")) for r in these)
        out.write(f"\n## {protocol.value}\n\n")
        head = ["log", "method", "scans", "ATE RMSE", "ATE max", "lost", "lost (covered)",
                "covered"]
        head += ["relations (trans, rot)"] if relations else []
        head += ["CPU ms/scan", "worst 10 s"]
        out.write("| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n")
        for r in sorted(these, key=lambda r: (r["run"], _label(r))):
            label = _label(r) + (" (suspect)" if (r["run"], r["method"]) in marked else "")
            cells = [r["run"], label, r["scans"], _length(_f(r, "ate_rmse_m")),
                     _length(_f(r, "ate_max_m")), _pct(_f(r, "lost_frac")),
                     _pct(_f(r, "lost_covered_frac")), _pct(_f(r, "covered_frac"))]
            if relations:
                tr, rot = _f(r, "rel_trans_m"), _f(r, "rel_rot_rad")
                cells.append("–" if not math.isfinite(tr) else
                             f"{_length(tr)}, {rot:.3f} rad")
            cells.append(f"{_f(r, 'cpu_ms_per_scan'):.2f}")
            cells.append(_worst(r))
            out.write("| " + " | ".join(str(c) for c in cells) + " |\n")
    starts = [r for r in ok if r["protocol"] == Protocol.GLOBAL_START.value]
    if starts:
        out.write("\n## global-start (same-run map, no initial pose)\n\n")
        out.write("| log | method | right and staying right after | lost | CPU ms/scan | "
                  "worst 10 s |\n|---|---|---|---|---|---|\n")
        for r in sorted(starts, key=lambda r: (r["run"], _label(r))):
            t = _f(r, "global_time_s")
            when = "never" if not math.isfinite(t) else f"{t:.1f} s"
            out.write(f"| {r['run']} | {_label(r)} | {when} | {_pct(_f(r, 'lost_frac'))} | "
                      f"{_f(r, 'cpu_ms_per_scan'):.2f} | {_worst(r)} |\n")
    out.write(integrity_markdown(ok))
    out.write(reliability_markdown(ok))
    out.write(generated_markdown(ok))
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        out.write("\n## Failed tasks\n\n| log | method | protocol | error |\n|---|---|---|---|\n")
        for r in failed:
            error = str(r.get("error", "")).replace("|", "\\|").replace("\n", " ")
            out.write(f"| {r['run']} | {_label(r)} | {r['protocol']} | {error} |\n")
    return out.getvalue()


def plot(rows: Sequence[dict[str, Any]], path: Path) -> Path | None:
    """Lost % and ATE RMSE per run and method, one row of panels per protocol."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from fusion.io.files import atomic_write_bytes

    ok = [r for r in rows if r.get("status") == "ok"
          and r["protocol"] != Protocol.GLOBAL_START.value]
    protocols = [p.value for p in (Protocol.SAME_RUN, Protocol.HELD_OUT_MAP)
                 if any(r["protocol"] == p.value for r in ok)]
    if not protocols:
        return None
    runs = sorted({r["run"] for r in ok})
    labels = sorted({_label(r) for r in ok})
    fig = Figure(figsize=(max(8.0, 1.6 * len(runs) + 3), 3.6 * len(protocols)))
    FigureCanvasAgg(fig)
    width = 0.8 / len(labels)
    for i, protocol in enumerate(protocols):
        for j, (key, title, scale) in enumerate((("lost_frac", "lost [%]", 100.0),
                                                 ("ate_rmse_m", "ATE RMSE [m]", 1.0))):
            ax = fig.add_subplot(len(protocols), 2, 2 * i + j + 1)
            for k, label in enumerate(labels):
                values = []
                for run in runs:
                    match = [r for r in ok if r["protocol"] == protocol and r["run"] == run
                             and _label(r) == label]
                    values.append(scale * _f(match[0], key) if match else math.nan)
                ax.bar([x + (k - (len(labels) - 1) / 2) * width for x in range(len(runs))],
                       values, width, label=label)
            ax.set_xticks(range(len(runs)), runs, rotation=20)
            ax.set_title(f"{protocol}: {title}")
            if key == "ate_rmse_m":
                ax.set_yscale("log")
            ax.grid(True, axis="y", linewidth=0.3)
            if i == 0 and j == 0:
                handles, names = ax.get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=len(labels), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    return atomic_write_bytes(path, buffer.getvalue())


def integrity_markdown(ok: Sequence[dict[str, Any]]) -> str:
    """Per task of a method that says how sure it is: the share of poses it reported
    localized, the share reported localized while lost (confident-wrong) and the Brier score
    of its probabilities (0 perfect, 0.25 a coin's)."""
    these = [r for r in ok if math.isfinite(_f(r, "brier"))]
    if not these:
        return ""
    out = io.StringIO()
    out.write("\n## Integrity (reported localized, and how well)\n\n"
              "| log | method | protocol | localized | confident-wrong | Brier |\n"
              "|---|---|---|---|---|---|\n")
    for r in sorted(these, key=lambda r: (r["protocol"], r["run"], _label(r))):
        out.write(f"| {r['run']} | {_label(r)} | {r['protocol']} | "
                  f"{_pct(_f(r, 'localized_frac'))} | {_pct(_f(r, 'confident_wrong_frac'))} | "
                  f"{_f(r, 'brier'):.3f} |\n")
    return out.getvalue()


def reliability_markdown(ok: Sequence[dict[str, Any]]) -> str:
    """Per method and protocol, its runs' poses pooled by the probability reported with them
    (:data:`fusion.integrity.RELIABILITY_BINS`): how many, their mean reported probability and
    the share that were right (within the bounds of a lost pose). A calibrated method's share
    right matches its mean probability in every bin."""
    groups: dict[tuple[str, str], np.ndarray] = {}
    for r in ok:
        cell = r.get("reliability") or ""
        if not cell:
            continue
        counts = np.asarray(json.loads(cell), dtype=float).reshape(-1, 3)
        key = (_label(r), r["protocol"])
        groups[key] = groups[key] + counts if key in groups else counts
    if not groups:
        return ""
    names = [f"{a:g}–{b:g}" for a, b in pairwise(RELIABILITY_BINS)]
    out = io.StringIO()
    out.write("\n## Reliability of the reported probability\n\nPoses pooled over the runs by "
              "the probability reported with them; each cell: poses · mean reported · share "
              "right.\n\n| method | protocol | " + " | ".join(names) + " |\n|---|---|"
              + "---|" * len(names) + "\n")
    for (label, protocol), counts in sorted(groups.items()):
        cells = []
        for n, right, total in counts:
            cells.append("–" if n == 0 else
                         f"{int(n):,} · {total / n:.3f} · {right / n:.3f}")
        out.write(f"| {label} | {protocol} | " + " | ".join(cells) + " |\n")
    return out.getvalue()


GOAL_ATE = 0.02
"""m: the generated buildings' goal for the median ATE over seeds."""
GOAL_LOST = 0.01
"""the share of poses lost (outside the kidnap's recovery allowance) a seed may have"""
GOAL_CONFIDENT_WRONG = 0.001
GOAL_RECOVERY = 5.0
"""s to recover from a kidnap"""


def generated_markdown(ok: Sequence[dict[str, Any]]) -> str:
    """For simulated runs (those scored against their kidnaps), per method and protocol: the
    seeds, the median ATE, and how many seeds meet each goal."""
    these = [r for r in ok if math.isfinite(_f(r, "lost_outside_kidnap_frac"))]
    if not these:
        return ""
    out = io.StringIO()
    out.write(f"\n## Generated runs: goals\n\nSeeds meeting each goal: lost ≤ "
              f"{GOAL_LOST:.0%} (outside the kidnap's recovery allowance), confident-wrong ≤ "
              f"{GOAL_CONFIDENT_WRONG:.1%}, kidnap recovered ≤ {GOAL_RECOVERY:g} s (of the seeds "
              "with a kidnap); median ATE outside the recovery allowance "
              f"(goal ≤ {GOAL_ATE * 100:g} cm).\n\n"
              "| method | protocol | seeds | median ATE | lost ok | confident-wrong ok | "
              "recovered ok |\n|---|---|---|---|---|---|---|\n")
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in these:
        groups.setdefault((_label(r), r["protocol"]), []).append(r)
    for (label, protocol), rs in sorted(groups.items()):
        n = len(rs)
        ate = sorted(_f(r, "ate_outside_kidnap_m") for r in rs)
        median = ate[n // 2] if n % 2 else 0.5 * (ate[n // 2 - 1] + ate[n // 2])
        lost = sum(_f(r, "lost_outside_kidnap_frac") <= GOAL_LOST for r in rs)
        cw = [_f(r, "confident_wrong_frac") for r in rs]
        cw_ok = (f"{sum(v <= GOAL_CONFIDENT_WRONG for v in cw)}"
                 if all(math.isfinite(v) for v in cw) else "–")
        kidnapped = [r for r in rs if r.get("recovery_s", "") != ""]
        rec = sum(_f(r, "recovery_s") <= GOAL_RECOVERY for r in kidnapped)
        out.write(f"| {label} | {protocol} | {n} | {_length(median)} | {lost} | {cw_ok} | "
                  f"{rec} of {len(kidnapped)} |\n")
    return out.getvalue()


def write_report(rows: Sequence[dict[str, Any]], out: Path) -> None:
    from fusion.io import atomic_write_text

    atomic_write_text(out / "summary.md", summary_markdown(rows))
    plot(rows, out / "summary.png")

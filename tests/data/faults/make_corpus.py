"""Writes the fault corpus beside this file: one small gzipped CARMEN log per fault, each the
same 6-second simulated RoboCup run (91 beams) damaged one way, with its map and ground truth.

    python tests/data/faults/make_corpus.py

``corpus.yaml`` says what each file must give (``tests/test_fault_corpus.py`` replays them
through ``houghloc run``): the exit status, what stderr must name, and for the recoverable ones
how far the accuracy may fall from the clean run's.
"""

from __future__ import annotations

import gzip
import shutil
from collections.abc import Callable
from pathlib import Path

from fusion.sim import scenario_preset, simulate, write_run
from fusion.sim.config import LaserConfig

HERE = Path(__file__).resolve().parent


def _stamp_index(tokens: list[str]) -> int:
    return 7 if tokens[0] == "ODOM" else len(tokens) - 3


def restamp(lines: list[str],
            change: Callable[[int, str, float], str | float | None]) -> list[str]:
    """The CARMEN lines with ``change(k, kind, t)`` as the stamp of record k (of its ODOM and
    ROBOTLASER1 records; None: unchanged; a float is printed to the microsecond)."""
    out = []
    for k, line in enumerate(lines):
        tokens = line.split()
        if tokens and tokens[0] in ("ODOM", "ROBOTLASER1"):
            i = _stamp_index(tokens)
            new = change(k, tokens[0], float(tokens[i]))
            if new is not None:
                tokens[i] = tokens[-1] = new if isinstance(new, str) else f"{new:.6f}"
        out.append(" ".join(tokens))
    return out


def _nth(lines: list[str], kind: str, n: int) -> int:
    return [k for k, line in enumerate(lines) if line.startswith(kind + " ")][n]


def _set_field(lines: list[str], k: int, field: int, value: str) -> list[str]:
    tokens = lines[k].split()
    tokens[field] = value
    return [*lines[:k], " ".join(tokens), *lines[k + 1:]]


def faults(lines: list[str]) -> dict[str, list[str] | bytes]:
    odom, laser = _nth(lines, "ODOM", 100), _nth(lines, "ROBOTLASER1", 20)
    t_odom = float(lines[odom].split()[7])
    repeated_end = _nth(lines, "ODOM", 150)

    def repeated(k: int, kind: str, t: float) -> str | None:
        return f"{t_odom:.6f}" if kind == "ODOM" and odom <= k < repeated_end else None

    backwards = list(lines)
    for n in (50, 120, 200):
        k = _nth(lines, "ODOM", n)
        backwards = _set_field(backwards, k, 7, f"{float(lines[k].split()[7]) - 0.5:.6f}")
    escape = _set_field(lines, laser, 0, "ROBOTLASER1\x1b[31mred")
    return {
        "clean": lines,
        "future-odometry-stamp": restamp(lines, lambda k, kind, t: (
            f"{t + 100.0:.6f}" if k == odom else None)),
        "laser-stamp-1e300": restamp(lines, lambda k, kind, t: "1e300" if k == laser else None),
        "repeated-odometry-stamps": restamp(lines, repeated),
        "coarse-stamps": restamp(lines, lambda k, kind, t: f"{round(t, 1):.1f}"),
        "backwards-stamps": backwards,
        "negative-stamps": restamp(lines, lambda k, kind, t: f"{t - 1000.0:.6f}"),
        "zero-stamps": restamp(lines, lambda k, kind, t: "0"),
        "absurd-odometry": _set_field(lines, odom, 1, "-1e300"),
        "nan-odometry": _set_field(lines, odom, 3, "nan"),
        "nan-beam": _set_field(lines, laser, 20, "nan"),
        "escape-bytes": escape,
        "truncated-line": [*lines[:laser], lines[laser][: len(lines[laser]) // 2],
                           *lines[laser + 1:]],
        "not-a-log": b"\x00\x01binary\xff" * 300,
    }


def main() -> None:
    run = simulate(scenario_preset("robocup-laser", seed=7, duration=6.0).model_copy(
        update={"laser": LaserConfig(n_beams=91)}))
    tmp = HERE / "_sim"
    paths = write_run(run, tmp)
    lines = paths["log"].read_text().splitlines()
    shutil.copy(paths["map"], HERE / "map.yaml")
    shutil.copy(paths["gt"], HERE / "gt.tum")
    for name, content in faults(lines).items():
        data = content if isinstance(content, bytes) else ("\n".join(content) + "\n").encode()
        (HERE / f"{name}.log.gz").write_bytes(gzip.compress(data, mtime=0))
    cut = gzip.compress(("\n".join(lines) + "\n").encode(), mtime=0)
    (HERE / "gzip-cut.log.gz").write_bytes(cut[: len(cut) * 2 // 3])
    shutil.rmtree(tmp)
    x, y, theta = run.odom_truth[0].tolist()
    (HERE / "start.txt").write_text(f"{x!r} {y!r} {theta!r}\n")


if __name__ == "__main__":
    main()

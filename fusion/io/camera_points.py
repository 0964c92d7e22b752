"""The ``camera.points`` file: floor points in the robot frame, one record per camera frame.

    POINTS t_capture t_arrival n x1 y1 ... xn yn
    LABELS t_capture n l1 ... ln        (the simulator's ground-truth labels; not read here)

``t_arrival`` is when the frame reached the localizer (``t_capture`` plus the pipeline's latency).
The simulator writes it beside its CARMEN log; :func:`fusion.io.open_log` merges the two.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from fusion.events import PointSet, ReadStats


def read_camera_points(path: str | Path, stats: ReadStats | None = None,
                       sensor: str = "camera") -> Iterator[PointSet]:
    """Yield the ``POINTS`` records of a ``camera.points`` file as :class:`PointSet` events
    (with ``arrival`` and the line number). A bad record is skipped with a warning that names the
    file and line (``warnings.warn``, and ``stats.warn`` if given); a missing file raises
    ``FileNotFoundError``."""
    path = Path(path)

    def bad(lineno: int, why: str) -> None:
        msg = f"{path}:{lineno}: skipped camera record: {why}"
        warnings.warn(msg, stacklevel=3)
        if stats is not None:
            stats.warn(msg)

    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, start=1):
            fields = line.split()
            if not fields or fields[0].startswith("#") or fields[0] == "LABELS":
                continue
            if fields[0] != "POINTS":
                bad(lineno, f"unknown record type {fields[0]!r}")
                continue
            try:
                t, arrival = float(fields[1]), float(fields[2])
                n = int(fields[3])
                values = np.array(fields[4:], dtype=float)
            except (IndexError, ValueError):
                bad(lineno, "expected 'POINTS t_capture t_arrival n x1 y1 ...' with numbers")
                continue
            if n < 0 or len(values) != 2 * n:
                bad(lineno, f"n = {n} but {len(values)} coordinates (expected {2 * max(n, 0)})")
                continue
            if not (math.isfinite(t) and math.isfinite(arrival) and np.isfinite(values).all()):
                bad(lineno, "non-finite value")
                continue
            if stats is not None:
                stats.records += 1
            yield PointSet(t, values.reshape(n, 2), sensor=sensor, arrival=arrival, line=lineno)

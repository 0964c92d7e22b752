"""``localized.csv``: the integrity output of a run beside its trajectory, one line per pose in
the trajectory's order (:mod:`fusion.integrity`)::

    t,probability,localized,status
    12.300000,0.999871,1,accepted

``probability``: that the pose is within 0.3 m and 5° of the truth; ``localized``: 1 when it is
at least 0.95 (:data:`fusion.integrity.LOCALIZED_PROBABILITY`); ``status``: what became of the
scan. Each line is flushed as it is written, as the trajectory's are, so an interrupted run
keeps every line it reported.
"""

from __future__ import annotations

from pathlib import Path
from typing import Self, TextIO

import numpy as np
from numpy.typing import NDArray

from fusion.integrity import is_localized

HEADER = "t,probability,localized,status\n"


class LocalizedWriter:
    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: TextIO | None = None

    def open(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("w", encoding="ascii", newline="\n")
        self._file.write(HEADER)
        self._file.flush()
        return self

    def write(self, t: float, probability: float, status: str) -> None:
        if self._file is None:
            raise RuntimeError("LocalizedWriter is not open")
        self._file.write(f"{t:.6f},{probability:.6f},{int(is_localized(probability))},{status}\n")
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_localized(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64], list[str]]:
    """The times, probabilities and statuses of a ``localized.csv``."""
    t, p, status = [], [], []
    with Path(path).open(encoding="ascii") as f:
        if f.readline() != HEADER:
            raise ValueError(f"{path}: not a localized.csv (expected the header "
                             f"{HEADER.strip()!r})")
        for number, line in enumerate(f, start=2):
            parts = line.rstrip("\n").split(",")
            if len(parts) != 4:
                raise ValueError(f"{path}:{number}: expected 4 fields, got {len(parts)}")
            t.append(float(parts[0]))
            p.append(float(parts[1]))
            status.append(parts[3])
    return np.array(t), np.array(p), status

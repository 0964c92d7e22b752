"""Reference relations (Kümmerle et al., "On measuring the accuracy of SLAM algorithms", 2009).

Each line ``t1 t2 dx dy dz roll pitch yaw``: the pose at ``t2`` expressed in the frame of the pose
at ``t1``. Only the planar part (dx, dy, yaw) is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.errors import LogError
from fusion.io.textfile import read_numeric_table
from houghloc.geometry import wrap_angle

INTEL_TIME_OFFSET = 976052857.337284
"""Subtract from the Intel relations' absolute times to reach the .mat/CARMEN relative time base."""


@dataclass(frozen=True)
class Relations:
    """N reference relations: ``t1``, ``t2`` (N,) and ``delta`` N×3 (dx, dy, dyaw)."""

    t1: NDArray[np.float64]
    t2: NDArray[np.float64]
    delta: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.t1)


def read_relations(path: str | Path, time_offset: float = 0.0) -> Relations:
    """Read a relations file; ``time_offset`` is subtracted from both times (for Intel use
    ``INTEL_TIME_OFFSET``). Comment lines start with ``#``. A malformed line raises ``LogError``
    with its line number (a reference must not be silently incomplete)."""
    data = read_numeric_table(path, 8)
    if len(data) == 0:
        raise LogError(Path(path), "no relations")
    # Subtract in float64 after parsing: absolute times ~1e9 keep ~1e-7 s resolution, enough.
    t1 = data[:, 0] - time_offset
    t2 = data[:, 1] - time_offset
    delta = np.column_stack((data[:, 2], data[:, 3], wrap_angle(data[:, 7])))
    return Relations(t1, t2, delta)

"""TUM trajectory files: ``t x y z qx qy qz qw`` per line, z = 0, the heading as a quaternion.

``evo`` and most SLAM tools read this format. The writer writes each line whole and flushes it, so
a run that is interrupted (Ctrl-C, crash, kill) leaves a file whose lines are all complete.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from types import TracebackType
from typing import Self, TextIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.io.errors import LogError
from fusion.io.textfile import read_numeric_table
from houghloc.geometry import wrap_angle


class TrajectoryValueError(ValueError):
    """A pose to be written is not finite: the localizer must never produce one."""


def heading_quaternion(theta: float) -> tuple[float, float, float, float]:
    """(qx, qy, qz, qw) of a rotation by ``theta`` about z."""
    half = 0.5 * theta
    return 0.0, 0.0, math.sin(half), math.cos(half)


def format_tum_line(t: float, x: float, y: float, theta: float) -> str:
    """One TUM line (with newline). Raises ``TrajectoryValueError`` on NaN/inf."""
    if not all(math.isfinite(v) for v in (t, x, y, theta)):
        raise TrajectoryValueError(f"non-finite pose at t={t!r}: ({x!r}, {y!r}, {theta!r})")
    qx, qy, qz, qw = heading_quaternion(theta)
    # Time with µs resolution; position to µm; quaternion to 1e-9 (≈ 2e-9 rad).
    return f"{t:.6f} {x:.6f} {y:.6f} 0.000000 {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n"


class TumWriter:
    """Write a trajectory in TUM format, one line per pose, each flushed as it is written.

    >>> with TumWriter("trajectory.tum") as w:
    ...     w.write(t, x, y, theta)

    ``fsync=True`` also forces each line to disk (survives a power cut, costs a syscall per line).
    """

    def __init__(self, path: str | Path, *, fsync: bool = False) -> None:
        self.path = Path(path)
        self.fsync = fsync
        self.count = 0
        self._file: TextIO | None = None

    def open(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # Line buffering is not enough on its own (a long line may be split over two writes);
        # each line is one write() followed by flush(), below.
        self._file = self.path.open("w", encoding="ascii", newline="\n")
        return self

    def write(self, t: float, x: float, y: float, theta: float) -> None:
        """Append one pose. Raises ``TrajectoryValueError`` for NaN/inf (nothing is written)."""
        if self._file is None:
            raise RuntimeError("TumWriter is not open (use it as a context manager)")
        line = format_tum_line(float(t), float(x), float(y), float(theta))
        self._file.write(line)
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self.count += 1

    def write_pose(self, t: float, pose: ArrayLike) -> None:
        """Append one pose given as (x, y, θ)."""
        x, y, theta = np.asarray(pose, dtype=float)
        self.write(t, x, y, theta)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def write_tum(path: str | Path, t: ArrayLike, poses: ArrayLike) -> Path:
    """Write a whole trajectory (N times, N×3 poses) at once."""
    t = np.asarray(t, dtype=float)
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(t) != len(poses):
        raise ValueError(f"{len(t)} times but {len(poses)} poses")
    with TumWriter(path) as writer:
        for ti, (x, y, theta) in zip(t.tolist(), poses.tolist(), strict=True):
            writer.write(ti, x, y, theta)
    return Path(path)


def read_tum(path: str | Path, limit: int | None = None
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read a TUM file into times (N,) and planar poses N×3 (x, y, yaw).

    The yaw is the heading of the quaternion's rotation (exact for rotations about z). Blank lines
    and ``#`` comments are skipped; any other malformed line raises ``LogError`` naming its line.
    ``limit``: stop after that many poses (the start pose of a long log without reading it all).
    """
    path = Path(path)
    data = read_numeric_table(path, 8, limit)
    if len(data) == 0:
        raise LogError(path, "no poses")
    qx, qy, qz, qw = data[:, 4:8].T
    norm = np.sqrt(qx**2 + qy**2 + qz**2 + qw**2)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        bad = int(np.argmax(np.abs(norm - 1.0) > 1e-3))
        raise LogError(path, f"pose {bad + 1}: quaternion not normalised (|q| = {norm[bad]:.6f})")
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy**2 + qz**2))
    return data[:, 0], np.column_stack((data[:, 1], data[:, 2], wrap_angle(yaw)))

"""The node's last pose on disk, so that a restart (a crash, a power cycle) starts where the
robot was rather than lost: written atomically every few seconds, read on activation and used
only when recent and well formed.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.files import atomic_write_text


@dataclass(frozen=True)
class SavedPose:
    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    frame: str
    saved_at: float
    """wall-clock seconds (time.time()): a restart compares it with its own clock."""

    def age(self, now: float | None = None) -> float:
        return (time.time() if now is None else now) - self.saved_at


def save_pose(path: str | Path, pose: NDArray[np.float64], cov: NDArray[np.float64],
              frame: str) -> None:
    """Write the pose atomically: a kill in the middle leaves the previous file whole."""
    doc = {"frame": frame, "saved_at": time.time(),
           "pose": [float(v) for v in pose], "covariance": [float(v) for v in np.ravel(cov)]}
    atomic_write_text(path, json.dumps(doc) + "\n")


def load_pose(path: str | Path) -> SavedPose:
    """The saved pose; ValueError naming the file and the problem when it cannot be used."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        pose = np.array(doc["pose"], dtype=float)
        cov = np.array(doc["covariance"], dtype=float).reshape(3, 3)
        saved = SavedPose(pose, cov, str(doc["frame"]), float(doc["saved_at"]))
    except FileNotFoundError:
        raise ValueError(f"{path}: no saved pose") from None
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ValueError(f"{path}: not a saved pose ({err})") from None
    if pose.shape != (3,) or not (np.isfinite(pose).all() and np.isfinite(cov).all()
                                  and math.isfinite(saved.saved_at)):
        raise ValueError(f"{path}: the saved pose is not three finite numbers with a finite "
                         "3×3 covariance")
    return saved

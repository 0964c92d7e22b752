"""Sightings of the map's landmarks (the RoboCup goals by their colour) by a forward camera.

At each scan time, a landmark within the camera's field of view and range is reported with its
label and a noisy bearing (robot frame). The walls do not hide the goals from inside the field.
"""

from __future__ import annotations

import numpy as np

from fusion.events import Landmark
from fusion.sim.run import SimRun


def landmark_sightings(run: SimRun, seed: int = 0, fov_deg: float = 60.0,
                       max_range: float = 9.0, sigma_deg: float = 2.0) -> list[Landmark]:
    """Landmark events at the scan (or camera) times of ``run``, in time order."""
    rng = np.random.default_rng(seed)
    times = run.scan_t if len(run.scan_t) else run.cam_t
    poses = run.scan_truth if len(run.scan_t) else run.cam_truth
    out: list[Landmark] = []
    for label, (lx, ly) in run.map.landmarks.items():
        dx, dy = lx - poses[:, 0], ly - poses[:, 1]
        bearing = np.arctan2(dy, dx) - poses[:, 2]
        bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
        seen = (np.abs(bearing) <= np.radians(fov_deg) / 2) & (np.hypot(dx, dy) <= max_range)
        noisy = bearing + rng.normal(0.0, np.radians(sigma_deg), len(bearing))
        out += [Landmark(float(t), label, float(b)) for t, b in zip(times[seen], noisy[seen],
                                                                      strict=True)]
    return sorted(out, key=lambda e: e.t)

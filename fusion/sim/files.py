"""Writing a simulated run to disk (:func:`fusion.io.open_log` reads it back).

``write_run(run, out_dir)`` writes, each file atomically (a temporary file, then ``os.replace``):

``log.carmen``
    CARMEN text log, one message per line, in time order (odometry first at equal times)::

        ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp
        FLASER n r1 … rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname \
logger_timestamp

    Scans are written as ``ROBOTLASER1``, which states its own beam layout (``FLASER`` leaves the
    spacing to convention, π/n or π/(n−1), and readers disagree); ``laser_message="FLASER"``
    (beam i at −90° + i·180°/(n−1)) or ``"auto"`` (FLASER for a 180° scanner) are available::

        ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode \
n r1 … rn 0 x y theta odom_x odom_y odom_theta tv rv forward_safety_dist side_safety_dist \
turn_axis ipc_timestamp ipc_hostname logger_timestamp

    (laser_type 3 = simulated, angles in radians, the ``0`` is the number of remission values).
    Both pose fields carry the odometry pose, as raw logs do; no return = ``max_range``;
    ``ipc_hostname`` is ``sim``; ``tv``/``rv`` are the odometry's velocities; ``accel`` is 0.
``gt.tum``
    Ground truth at every scan and camera capture: ``t x y 0 0 0 qz qw`` (z = 0, quaternion of
    the heading: qz = sin(θ/2), qw = cos(θ/2)).
``map.yaml``
    A copy of the map file.
``scenario.yaml``
    The :class:`~fusion.sim.config.ScenarioConfig` with ``map: map.yaml``; ``load_scenario``
    reads it back and ``simulate`` reproduces the run.
``camera.points`` (only with a camera)
    Text, ``#`` starts a comment; per frame, in arrival order::

        POINTS t_capture t_arrival n x1 y1 … xn yn
        LABELS t_capture n l1 … ln

    points in the robot frame at capture time (metres); labels as in ``fusion.sim.camera``
    (evaluation only; readers may ignore LABELS lines).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Literal

import numpy as np
import yaml

from fusion.io.files import atomic_file
from fusion.io.tum import format_tum_line
from fusion.sim.config import ScenarioConfig
from fusion.sim.poses import increments
from fusion.sim.run import SimRun
from fusion.sim.world import resolve_map_path
from houghloc.yaml_io import read_yaml, validated

HOSTNAME = "sim"
LASER_TYPE_SIMULATED = 3
_BLOCK = 4096  # records turned into Python values at a time while writing


def _atomic_write(path: Path, write: Callable[[IO[str]], object]) -> Path:
    """Write through :func:`~fusion.io.files.atomic_file`: a reader never sees a half-written
    file."""
    with atomic_file(path) as f:
        write(f)
    return path


def write_run(run: SimRun, out_dir: str | Path,
              laser_message: Literal["auto", "FLASER", "ROBOTLASER1"] = "ROBOTLASER1"
              ) -> dict[str, Path]:
    """Write the run's files (see the module docstring) and return their paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "log": _atomic_write(out / "log.carmen", lambda f: _write_carmen(run, f, laser_message)),
        "gt": _atomic_write(out / "gt.tum", lambda f: _write_tum(run, f)),
        "map": _atomic_write(out / "map.yaml",
                             lambda f: f.write(run.map_path.read_text(encoding="utf-8"))),
        "scenario": _atomic_write(out / "scenario.yaml", lambda f: _write_scenario(run, f)),
    }
    if run.config.camera is not None:
        paths["camera"] = _atomic_write(out / "camera.points", lambda f: _write_points(run, f))
    return paths


# ---------------------------------------------------------------------------------- CARMEN
def _odom_velocities(run: SimRun) -> tuple[np.ndarray, np.ndarray]:
    """(tv, rv) of each odometry record from the increment that ends at it (0 for the first)."""
    inc = increments(run.odom_pose)
    dt = np.diff(run.odom_t)
    tv = np.concatenate(([0.0], inc[:, 0] / dt))
    rv = np.concatenate(([0.0], inc[:, 2] / dt))
    return tv, rv


def _write_carmen(run: SimRun, f: IO[str], laser_message: str) -> None:
    """Stream the log: lines are made and written one at a time, merged by time with odometry
    first at equal times (a localizer predicts before it corrects)."""
    cfg = run.config
    f.write("# CARMEN Logfile\n# file format is one message per line\n")
    f.write(f"# simulated by fusion.sim: scenario {cfg.name!r}, seed {cfg.seed}\n")
    f.write("# ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp\n")
    tv, rv = _odom_velocities(run)
    has_scans = cfg.laser is not None and run.laser is not None and len(run.scan_t) > 0
    use_flaser = has_scans and cfg.laser is not None and (
        laser_message == "FLASER"
        or (laser_message == "auto" and math.isclose(cfg.laser.fov_deg, 180.0)))

    def odom_lines() -> Iterator[tuple[float, int, str]]:
        for k0 in range(0, len(run.odom_t), _BLOCK):  # in blocks: a list per record is costly
            block = slice(k0, k0 + _BLOCK)
            for (x, y, th), v, w, t, gone in zip(
                    run.odom_pose[block].tolist(), tv[block].tolist(), rv[block].tolist(),
                    run.odom_t[block].tolist(), run.odom_missing[block].tolist(), strict=True):
                if gone:  # a gap in the records (ScenarioConfig.odometry_gaps)
                    continue
                yield t, 0, (f"ODOM {x:.6f} {y:.6f} {th:.6f} {v:.6f} {w:.6f} 0.000000 {t:.6f} "
                             f"{HOSTNAME} {t:.6f}\n")

    def laser_lines() -> Iterator[tuple[float, int, str]]:
        if not has_scans or cfg.laser is None or run.laser is None:
            return
        fov = math.radians(cfg.laser.fov_deg)
        row_fmt = " ".join(["%.3f"] * len(run.angles))
        k_odom = np.clip(np.searchsorted(run.odom_t, run.scan_t), 0, len(run.odom_t) - 1)
        head = (f"{LASER_TYPE_SIMULATED} {run.angles[0]:.10f} {fov:.10f} "
                f"{fov / (len(run.angles) - 1):.12f} {cfg.laser.max_range:.3f} "
                f"{cfg.laser.sigma:.3f} 0")
        scans = zip(run.scan_t, run.scan_odom, k_odom, run.laser.scans(), strict=True)
        for t, (x, y, th), j, (r, _) in scans:
            ranges = row_fmt % tuple(r.tolist())
            pose = f"{x:.6f} {y:.6f} {th:.6f}"
            if use_flaser:
                yield t, 1, (f"FLASER {len(run.angles)} {ranges} {pose} {pose} "
                             f"{t:.6f} {HOSTNAME} {t:.6f}\n")
            else:
                yield t, 1, (f"ROBOTLASER1 {head} {len(run.angles)} {ranges} 0 {pose} {pose} "
                             f"{tv[j]:.6f} {rv[j]:.6f} 0.000 0.000 0.000 {t:.6f} {HOSTNAME} "
                             f"{t:.6f}\n")

    if has_scans:
        if use_flaser:
            f.write("# FLASER n r1 ... rn x y theta odom_x odom_y odom_theta "
                    "ipc_timestamp ipc_hostname logger_timestamp\n")
        else:
            f.write("# ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy "
                    "remission_mode n r1 ... rn 0 x y theta odom_x odom_y odom_theta tv rv "
                    "forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname "
                    "logger_timestamp\n")
    for *_, line in heapq.merge(odom_lines(), laser_lines()):
        f.write(line)


# ---------------------------------------------------------------------------------- TUM
def _write_tum(run: SimRun, f: IO[str]) -> None:
    f.write("# ground truth: t x y z qx qy qz qw\n")
    f.writelines(format_tum_line(t, x, y, theta) for t, (x, y, theta)
                 in zip(run.truth_t.tolist(), run.truth.tolist(), strict=True))


# ---------------------------------------------------------------------------------- scenario
def _write_scenario(run: SimRun, f: IO[str]) -> None:
    data = run.config.model_dump(mode="json")
    data["map"] = "map.yaml"
    f.write("# houghloc simulated scenario; reproduce with fusion.sim: "
            "simulate(load_scenario(this file))\n")
    yaml.safe_dump(data, f, sort_keys=False, width=100)


def load_scenario(path: str | Path) -> ScenarioConfig:
    """Read a scenario YAML; a relative ``map`` is resolved against the file's directory first
    (then the working directory and ``fusion/configs/maps``) and stored as an absolute path."""
    path = Path(path)
    raw = read_yaml(path, ValueError, "scenario")
    cfg = validated(ScenarioConfig, raw, ValueError, "scenario", str(path))
    map_path = resolve_map_path(cfg.map, base=path.parent)
    return cfg.model_copy(update={"map": str(map_path)})


# ---------------------------------------------------------------------------------- camera
def _write_points(run: SimRun, f: IO[str]) -> None:
    f.write("# houghloc camera points: floor points in the robot frame at capture time (m)\n")
    f.write("# POINTS t_capture t_arrival n x1 y1 ... xn yn\n# LABELS t_capture n l1 ... ln\n")
    for k in np.argsort(run.cam_arrival, kind="stable").tolist():
        pts, lab = run.cam_points[k], run.cam_labels[k]
        t, a = float(run.cam_t[k]), float(run.cam_arrival[k])
        xy = " ".join(["%.4f"] * pts.size) % tuple(pts.ravel().tolist())
        f.write(f"POINTS {t:.6f} {a:.6f} {len(pts)}{' ' if len(pts) else ''}{xy}\n")
        ls = " ".join(str(v) for v in lab.tolist())
        f.write(f"LABELS {t:.6f} {len(lab)}{' ' if len(lab) else ''}{ls}\n")

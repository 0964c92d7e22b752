"""MRPT's ``pf-localization`` (Debian package ``mrpt-apps``) as a benchmark peer.

It is a batch program: it reads a rawlog and a map and writes what it estimates. So each piece
is written out the way its converters expect:

* the piece's events as a raw CARMEN log (``ROBOTLASER1`` records, which state their beam
  layout; the robot pose fields carry the raw odometry, moved to start at the start pose — the
  filter uses only its increments), converted by ``carmen2rawlog``;
* the map-building scans at their reference poses likewise, converted by ``carmen2simplemap``;
  ``pf-localization`` builds its occupancy grid (5 cm) from it;
* a configuration with MRPT's likelihood-field model (``LF_Trun``) and KLD-adaptive sampling,
  the particles drawn uniformly in ±0.3 m and ±10° around the start pose, or over the map's
  free cells for a global start.

The pose after each scan is read from the program's ``PDF estimation`` lines, one per
(odometry, scan) pair; its CPU time is the child process's.
"""

from __future__ import annotations

import math
import re
import resource
import shutil
import subprocess
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from fusion.bench.data import Piece, scan_stamp
from fusion.config import SensorConfig
from fusion.evaluation import Trajectory
from fusion.events import Odometry, Scan
from houghloc.geometry import Pose, compose, relative

PROGRAMS = ("pf-localization", "carmen2rawlog", "carmen2simplemap")
START_BOX_XY = 0.3
"""m: the start pose's particles are drawn within this of it (as AMCL's initial σ is 0.5 m)."""
START_BOX_DEG = 10.0

_ESTIMATE = re.compile(r"PDF estimation: \(([-\d.eE+]+),([-\d.eE+]+),([-\d.eE+]+)deg\)")


class MrptUnavailable(RuntimeError):
    """``pf-localization`` or its converters are not installed."""


def run_pf_localization(piece: Piece, sensor: SensorConfig, timeout: float = 7200.0
                        ) -> tuple[Trajectory, float]:
    """The poses at the piece's scans and the CPU seconds ``pf-localization`` spent."""
    missing = [p for p in PROGRAMS if shutil.which(p) is None]
    if missing:
        raise MrptUnavailable(f"mrpt needs {', '.join(missing)}: apt-get install mrpt-apps")
    if not piece.map_source.scans:
        raise ValueError("mrpt needs a map built from scans (build_from), not a given map")
    with tempfile.TemporaryDirectory(prefix="houghloc-mrpt-") as tmp:
        folder = Path(tmp)
        scans = piece.scans
        _write_carmen(folder / "run.log", _odometry_records(piece))
        _write_carmen(folder / "map.log", ((s, s.reference) for s in piece.map_source.scans))
        _convert("carmen2rawlog", folder / "run.log", folder / "run.rawlog")
        _convert("carmen2simplemap", folder / "map.log", folder / "map.simplemap")
        (folder / "pf.ini").write_text(_ini(folder, piece, sensor))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run(["pf-localization", str(folder / "pf.ini")], cwd=folder,
                              stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              timeout=timeout, check=False)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    found = [(float(x), float(y), math.radians(float(d)))
             for x, y, d in _ESTIMATE.findall(done.stdout + done.stderr)]
    if done.returncode != 0 or len(found) != len(scans):
        tail = (done.stdout + done.stderr).strip().splitlines()[-3:]
        raise RuntimeError(f"pf-localization gave {len(found)} poses for {len(scans)} scans "
                           f"(exit {done.returncode}): {' / '.join(tail)}")
    return Trajectory(np.array([scan_stamp(s) for s in scans]), np.asarray(found)), cpu


def _odometry_records(piece: Piece) -> Iterable[tuple[Scan, tuple[float, float, float]]]:
    """Each scan with the raw odometry at it, moved so that the first scan is at the start
    pose (or the origin for a global start)."""
    start = piece.start if piece.start is not None else np.zeros(3)
    first = last = None
    for e in piece.events:
        if isinstance(e, Odometry) and math.isfinite(e.x + e.y + e.theta):
            last = np.array((e.x, e.y, e.theta))
        elif isinstance(e, Scan):
            now = last if last is not None else np.zeros(3)
            first = now if first is None else first
            yield e, tuple(compose(start, relative(first, now)).tolist())


def _write_carmen(path: Path, records: Iterable[tuple[Scan, Pose | None]]) -> None:
    with path.open("w") as f:
        for scan, pose in records:
            assert pose is not None  # the map's scans are corrected ones
            x, y, th = (float(v) for v in pose)
            angles = np.asarray(scan.angles, dtype=float)
            n = len(angles)
            step = (angles[-1] - angles[0]) / (n - 1) if n > 1 else 0.0
            max_range = min(scan.max_range, 80.0)
            ranges = np.where(np.isfinite(scan.ranges), scan.ranges, max_range)
            t = scan_stamp(scan)
            f.write(f"ROBOTLASER1 0 {angles[0]:.10f} {step * (n - 1):.10f} {step:.12f} "
                    f"{max_range:.3f} 0.01 0 {n} " + " ".join(f"{r:.3f}" for r in ranges)
                    + f" 0 {x:.6f} {y:.6f} {th:.6f} {x:.6f} {y:.6f} {th:.6f} 0 0 0 0 0 "
                    f"{t:.6f} bench {t:.6f}\n")


def _convert(program: str, source: Path, target: Path) -> None:
    done = subprocess.run([program, "-i", str(source), "-o", str(target), "-w", "-q"],
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=600, check=False)
    if done.returncode != 0 or not target.exists():
        raise RuntimeError(f"{program} failed: {(done.stderr or done.stdout).strip()[-300:]}")


def _ini(folder: Path, piece: Piece, sensor: SensorConfig) -> str:
    if piece.start is None:
        pts = piece.map_source.points
        (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
        box = (0, x0, x1, y0, y1, -180.0, 180.0, 40000)  # free cells of the whole map
    else:
        x, y, th = piece.start
        b, d = START_BOX_XY, START_BOX_DEG
        box = (1, x - b, x + b, y - b, y + b, math.degrees(th) - d, math.degrees(th) + d,
               5000)
    mode, x0, x1, y0, y1, a0, a1, count = box
    return f"""[KLD_options]
KLD_binSize_PHI_deg=5
KLD_binSize_XY=0.10
KLD_delta=0.01
KLD_epsilon=0.01
KLD_maxSampleSize=40000
KLD_minSampleSize=150
KLD_minSamplesPerBin=0
[PF_options]
PF_algorithm=0
resamplingMethod=0
adaptiveSampleSize=1
BETA=0.5
sampleSize=1
[DummyOdometryParams]
minStdXY=0.10
minStdPHI=2.0
[LocalizationExperiment]
map_file={folder / 'map.simplemap'}
rawlog_file={folder / 'run.rawlog'}
logOutput_dir=
experimentRepetitions=1
particles_count={count}
init_PDF_mode={mode}
init_PDF_min_x={x0:.4f}
init_PDF_max_x={x1:.4f}
init_PDF_min_y={y0:.4f}
init_PDF_max_y={y1:.4f}
init_PDF_min_yaw_deg={a0:.4f}
init_PDF_max_yaw_deg={a1:.4f}
SHOW_PROGRESS_3D_REAL_TIME=false
[MetricMap]
occupancyGrid_count=1
likelihoodMapSelection=-1
[MetricMap_occupancyGrid_00_creationOpts]
resolution=0.05
[MetricMap_occupancyGrid_00_insertOpts]
maxDistanceInsertion={sensor.max_range:.1f}
maxOccupancyUpdateCertainty=0.55
considerInvalidRangesAsFreeSpace=0
[MetricMap_occupancyGrid_00_likelihoodOpts]
likelihoodMethod=4
LF_decimation=5
LF_stdHit=0.20
LF_maxCorrsDistance=0.30
LF_zHit=0.95
LF_zRandom=0.05
LF_maxRange={sensor.max_range:.1f}
"""

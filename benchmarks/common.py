"""Helpers shared by the benchmark scripts: interleaved timing and small scene builders."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from houghloc import SegmentMap
from houghloc.geometry import ray_segment_distances

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "fusion" / "configs" / "maps"


def time_interleaved(funcs: dict[str, Callable[[], object]], rounds: int = 15,
                     inner: int = 20) -> dict[str, float]:
    """Median seconds per call of each function, measured in alternating rounds.

    These machines are noisy: alternating the contenders round by round exposes them to the same
    load, so their ratio means something even when absolute times drift.
    """
    samples = time_rounds(funcs, rounds, inner)
    return {k: float(np.median(v)) for k, v in samples.items()}


def time_rounds(funcs: dict[str, Callable[[], object]], rounds: int = 15,
                inner: int = 20) -> dict[str, NDArray[np.float64]]:
    """Seconds per call of each function in each of ``rounds`` alternating rounds: the k-th
    entries of two contenders ran side by side, so their ratio is paired."""
    samples: dict[str, list[float]] = {k: [] for k in funcs}
    for f in funcs.values():
        f()  # warm caches and lazy initialisation
    for _ in range(rounds):
        for name, f in funcs.items():
            t0 = time.perf_counter()
            for _ in range(inner):
                f()
            samples[name].append((time.perf_counter() - t0) / inner)
    return {k: np.array(v) for k, v in samples.items()}


def ray_scan(m: SegmentMap, pose: np.ndarray, n_beams: int = 361, fov: float = np.pi,
             sigma: float = 0.01, max_range: float = 10.0, seed: int = 0) -> np.ndarray:
    """Robot-frame points of a noisy laser scan of the map's walls (first hit per beam)."""
    rng = np.random.default_rng(seed)
    rel = np.linspace(-fov / 2, fov / 2, n_beams)
    ang = rel + pose[2]
    d = np.column_stack((np.cos(ang), np.sin(ang)))
    near = m.segments_near(pose[:2], max_range)
    walls = near[m.is_wall[near]]
    r = ray_segment_distances(pose, d, m.starts[walls], m.ends[walls]).min(axis=1, initial=np.inf)
    r = r + rng.normal(0.0, sigma, n_beams)
    keep = r < max_range
    return np.column_stack((r * np.cos(rel), r * np.sin(rel)))[keep]


def tiled_map(base: SegmentMap, n_segments: int) -> SegmentMap:
    """Copies of ``base`` side by side on a square grid until ``n_segments`` are reached."""
    span = base.starts.max(axis=0) - base.starts.min(axis=0) + 1.0
    tiles = int(np.ceil(n_segments / len(base)))
    side = int(np.ceil(np.sqrt(tiles)))
    starts, ends = [], []
    for k in range(tiles):
        off = np.array([k % side, k // side]) * span
        starts.append(base.starts + off)
        ends.append(base.ends + off)
    s = np.concatenate(starts)[:n_segments]
    e = np.concatenate(ends)[:n_segments]
    kinds = list(np.tile(base.kinds, tiles)[:n_segments])
    return SegmentMap(s, e, kinds=kinds, name=f"{base.name}x{tiles}")


def opencv_voting(points: np.ndarray) -> Callable[[], object]:
    """OpenCV's Hough transform of ``points`` at 1° × 1 cm over ρ ∈ [−20, 20] m: the peer."""
    pts = points.astype(np.float32).reshape(-1, 1, 2)
    return lambda: cv2.HoughLinesPointSet(pts, 32, 10, -20.0, 20.0, 0.01, 0.0, np.pi,
                                          np.pi / 180)


def icp_alignment(m: SegmentMap, points: np.ndarray, guess: np.ndarray
                  ) -> Callable[[], object] | None:
    """One scan-to-map point-to-point ICP alignment (``small_gicp``, the benchmark's ICP peer with
    its settings) of ``points`` from ``guess``, against the map as the benchmark gives it to ICP
    (points along the segments, one per 2.5 cm cell); None when the peers extra is not
    installed."""
    try:
        import small_gicp
    except ImportError:
        return None
    from fusion.bench.data import MAP_POINT_SPACING, thin
    from fusion.bench.methods import ICP_MAX_CORRESPONDENCE, ICP_MAX_ITERATIONS

    along = [a + np.linspace(0.0, 1.0, max(2, int(np.ceil(np.hypot(*(b - a)) / 0.01)) + 1))[:, None]
             * (b - a) for a, b in zip(m.starts, m.ends, strict=True)]
    target_xy = thin(np.concatenate(along), MAP_POINT_SPACING)
    target = small_gicp.PointCloud(np.column_stack((target_xy, np.zeros(len(target_xy)))))
    tree = small_gicp.KdTree(target)
    xyz = np.column_stack((points, np.zeros(len(points))))
    c, s = np.cos(guess[2]), np.sin(guess[2])
    init = np.eye(4)
    init[:2, :2] = ((c, -s), (s, c))
    init[:2, 3] = guess[:2]

    def align() -> object:
        return small_gicp.align(target, small_gicp.PointCloud(xyz), tree, init,
                                registration_type="ICP",
                                max_correspondence_distance=ICP_MAX_CORRESPONDENCE,
                                max_iterations=ICP_MAX_ITERATIONS)

    return align


def yardstick_seconds(calls: int = 200) -> float:
    """Median seconds of the peer on a fixed 361-beam RoboCup scan: the machine's speed now.

    A long replay cannot be interleaved call by call with a peer, so its time per scan is
    divided by this, measured just before and after it: the ratio survives the drift of a shared
    machine between runs, where scans per second do not.
    """
    peer = opencv_voting(_yardstick_scan())
    for _ in range(50):  # the first calls of a fresh process run slow (caches, clock ramp-up)
        peer()
    samples = []
    for _ in range(calls):
        t0 = time.perf_counter()
        peer()
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


@functools.lru_cache(maxsize=1)
def _yardstick_scan() -> np.ndarray:
    """The peer's fixed scan, built once per process (it is timed before and after each run)."""
    field = SegmentMap.from_yaml(MAPS / "robocup.yaml")
    return ray_scan(field, np.array([0.5, -0.4, 0.3]), 361, seed=0)

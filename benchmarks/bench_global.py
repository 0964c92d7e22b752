"""Speed of global set matching (docs/method.md §6) on office-large, and its growth with the map.

Prints (1) one `global_match` on the packaged map `office-large` from 360° of accumulated views
(median over poses; target ≤ 0.2 s), its success and the one-off cost of the per-map caches,
(2) how it grows when office-large is tiled up to thousands of segments, with the numbers that
explain the growth (map lines, angle-index entries, pose hypotheses), and (3) what the pruning buys
on the largest map: the cap on observed pairs and the vote/cheap-score stages before the
point-based score. Times are medians of interleaved rounds on a shared machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import MAPS, ray_scan, tiled_map, time_interleaved
from houghloc import SegmentMap, observe_lines
from houghloc.geometry import relative, transform_points, wrap_angle
from houghloc.global_match import GlobalMatchConfig, global_match
from houghloc.map_lookup import angle_index, wall_distance

POSES = [np.array(p) for p in ((21.66, 2.7, -0.58), (9.57, 21.04, -2.77), (29.38, 17.07, 2.71),
                               (2.67, 8.26, -0.44), (37.75, 3.04, 2.29), (14.56, 16.15, 2.01))]


def accumulated_views(m: SegmentMap, pose: np.ndarray, seed: int) -> np.ndarray:
    """Four 180° scans a quarter turn apart (a few cm of motion), in the frame of ``pose``."""
    rng = np.random.default_rng(seed)
    views = []
    for k in range(4):
        view = pose + np.array([*rng.normal(0.0, 0.05, 2), k * np.pi / 2])
        scan = ray_scan(m, view, 181, seed=seed * 4 + k)
        views.append(transform_points(relative(pose, view), scan))
    return np.concatenate(views)


def build_caches(m: SegmentMap, cfg: GlobalMatchConfig) -> float:
    """Seconds to build the angle index and the distance-transform grid (once per map)."""
    t0 = time.perf_counter()
    angle_index(m, ("wall",), cfg.min_pair_angle, cfg.angle_tol_max + 1e-9)
    wall_distance(m, ("wall",), cfg.dt_cell)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--max-segments", type=int, default=2000)
    args = parser.parse_args(argv)
    cfg = GlobalMatchConfig()
    office = SegmentMap.from_yaml(MAPS / "office-large.yaml")
    results: dict = {}

    print(f"1) one global match on office-large ({len(office)} segments, {office.n_lines} lines)")
    cache_s = build_caches(office, cfg)
    scenes = []
    for i, pose in enumerate(POSES):
        pts = accumulated_views(office, pose, seed=i)
        scenes.append((pose, pts, observe_lines(pts, cfg.hough)[2]))
    times, hits = [], 0
    for pose, pts, lines in scenes:
        res = global_match(lines, pts, office, cfg)
        best = res.best
        hits += best is not None and bool(np.hypot(*(best.pose[:2] - pose[:2])) < 0.1 and abs(
            wrap_angle(best.pose[2] - pose[2])) < np.radians(2))
        t = time_interleaved({"global": lambda ln=lines, p=pts: global_match(ln, p, office, cfg)},
                             rounds=args.rounds, inner=3)
        times.append(t["global"])
    results["office_large_s"] = float(np.median(times))
    print(f"   {len(POSES)} poses, {np.median([len(s[1]) for s in scenes]):.0f} points and "
          f"{np.median([len(s[2]) for s in scenes]):.0f} lines each: median "
          f"{np.median(times) * 1e3:.1f} ms, max {max(times) * 1e3:.1f} ms  (target ≤ 200 ms); "
          f"best within 10 cm / 2°: {hits}/{len(POSES)}")
    print(f"   per-map caches (angle index + distance grid), built once: {cache_s * 1e3:.1f} ms")

    print("2) growth with the map (office-large tiled; the robot in the first copy)")
    print(f"   {'segments':>8} {'lines':>6} {'index':>8} {'hypotheses':>10} {'caches ms':>10} "
          f"{'match ms':>9} {'× base':>7}")
    pose, pts, lines = scenes[0]
    sizes = [n for n in (len(office), 250, 500, 1000, 2000, 4000) if n <= args.max_segments]
    growth = {}
    for n in sizes:
        m = office if n == len(office) else tiled_map(office, n)
        cache_s = build_caches(m, cfg)
        index = angle_index(m, ("wall",), cfg.min_pair_angle, cfg.angle_tol_max + 1e-9)
        res = global_match(lines, pts, m, cfg)
        t = time_interleaved({"global": lambda mm=m: global_match(lines, pts, mm, cfg)},
                             rounds=max(3, args.rounds // 2), inner=2)["global"]
        growth[len(m)] = t
        base = growth[len(office)]
        caches = "(in 1)" if m is office else f"{cache_s * 1e3:.1f}"
        print(f"   {len(m):8d} {m.n_lines:6d} {len(index.delta):8d} {res.n_candidates:10d} "
              f"{caches:>10} {t * 1e3:9.1f} {t / base:7.2f}")
    results["growth"] = growth

    largest = office if sizes[-1] == len(office) else tiled_map(office, sizes[-1])
    print(f"3) what the pruning buys on the largest map ({len(largest)} segments)")
    build_caches(largest, cfg)
    print("   (the tiles are identical copies: every copy of the true pose is a right answer)")
    variants = {
        "default": cfg,
        "no hypothesis budget (every pair expanded)": cfg.model_copy(
            update={"max_pair_hypotheses": 10**9}),
        "no budget, all pairs of the 12 strongest lines": cfg.model_copy(
            update={"max_pair_hypotheses": 10**9, "max_observed_pairs": 66}),
        "no vote cap (every cell gets the cheap score)": cfg.model_copy(
            update={"max_cells_cheap": 10**9}),
    }
    span = office.starts.max(axis=0) - office.starts.min(axis=0) + 1.0  # as in tiled_map
    for name, c in variants.items():
        res = global_match(lines, pts, largest, c)
        t = time_interleaved({"v": lambda c=c: global_match(lines, pts, largest, c)},
                             rounds=3, inner=1)["v"]
        found = any(is_copy(h.pose, pose, span) for h in res.hypotheses)
        print(f"   {name:48s} {res.n_candidates:9d} hypotheses {t * 1e3:8.1f} ms  "
              f"a copy of the true pose reported: {found}")
    return results


def is_copy(pose: np.ndarray, truth: np.ndarray, span: np.ndarray) -> bool:
    """Is ``pose`` the true pose in some tile (within 10 cm / 2°)?"""
    shift = (pose[:2] - truth[:2]) / span
    off = (shift - np.round(shift)) * span
    return bool(np.hypot(*off) < 0.1 and abs(wrap_angle(pose[2] - truth[2])) < np.radians(2))


if __name__ == "__main__":
    main()

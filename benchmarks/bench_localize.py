"""Speed of one `localize_scan` step against OpenCV's Hough voting on the same points.

Prints (1) the ratio of our whole step (vote, peaks, refinement, matching, displacement) to
`cv2.HoughLinesPointSet` alone at 1° × 1 cm over ρ ∈ [−20, 20] m on the same 361-point scans,
(2) how the step grows with the number of points, (3) how it grows with the map's size.
Absolute times on a shared machine mean little; the ratios are measured in the same run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks.common import (
    MAPS,
    REPO,
    icp_alignment,
    opencv_voting,
    ray_scan,
    tiled_map,
    time_interleaved,
    time_rounds,
)
from houghloc import HoughConfig, SegmentMap, localize_scan


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--plot", type=Path, default=REPO / "runs" / "bench" / "localize.png",
                        help="where to draw the growth with points and map size (PNG)")
    args = parser.parse_args(argv)
    cfg = HoughConfig()
    field = SegmentMap.from_yaml(MAPS / "robocup.yaml")
    rng = np.random.default_rng(7)
    poses = [np.array([rng.uniform(-3.5, 3.5), rng.uniform(-1.8, 1.8), rng.uniform(-3, 3)])
             for _ in range(8)]
    guesses = [p + np.array([0.1, -0.1, np.radians(4)]) for p in poses]

    results = {}
    print("1) one scan step, RoboCup field (median per call), against one OpenCV Hough voting "
          "and one small_gicp ICP alignment of the same scan")
    for beams in (180, 361):
        scans = [ray_scan(field, p, beams, seed=i) for i, p in enumerate(poses)]
        ours_t, cv_t, icp_t = [], [], []
        for pts, guess in zip(scans, guesses, strict=True):
            contenders = {"ours": lambda p=pts, g=guess: localize_scan(p, field, g, cfg),
                          "opencv": opencv_voting(pts)}
            icp = icp_alignment(field, pts, guess)
            if icp is not None:
                contenders["icp"] = icp
            t = time_interleaved(contenders, rounds=args.rounds)
            ours_t.append(t["ours"])
            cv_t.append(t["opencv"])
            icp_t.append(t.get("icp", np.nan))
        ratio = float(np.median(np.array(ours_t) / np.array(cv_t)))
        results[f"ratio_vs_opencv_{beams}"] = ratio
        line = (f"   {beams} beams: localize_scan {np.median(ours_t) * 1e3:.3f} ms   "
                f"cv2.HoughLinesPointSet (1°×1 cm, ρ∈[−20,20]) {np.median(cv_t) * 1e3:.3f} ms "
                f"ratio {ratio:.2f}× (target ≤ 0.15×)")
        if np.isfinite(icp_t).all():
            icp_ratio = float(np.median(np.array(ours_t) / np.array(icp_t)))
            results[f"ratio_vs_icp_{beams}"] = icp_ratio
            line += (f"   small_gicp ICP {np.median(icp_t) * 1e3:.3f} ms ratio {icp_ratio:.2f}× "
                     "(target ≤ 1.0×)")
        else:
            line += "   (small_gicp not installed: pip install 'houghloc[peers]')"
        print(line)
    results["ratio_vs_opencv"] = results["ratio_vs_opencv_361"]

    print("2) growth with the number of points (same scene, denser beams)")
    base = None
    growth: dict[str, list[tuple[int, float]]] = {"ours": [], "opencv": [], "map": []}
    for n in (100, 361, 1000, 3000, 10000):
        pts = ray_scan(field, poses[0], n, seed=1)
        t = time_interleaved({"ours": lambda p=pts: localize_scan(p, field, guesses[0], cfg),
                              "opencv": opencv_voting(pts)}, rounds=max(5, args.rounds // 3))
        base = base or t["ours"]
        growth["ours"].append((n, t["ours"]))
        growth["opencv"].append((n, t["opencv"]))
        print(f"   {n:6d} points: {t['ours'] * 1e3:7.3f} ms ({t['ours'] / base:5.2f}× of 100)"
              f"   opencv {t['opencv'] * 1e3:7.3f} ms   ratio {t['ours'] / t['opencv']:.2f}×")

    print("3) growth with the map (office tiled; the robot in the first copy)")
    office = SegmentMap.from_yaml(MAPS / "office.yaml")
    pose = np.array([5.0, 6.0, 0.3])
    pts = ray_scan(office, pose, 361, seed=2)
    guess = pose + np.array([0.1, 0.1, 0.05])
    maps = {}
    for n in (10, 100, 1000, 10000):
        big = tiled_map(office, max(n, 29)) if n >= 29 else office
        if n < 29:  # fewer segments than the office: keep the ones nearest the robot
            near = np.argsort(np.linalg.norm((big.starts + big.ends) / 2 - pose[:2], axis=1))[:n]
            big = SegmentMap(big.starts[near], big.ends[near], list(big.kinds[near]))
        maps[n] = big
    # the sizes in alternating rounds: a burst of load on the machine falls on all of them, and
    # each size is compared with the smallest map in the same round (a paired ratio), so that
    # the machine's drift between rounds does not read as growth
    rounds = time_rounds({str(n): lambda b=big: localize_scan(pts, b, guess, cfg)
                          for n, big in maps.items()}, rounds=args.rounds)
    smallest = rounds[str(min(maps))]
    relative = {}
    for n, big in maps.items():
        relative[n] = float(np.median(rounds[str(n)] / smallest))
        growth["map"].append((len(big), float(np.median(rounds[str(n)]))))
        print(f"   {len(big):6d} segments: {np.median(rounds[str(n)]) * 1e3:7.3f} ms "
              f"({relative[n]:.2f}× of {min(maps)}, median of the rounds' ratios)")
    spread = max(relative.values()) / min(relative.values())
    results["map_size_spread"] = spread
    print(f"   largest / smallest: {spread:.2f}×  (target ≤ 1.2×)")
    _plot(growth, args.plot)
    print(f"   plot: {args.plot}")
    return results


def _plot(growth: dict[str, list[tuple[int, float]]], path: Path) -> None:
    """Time per step against the scan's points and the map's segments, log–log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for name, label in (("ours", "localize_scan"), ("opencv", "cv2.HoughLinesPointSet")):
        n, t = zip(*growth[name], strict=True)
        left.loglog(n, np.array(t) * 1e3, "o-", label=label)
    n, t = zip(*growth["ours"], strict=True)
    left.loglog(n, t[0] * 1e3 * np.array(n) / n[0], ":", color="grey", label="linear in points")
    left.set(xlabel="points in the scan", ylabel="ms per scan", title="growth with the points")
    left.legend()
    n, t = zip(*growth["map"], strict=True)
    right.semilogx(n, np.array(t) * 1e3, "o-", label="localize_scan, 361 points")
    right.set(xlabel="segments in the map", ylabel="ms per scan", title="growth with the map",
              ylim=(0, 1.5 * max(t) * 1e3))
    right.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()

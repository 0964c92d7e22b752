"""Localization on the real logs (Intel lab, Freiburg 079, ACES) end to end, without Rerun.

    python -m benchmarks.bench_real [--only intel|fr079|aces] [--scans N] [--set KEY=VALUE …]
    python -m benchmarks.bench_real --build-maps [--only …]   # rebuild the packaged maps + pictures

For each dataset: houghloc (odometry + Hough fixes in the EKF) against the GMapping reference
poses (ATE RMSE / max, lost = > 0.3 m or > 5°), the odometry alone (SE(2)-aligned to the
reference, its best case), and for Intel the relation error of Kümmerle et al. 2009 for all three
— houghloc, odometry, and the GMapping poses themselves (the reference's own quality).

Start pose: the first scan's reference pose. Odometry before the first scan is dropped (but the
last reading before it, which anchors the odometry frame), so motion before the first scan cannot
matter. Intel's .mat has no reference poses: they come from ``intel.gfs.log`` (FLASER poses), and
its start pose is the GMapping map's origin (the robot stands still there for 30 s; composing the
first FLASER pose back to t = 0 with the raw odometry is 6.7° off: the odometry over-reports the
first turn).

``--set scan_odometry.enabled=false`` (dotted keys, YAML values; repeatable) overrides settings
of each dataset's config for the run: how the robustness of a setting is measured.

Skips with a message when ``../shared/data`` is missing.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import yardstick_seconds
from fusion.bench.data import reference_poses
from fusion.io import from_first_scan

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


@dataclass(frozen=True)
class Dataset:
    name: str
    log: Path
    map: Path
    config: Path
    reference: Path | None = None  # a corrected log with the reference poses (None: `log` has them)
    relations: Path | None = None
    time_offset: float = 0.0
    initial_pose: tuple[float, float, float] | None = None  # None: the first scan's reference


def datasets() -> list[Dataset]:
    from fusion.io import INTEL_TIME_OFFSET

    return [
        Dataset("intel", DATA / "intel" / "scan_intel.mat", ROOT / "fusion/configs/maps/intel.yaml",
                ROOT / "fusion/configs/intel-laser.yaml", DATA / "intel" / "intel.gfs.log",
                DATA / "intel" / "intel.relations", INTEL_TIME_OFFSET, (0.0, 0.0, 0.0)),
        Dataset("fr079", DATA / "fr079" / "freiburg-079-corrected.log.gz",
                ROOT / "fusion/configs/maps/fr079.yaml", ROOT / "fusion/configs/fr079-laser.yaml"),
        Dataset("aces", DATA / "aces" / "aces-corrected.log.gz",
                ROOT / "fusion/configs/maps/aces.yaml",
                ROOT / "fusion/configs/aces-laser.yaml"),
    ]


MAP_SOURCES = {  # the corrected log each map is built from, and who recorded it
    "intel": ("intel/intel.gfs.log", "Dirk Hähnel (Intel Research Lab Seattle)"),
    "fr079": ("fr079/freiburg-079-corrected.log.gz", "Cyrill Stachniss (Freiburg building 079)"),
    "aces": ("aces/aces-corrected.log.gz", "Patrick Beeson (ACES, UT Austin)"),
}


def build_real_map(name: str, out_yaml: Path, png: Path | None = None):
    """The segment map of one building from its corrected log (the builder's defaults), written
    to ``out_yaml`` with an attribution header, and its picture to ``png``."""
    import yaml

    from fusion.mapping import read_reference_scans, render_map_png, segment_map_from_scans

    source, recorder = MAP_SOURCES[name]
    grid, segment_map = segment_map_from_scans(read_reference_scans(DATA / source), name=name)
    header = (f"# Segment map of the {name} building, built by `python -m benchmarks.bench_real "
              f"--build-maps`\n# (fusion.mapping, builder defaults) from the corrected log in "
              f"../shared/data (GMapping poses).\n# Data: Kümmerle et al. 2009 via the Radish "
              f"repository;\n# recorded by {recorder}.\n")
    body = yaml.safe_dump(segment_map.to_dict(), sort_keys=False, width=120)
    out_yaml.write_text(header + body)
    if png is not None:
        render_map_png(grid, segment_map, png)
    return segment_map


@dataclass
class Outcome:
    name: str
    scans: int
    seconds: float
    est: object  # Trajectory
    odom: object  # Trajectory, odometry poses at the scans (odometry frame)
    ref: object  # Trajectory
    stats: dict
    relations: object | None = None

    @property
    def scans_per_second(self) -> float:
        return self.scans / self.seconds if self.seconds > 0 else float("nan")


def run(ds: Dataset, limit: int | None = None, config: Path | None = None) -> Outcome:
    """Replay one dataset through the Localizer (no logger): estimates, odometry, reference."""
    from fusion.evaluation import Trajectory
    from fusion.events import Odometry, Scan
    from fusion.io import Relations, open_log, read_relations
    from fusion.localizer import Localizer
    from houghloc import SegmentMap

    segment_map = SegmentMap.from_yaml(ds.map)
    events, _ = open_log(ds.log)
    events = list(from_first_scan(events, limit))
    scans = [e for e in events if isinstance(e, Scan)] if ds.reference else None
    ref = reference_poses(ds.reference or ds.log, scans)
    first = next(e for e in events if isinstance(e, Scan))
    start = ds.initial_pose
    if start is None:
        start = first.reference if first.reference else tuple(ref.poses[0])
    loc = Localizer.from_config(config or ds.config, segment_map, start)
    t_out, poses, odom_t, odom = [], [], [], []
    last_odom = None
    t0 = time.perf_counter()
    for e in events:
        if isinstance(e, Odometry):
            loc.on_odometry(e.t, e.x, e.y, e.theta)
            last_odom = (e.x, e.y, e.theta)
        elif isinstance(e, Scan):
            est = loc.on_scan(e.t, e.ranges, e.angles, e.sensor, e.max_range)
            stamp = e.t if e.stamp is None else e.stamp
            t_out.append(stamp)
            poses.append(est.pose)
            if last_odom is not None:
                odom_t.append(stamp)
                odom.append(last_odom)
    seconds = time.perf_counter() - t0
    relations = None
    if ds.relations:  # the relations inside the replayed span: the same set for every method
        rel = read_relations(ds.relations, ds.time_offset)
        span = (min(t_out) - 0.02, max(t_out) + 0.02) if t_out else (0.0, -1.0)
        keep = ((rel.t1 >= span[0]) & (rel.t1 <= span[1]) & (rel.t2 >= span[0])
                & (rel.t2 <= span[1]))
        relations = Relations(rel.t1[keep], rel.t2[keep], rel.delta[keep])
    stats = dict(loc.stats.statuses)
    return Outcome(ds.name, len(t_out), seconds, Trajectory(np.asarray(t_out), np.asarray(poses)),
                   Trajectory(np.asarray(odom_t), np.asarray(odom).reshape(-1, 3)), ref, stats,
                   relations)


def score(outcome: Outcome, max_dt: float = 0.006) -> dict:
    """ATE and lost fraction (houghloc; odometry SE(2)-aligned), relation errors when known.

    ``max_dt``: reference stamps are printed with 6 significant digits (Intel: ~0.01 s late in the
    run, 1–5 ms in the .mat's span); scans can be 2 ms apart, so keep the tolerance tight."""
    from fusion.evaluation import ATE, Alignment, LostFraction, RelationError

    out: dict = {"dataset": outcome.name, "scans": outcome.scans,
                 "scans_per_second": outcome.scans_per_second, "statuses": outcome.stats}
    for key, traj, align in (("houghloc", outcome.est, Alignment.NONE),
                             ("odometry", outcome.odom, Alignment.SE2)):
        try:
            ate = ATE(alignment=align, max_dt=max_dt).compute(traj, outcome.ref)
        except ValueError as exc:  # a short slice may hold too few reference poses to align on
            out[key] = {"note": str(exc)}
            continue
        lost = LostFraction(max_dt=max_dt).from_ate(ate)
        out[key] = {"ate_rmse_m": ate.position["rmse"], "ate_max_m": ate.position["max"],
                    "heading_rmse_deg": ate.heading_deg["rmse"],
                    "matched": len(ate.position_errors), "lost": lost.fraction}
        if outcome.relations is not None:
            rel = RelationError(max_dt=0.02).compute(traj, outcome.relations).as_dict()
            out[key]["relations"] = rel
    if outcome.relations is not None:
        rel = RelationError(max_dt=0.02).compute(outcome.ref, outcome.relations).as_dict()
        out["reference"] = {"relations": rel}
    return out


def _fmt(v: float | None, unit: str = "m") -> str:
    if v is None or not math.isfinite(v):
        return "–"
    return f"{v * 100:.1f} cm" if unit == "m" and v < 1 else f"{v:.2f} {unit}"


def print_table(rows: list[dict]) -> None:
    head = (f"{'dataset':8s} {'method':10s} {'scans':>6s} {'ATE RMSE':>10s} {'ATE max':>10s} "
            f"{'lost':>7s} {'rel. trans':>11s} {'rel. rot (n)':>16s} {'scans/s':>8s} "
            f"{'× peer':>7s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        for method in ("houghloc", "odometry", "reference"):
            if method not in r:
                continue
            m = r[method]
            rel = m.get("relations", {})
            tr, rot = rel.get("translation_mean_m"), rel.get("rotation_mean_deg")
            rot = None if rot is None else math.radians(rot)
            label = {"odometry": "odom (SE2)", "reference": "GMapping"}.get(method, method)
            lost = f"{m['lost'] * 100:.1f}%" if math.isfinite(m.get("lost", math.nan)) else "–"
            rot_s = f"{rot:.3f} rad" if rot is not None and math.isfinite(rot) else "–"
            if rel:
                rot_s += f" ({rel.get('count')})"
            sps = f"{r['scans_per_second']:.0f}" if method == "houghloc" else ""
            peer = f"{r['x_peer']:.2f}" if method == "houghloc" and "x_peer" in r else ""
            scans = r["scans"] if method == "houghloc" else ""
            print(f"{r['dataset']:8s} {label:10s} {scans:>6} {_fmt(m.get('ate_rmse_m')):>10s} "
                  f"{_fmt(m.get('ate_max_m')):>10s} {lost:>7s} {_fmt(tr):>11s} {rot_s:>16s} "
                  f"{sps:>8s} {peer:>7s}")


def overridden_config(path: Path, overrides: list[str]):
    """The dataset's config with ``key.sub=value`` overrides (values parsed as YAML); the path
    itself when there are none. A malformed override or an invalid result is a ValueError."""
    if not overrides:
        return path
    import yaml

    from fusion.config import LocalizerConfig
    from houghloc.yaml_io import read_yaml

    raw = read_yaml(path, ValueError, "config") or {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set {item!r}: expected KEY=VALUE, e.g. "
                             "filter.gate_probability=0.999")
        node = raw
        *parents, leaf = key.split(".")
        for name in parents:
            node = node.setdefault(name, {})
            if not isinstance(node, dict):
                raise ValueError(f"--set {item!r}: {name!r} is not a group of settings")
        try:
            node[leaf] = yaml.safe_load(value)
        except yaml.YAMLError as error:
            raise ValueError(f"--set {item!r}: the value is not YAML ({error})") from None
    return LocalizerConfig.from_dict(raw, source=f"{path} with {' '.join(overrides)}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", choices=["intel", "fr079", "aces"], action="append")
    parser.add_argument("--scans", type=int, help="only the first N scans of each log")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a setting of each dataset's config, e.g. "
                        "ambiguity.local_search_xy=0.75 (dotted key, YAML value; repeatable)")
    parser.add_argument("--build-maps", action="store_true",
                        help="rebuild fusion/configs/maps/<name>.yaml and "
                        "docs/images/map-<name>.png")
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"bench_real: skipped — the real datasets are not in {DATA}")
        return 0
    if args.build_maps:
        for name in MAP_SOURCES:
            if not args.only or name in args.only:
                m = build_real_map(name, ROOT / f"fusion/configs/maps/{name}.yaml",
                                   ROOT / f"docs/images/map-{name}.png")
                print(f"{name}: {len(m)} segments on {m.n_lines} lines")
        return 0
    rows = []
    for ds in datasets():
        if args.only and ds.name not in args.only:
            continue
        missing = [p for p in (ds.log, ds.reference) if p is not None and not p.exists()]
        if missing:
            print(f"bench_real: {ds.name} skipped — missing {', '.join(map(str, missing))}")
            continue
        try:
            config = overridden_config(ds.config, args.set)
        except ValueError as error:
            print(f"bench_real: {error}", file=sys.stderr)
            return 2
        before = yardstick_seconds()
        outcome = run(ds, args.scans, config)
        peer = 0.5 * (before + yardstick_seconds())
        rows.append(score(outcome) | {"x_peer": outcome.seconds / max(outcome.scans, 1) / peer,
                                      "peer_ms": 1e3 * peer})
        print(f"{ds.name}: {outcome.scans} scans in {outcome.seconds:.1f} s, {outcome.stats}",
              file=sys.stderr)
    print_table(rows)
    if rows:
        peer_ms = float(np.mean([r["peer_ms"] for r in rows]))
        print(f"× peer: time per scan over OpenCV's HoughLinesPointSet of one 361-beam scan "
              f"({peer_ms:.2f} ms here), timed before and after each replay: it does not drift "
              f"with the machine's load as scans/s does. 500 scans/s is {2.0 / peer_ms:.2f}× peer.")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A run's data for the benchmark: the events to localize, the reference poses, and the scans
the maps are built from, cut into the pieces each protocol localizes.

Every method of a task is fed the same :class:`Piece`: the same events (from the first scan of
the piece on, with the odometry reading before it that anchors the odometry frame), the same
start pose and the same map source. What "covered" means is defined here once
(:func:`covered`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fusion.bench.spec import Protocol, RunSpec
from fusion.evaluation import Trajectory
from fusion.events import Event, Odometry, Scan
from fusion.io.timing import from_first_scan
from houghloc.geometry import ranges_to_points, transform_points

COVERED_DISTANCE = 0.10
"""m: a scan point explained by the map lies this close to a point the map was built from."""
COVERED_SHARE = 0.5
"""A pose is *covered* when at least this share of its scan's points, placed at the reference
pose, lie within :data:`COVERED_DISTANCE` of the map's source points: the map shows what the
scan sees. A held-out map misses rooms and furniture the other half never saw; lost poses there
say more about the map than the method."""
MAP_POINT_SPACING = 0.025
"""m: the map's source points are thinned to one per cell of this size (ICP's target, coverage)."""


def scan_stamp(scan: Scan) -> float:
    """The time a scan's outputs are written at (its record's own stamp when the reader had to
    reorder it)."""
    return scan.t if scan.stamp is None else scan.stamp


def reference_poses(path: Path, scans: list[Scan] | None = None) -> Trajectory:
    """The corrected poses a CARMEN log attaches to its scans (``Scan.reference``).

    With ``scans`` (the raw log's, when the reference comes from another file), each reference
    pose takes the stamp of the raw scan with the same ranges: reference logs print stamps with
    six significant digits (1–10 ms) while a raw log may deliver scans in bursts 1 ms apart,
    turning on the spot by degrees from one to the next."""
    from fusion.io import corrected_scans

    ref_scans = corrected_scans(path)
    times = np.array([e.t for e in ref_scans], dtype=float)
    if scans:
        times = _stamps_of_identical_scans(ref_scans, times, scans)
    arr = np.asarray([e.reference for e in ref_scans], dtype=float).reshape(-1, 3)
    order = np.argsort(times, kind="stable")
    return Trajectory(times[order], arr[order])


def _stamps_of_identical_scans(ref_scans: list[Scan], times: NDArray[np.float64],
                               scans: list[Scan], window: float = 0.02,
                               tolerance: float = 0.011) -> NDArray[np.float64]:
    """``times`` with each entry replaced by the stamp of the raw scan within ``window`` seconds
    whose ranges equal the reference scan's (to the printed precision, ``tolerance`` m); kept
    when there is no such scan."""
    raw_t = np.array([scan_stamp(s) for s in scans], dtype=float)
    order = np.argsort(raw_t, kind="stable")
    sorted_t = raw_t[order]
    out = times.copy()
    for k, ref in enumerate(ref_scans):
        lo, hi = np.searchsorted(sorted_t, (times[k] - window, times[k] + window))
        candidates = order[lo:hi]
        if len(candidates) == 0:
            continue
        r = np.asarray(ref.ranges, dtype=float)
        diff = [np.max(np.abs(np.asarray(scans[i].ranges, dtype=float) - r))
                if len(scans[i].ranges) == len(r) else np.inf for i in candidates]
        best = int(np.argmin(diff))
        if diff[best] <= tolerance:
            out[k] = raw_t[candidates[best]]
    return out


def _is_tum(path: Path) -> bool:
    return path.suffix.lower() in (".tum", ".txt")


def pose_near(traj: Trajectory, t: float, max_dt: float) -> NDArray[np.float64] | None:
    """The pose of ``traj`` nearest in time to ``t``, if within ``max_dt``."""
    if len(traj) == 0:
        return None
    k = int(np.argmin(np.abs(traj.t - t)))
    return traj.poses[k] if abs(traj.t[k] - t) <= max_dt else None


@dataclass(frozen=True)
class MapSource:
    """What every method's map is made of: scans at their reference poses (a map built from a
    corrected log), or a segment map given as it is."""

    scans: tuple[Scan, ...] = ()
    segment_map_path: Path | None = None
    name: str = "map"

    @cached_property
    def segment_map(self):
        """houghloc's map: the map builder's segments (its defaults), or the given map."""
        from fusion.mapping import segment_map_from_scans
        from houghloc import SegmentMap

        if self.segment_map_path is not None:
            return SegmentMap.from_yaml(self.segment_map_path)
        return segment_map_from_scans(list(self.scans), name=self.name)[1]

    @cached_property
    def grid(self):
        """AMCL's map: the occupancy grid of the scans (5 cm), or the segments rasterised with
        the rest of their bounding box free."""
        from fusion.mapping import OccupancyGrid, occupancy_from_scans

        if self.segment_map_path is None:
            return occupancy_from_scans(list(self.scans))
        resolution = 0.05
        pts = self.points
        origin = pts.min(axis=0) - 1.0
        shape = np.ceil((pts.max(axis=0) + 1.0 - origin) / resolution).astype(int)[::-1]
        occupied = np.zeros(shape, dtype=bool)
        cols, rows = np.floor((pts - origin) / resolution).astype(int).T
        occupied[rows, cols] = True
        return OccupancyGrid.from_masks(occupied, ~occupied, resolution, tuple(origin))

    @cached_property
    def points(self) -> NDArray[np.float64]:
        """The map as points (ICP's target, and what coverage is measured against): the scans'
        endpoints, or points every 1 cm along the segments; one per 2.5 cm cell."""
        if self.segment_map_path is None:
            from fusion.mapping import scan_endpoints

            pts = scan_endpoints(self.scans)
        else:
            m = self.segment_map
            chunks = []
            for a, b in zip(m.starts, m.ends, strict=True):
                n = max(2, int(np.ceil(np.linalg.norm(b - a) / 0.01)) + 1)
                chunks.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
            pts = np.concatenate(chunks) if chunks else np.empty((0, 2))
        return thin(pts, MAP_POINT_SPACING)


def thin(points: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """One point (the first) per square cell of side ``cell``."""
    if len(points) == 0:
        return points
    keys = np.floor(points / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


@dataclass(frozen=True)
class Piece:
    """One stretch of a log localized from ``start`` (None: global start) in ``map_source``."""

    events: tuple[Event, ...]
    start: NDArray[np.float64] | None
    map_source: MapSource

    @property
    def scans(self) -> list[Scan]:
        return [e for e in self.events if isinstance(e, Scan)]


@dataclass(frozen=True)
class RunData:
    """A run's events, reference and map-building scans, read once per task."""

    spec: RunSpec
    events: tuple[Event, ...]
    reference: Trajectory
    build_scans: tuple[Scan, ...]
    max_dt: float

    @classmethod
    def load(cls, spec: RunSpec, max_dt: float) -> RunData:
        from fusion.io import open_log

        if spec.log is None:  # a scenario run not yet simulated (fusion.bench.generated)
            raise ValueError(f"run {spec.name}: no log to read")
        log = spec.log
        events, _ = open_log(log)
        kept = tuple(from_first_scan(events, spec.max_scans))
        scans = [e for e in kept if isinstance(e, Scan)]
        if not scans:
            raise ValueError(f"{spec.log}: no scan to localize")
        reference = cls._reference(spec, scans)
        build_scans: tuple[Scan, ...] = ()
        if spec.build_from is not None:
            build_scans = tuple(_placed_scans(spec.build_from, reference, log, scans, max_dt))
        return cls(spec, kept, reference, build_scans, max_dt)

    @staticmethod
    def _reference(spec: RunSpec, scans: list[Scan]) -> Trajectory:
        if spec.reference is None:
            have = [s for s in scans if s.reference is not None]
            if not have:
                raise ValueError(f"{spec.log}: no reference poses (not a corrected log); give "
                                 "`reference`")
            return Trajectory(np.array([scan_stamp(s) for s in have]),
                              np.array([s.reference for s in have]))
        if _is_tum(spec.reference):
            return Trajectory.from_tum(spec.reference)
        same = spec.log is not None and spec.reference.resolve() == spec.log.resolve()
        return reference_poses(spec.reference, None if same else scans)

    def pieces(self, protocol: Protocol) -> list[Piece]:
        """What the protocol localizes: the whole run in the same-run map (from its start pose,
        or from none for a global start), or — held out — the run in a map of the scans outside
        its span (Intel: the corrected scans after the raw log ends), else each half of the run
        (by time) in the map of the other half."""
        whole = self._map(self.build_scans)
        if protocol is Protocol.SAME_RUN:
            return [Piece(self.events, self._start(self.events, first=True), whole)]
        if protocol is Protocol.GLOBAL_START:
            return [Piece(self.events, None, whole)]
        if self.spec.build_from is None:
            raise ValueError("held-out-map needs build_from (a corrected log to build maps "
                             "from), not a given map")
        stamps = np.array([scan_stamp(s) for s in self.build_scans])
        times = [scan_stamp(e) for e in self.events if isinstance(e, Scan)]
        t0, t1 = min(times), max(times)
        outside = [s for s, t in zip(self.build_scans, stamps, strict=True) if t < t0 or t > t1]
        if len(outside) >= 0.25 * len(self.build_scans):
            return [Piece(self.events, self._start(self.events, first=True),
                          self._map(tuple(outside)))]
        middle = 0.5 * (t0 + t1)
        first, second = _split(self.events, middle)
        later = tuple(s for s, t in zip(self.build_scans, stamps, strict=True) if t >= middle)
        earlier = tuple(s for s, t in zip(self.build_scans, stamps, strict=True) if t < middle)
        return [Piece(first, self._start(first, first=True), self._map(later)),
                Piece(second, self._start(second, first=False), self._map(earlier))]

    def _map(self, scans: tuple[Scan, ...]) -> MapSource:
        if self.spec.map is not None:
            return MapSource(segment_map_path=self.spec.map, name=self.spec.name)
        if not scans:
            raise ValueError(f"{self.spec.build_from}: no scan to build the map from")
        return MapSource(scans=scans, name=self.spec.name)

    def _start(self, events: tuple[Event, ...], first: bool) -> NDArray[np.float64]:
        if first and self.spec.initial_pose is not None:
            return np.asarray(self.spec.initial_pose, dtype=float)
        scan = next(e for e in events if isinstance(e, Scan))
        pose = pose_near(self.reference, scan_stamp(scan), max(self.max_dt, 0.05))
        if pose is None:
            raise ValueError(f"{self.spec.log}: no reference pose at the first scan "
                             f"(t = {scan_stamp(scan):.3f} s); give initial_pose")
        return pose


def _split(events: tuple[Event, ...], middle: float) -> tuple[tuple[Event, ...], ...]:
    """The events before ``middle`` and those from the first scan at or after it on (with the
    odometry reading that anchors them)."""
    cut = next(i for i, e in enumerate(events)
               if isinstance(e, Scan) and scan_stamp(e) >= middle)
    anchor = next((i for i in range(cut - 1, -1, -1) if isinstance(events[i], Odometry)), cut)
    return events[:cut], tuple(from_first_scan(events[anchor:]))


def _placed_scans(path: Path, reference: Trajectory, log: Path, log_scans: list[Scan],
                  max_dt: float) -> Iterator[Scan]:
    """The scans of ``path`` with a map-frame pose: their own reference (a corrected log), or
    the run's reference at their time."""
    from fusion.io import open_log

    if path.resolve() == log.resolve():
        source: Iterable[Event] = log_scans
    else:
        source, _ = open_log(path)
    for e in source:
        if not isinstance(e, Scan):
            continue
        if e.reference is not None:
            yield e
            continue
        pose = pose_near(reference, scan_stamp(e), max_dt)
        if pose is not None:
            yield dataclasses.replace(e, reference=tuple(pose.tolist()))


def covered(scans: list[Scan], poses: NDArray[np.float64], map_points: NDArray[np.float64],
            max_range: float = 30.0) -> NDArray[np.bool_]:
    """Whether the map covers each scan placed at its reference pose (:data:`COVERED_SHARE`)."""
    out = np.zeros(len(scans), dtype=bool)
    if len(map_points) == 0:
        return out
    tree = cKDTree(map_points)
    for k, (scan, pose) in enumerate(zip(scans, poses, strict=True)):
        pts = ranges_to_points(scan.ranges, scan.angles, min(max_range, scan.max_range))
        if len(pts):
            dist, _ = tree.query(transform_points(pose, pts),
                                 distance_upper_bound=COVERED_DISTANCE)
            out[k] = np.mean(dist <= COVERED_DISTANCE) >= COVERED_SHARE
    return out

"""The 2D laser: vectorised ray casting (beams × segments, beams × discs), first hit wins.

Seen: walls (label = the map segment's index ≥ 0), clutter (−3), moving obstacles (−2). Painted
lines are invisible. A beam that hits nothing within ``max_range`` reports ``max_range`` (−1);
so does a dropped beam; a spurious short return is labelled −4. The noise model is in
:class:`fusion.sim.config.LaserConfig`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.sim.config import LaserConfig
from fusion.sim.raycast import ray_disc_distances
from houghloc.geometry import Pose, compose, ray_segment_distances
from houghloc.segment_map import SegmentMap

FloatArray = NDArray[np.float64]

NO_RETURN = -1
MOVING_OBSTACLE = -2
CLUTTER = -3
SPURIOUS = -4

_NEAR_QUERY_MIN_SEGMENTS = 64  # below this, testing every wall is cheaper than the index query


@dataclass(frozen=True)
class LaserScan:
    """One scan: ``ranges[i]`` along ``angles[i]`` (robot frame) and what each beam hit."""

    ranges: FloatArray
    angles: FloatArray
    labels: NDArray[np.int16]


def beam_angles(cfg: LaserConfig) -> FloatArray:
    """Beam directions in the robot frame: −fov/2 … +fov/2 evenly (the FLASER layout)."""
    half = 0.5 * np.radians(cfg.fov_deg)
    return np.linspace(-half, half, cfg.n_beams)


def visible_walls(m: SegmentMap, xy: ArrayLike, max_range: float) -> NDArray[np.intp]:
    """Indices of the walls that can be within ``max_range`` of ``xy``."""
    if len(m) < _NEAR_QUERY_MIN_SEGMENTS:
        return np.flatnonzero(m.is_wall)
    near = m.segments_near(xy, max_range)
    return near[m.is_wall[near]]


@dataclass(frozen=True)
class Occluders:
    """Every segment a laser sees — walls (label = map index) and clutter (−3) — stacked once so
    each scan makes one ray-casting call."""

    starts: FloatArray
    ends: FloatArray
    labels: NDArray[np.int16]
    map_size: int  # segments of the map; above _NEAR_QUERY_MIN_SEGMENTS query the index per scan

    @classmethod
    def build(cls, m: SegmentMap, clutter: FloatArray | None = None,
              transparent: Sequence[str] = ()) -> Occluders:
        """Walls and clutter; the walls named in ``transparent`` (glass) are left out."""
        c = np.empty((0, 4)) if clutter is None else np.asarray(clutter, float).reshape(-1, 4)
        seen = m.is_wall & ~np.isin(np.asarray(m.ids, dtype=object), list(transparent))
        walls = np.flatnonzero(seen)
        return cls(
            starts=np.vstack((m.starts[walls], c[:, :2])),
            ends=np.vstack((m.ends[walls], c[:, 2:])),
            labels=np.concatenate((walls, np.full(len(c), CLUTTER))).astype(np.int16),
            map_size=len(m),
        )

    def near(self, m: SegmentMap, origin: FloatArray, max_range: float) -> Occluders:
        """The subset that can be within ``max_range`` (index query on large maps only)."""
        if self.map_size < _NEAR_QUERY_MIN_SEGMENTS:
            return self
        near = m.segments_near(origin, max_range)
        keep = np.isin(self.labels, near[m.is_wall[near]]) | (self.labels == CLUTTER)
        return Occluders(self.starts[keep], self.ends[keep], self.labels[keep], self.map_size)


def true_ranges(m: SegmentMap, pose: Pose, angles: FloatArray, max_range: float,
                discs: FloatArray | None = None, clutter: FloatArray | None = None,
                occluders: Occluders | None = None) -> tuple[FloatArray, NDArray[np.int16]]:
    """Noise-free first-hit distances and labels of the beams (``inf``/−1 beyond ``max_range``).

    ``occluders`` (walls + clutter, from :meth:`Occluders.build`) replaces ``clutter`` when a
    caller casts many scans in one world.
    """
    x, y, th = (float(v) for v in pose)
    origin = np.array([x, y])
    occ = (occluders or Occluders.build(m, clutter)).near(m, origin, max_range)
    starts, ends, labels = occ.starts, occ.ends, occ.labels
    # Cull segments that no beam can reach: both ends behind the sensor (for a field of view of
    # at most 180°) or the whole segment beyond max_range. Halves the work of a forward scanner.
    if len(starts) and np.ptp(angles) <= np.pi + 1e-9:
        mid = 0.5 * (angles.max() + angles.min()) + th
        h = np.array([np.cos(mid), np.sin(mid)])
        ahead = ((starts - origin) @ h > -1e-9) | ((ends - origin) @ h > -1e-9)
        starts, ends, labels = starts[ahead], ends[ahead], labels[ahead]
    phi = th + angles
    dirs = np.column_stack((np.cos(phi), np.sin(phi)))
    t = ray_segment_distances(origin, dirs, starts, ends)
    if discs is not None and len(discs):
        d = np.asarray(discs, dtype=float).reshape(-1, 3)
        t = np.hstack((t, ray_disc_distances(origin, dirs, d)))
        labels = np.concatenate((labels, np.full(len(d), MOVING_OBSTACLE, dtype=np.int16)))
    if t.shape[1] == 0:
        return np.full(len(angles), np.inf), np.full(len(angles), NO_RETURN, dtype=np.int16)
    first = np.argmin(t, axis=1)
    r = t[np.arange(len(angles)), first]
    hit = r <= max_range
    return np.where(hit, r, np.inf), np.where(hit, labels[first], NO_RETURN).astype(np.int16)


def corrupt_ranges(r_true: FloatArray, labels: NDArray[np.int16], cfg: LaserConfig,
                   rng: np.random.Generator) -> tuple[FloatArray, NDArray[np.int16]]:
    """Apply the sensor model: Gaussian noise, dropouts, spurious short returns, max-range clip."""
    n = len(r_true)
    r = r_true + cfg.sigma * rng.standard_normal(n)
    labels = labels.copy()
    u = rng.random((2, n))
    spurious = u[1] < cfg.spurious_prob
    upper = np.where(np.isfinite(r_true), r_true, cfg.max_range)
    short = cfg.min_range + rng.random(n) * np.maximum(upper - cfg.min_range, 0.0)
    r = np.where(spurious, short, r)
    labels[spurious] = SPURIOUS
    dropped = (u[0] < cfg.dropout_prob) & ~spurious
    no_return = dropped | ~np.isfinite(r) | (r >= cfg.max_range)
    r = np.where(no_return, cfg.max_range, np.maximum(r, cfg.min_range))
    labels[no_return] = NO_RETURN
    return r, labels


def laser_scan(m: SegmentMap, pose: Pose, rng: np.random.Generator,
               cfg: LaserConfig | None = None, obstacles: FloatArray | None = None,
               clutter: FloatArray | None = None) -> LaserScan:
    """Simulate one scan from ``pose`` (map frame).

    ``obstacles``: discs (D×3 rows ``[x, y, r]``); ``clutter``: unmapped segments (M×4 rows
    ``[x0, y0, x1, y1]``). Labels: map segment index ≥ 0, −1 no return, −2 moving obstacle,
    −3 clutter, −4 spurious.
    """
    cfg = cfg or LaserConfig()
    angles = beam_angles(cfg)
    r_true, labels = true_ranges(m, pose, angles, cfg.max_range, obstacles, clutter)
    ranges, labels = corrupt_ranges(r_true, labels, cfg, rng)
    return LaserScan(ranges, angles, labels)


@dataclass(frozen=True)
class LaserRecording:
    """A run's scans, cast on demand in time order, so a long run never holds them all.

    Scan k is cast from ``truth[k]`` among ``discs[k]``; the sensor noise comes from one
    generator seeded by ``seed`` and consumed scan after scan, so every pass over the
    recording yields the same scans, whatever the block size.
    """

    map: SegmentMap
    cfg: LaserConfig
    angles: FloatArray
    occluders: Occluders
    truth: FloatArray  # K×3, map frame
    discs: FloatArray  # K×D×3
    seed: np.random.SeedSequence

    def __len__(self) -> int:
        return len(self.truth)

    def blocks(self, size: int = 512) -> Iterator[tuple[int, FloatArray, NDArray[np.int16]]]:
        """``(k0, ranges, labels)`` for scans ``k0 … k0 + len(ranges) − 1``, in order."""
        rng = np.random.default_rng(self.seed)
        for k0 in range(0, len(self), size):
            k1 = min(k0 + size, len(self))
            ranges = np.empty((k1 - k0, len(self.angles)))
            labels = np.empty((k1 - k0, len(self.angles)), dtype=np.int16)
            for i, k in enumerate(range(k0, k1)):
                r, lab = true_ranges(self.map, self.truth[k], self.angles, self.cfg.max_range,
                                     self.discs[k], occluders=self.occluders)
                ranges[i], labels[i] = corrupt_ranges(r, lab, self.cfg, rng)
            yield k0, ranges, labels

    def mounted(self, mount: ArrayLike) -> LaserRecording:
        """The same recording from a laser mounted at ``mount`` (x, y, θ on the robot's base):
        each scan cast from the laser's own true pose, robot ⊕ mount."""
        return replace(self, truth=compose(self.truth, mount))

    def scans(self) -> Iterator[tuple[FloatArray, NDArray[np.int16]]]:
        """``(ranges, labels)`` of each scan in order."""
        for _, ranges, labels in self.blocks():
            yield from zip(ranges, labels, strict=True)

    def all(self) -> tuple[FloatArray, NDArray[np.int16]]:
        """Every scan at once: K×B ranges and labels (for short runs and tests)."""
        parts = list(self.blocks())
        if not parts:
            return (np.empty((0, len(self.angles))),
                    np.empty((0, len(self.angles)), dtype=np.int16))
        return (np.concatenate([r for _, r, _ in parts]),
                np.concatenate([lab for _, _, lab in parts]))

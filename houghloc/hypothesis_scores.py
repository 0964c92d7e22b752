"""Steps 3 to 5 of global set matching (:mod:`houghloc.global_match`): a hypothesis scored by
its lines' samples, then by all its points, on the map's distance transform; near-identical
poses clustered; the survivors refined on their matched lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from houghloc.displacement import Displacement, match_and_solve
from houghloc.geometry import TWO_PI, bearing_span, mod_two_pi, within_radius, wrap_angle
from houghloc.jit import njit
from houghloc.map_lookup import WallDistance
from houghloc.matching import Matches
from houghloc.pose_hypotheses import row_chunks
from houghloc.refine import Lines
from houghloc.segment_map import References, SegmentMap

if TYPE_CHECKING:
    from houghloc.config import GlobalMatchConfig

END_GRAZE = 1e-3  # m; a ray this close to a wall's end along it passes the wall (seen_directly)


@dataclass(frozen=True)
class Hypothesis:
    """One candidate pose of ``base`` in ``map``.

    ``cov`` is the covariance of the refined pose from its matched lines alone. ``score`` ∈ [0, 1]
    (see the module docstring); ``n_lines_explained`` counts the observed lines lying on walls;
    ``inlier_fraction`` is the fraction of points within ``inlier_distance`` of a wall;
    ``matches`` is an M×2 array of (observed line index, map line index) used by the refinement.
    """

    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    score: float
    n_lines_explained: int
    inlier_fraction: float
    matches: NDArray[np.intp]
    slid: bool = False  # found by sliding along parallel lines: its position along them rests


def cheap_scores(poses: NDArray, lines: Lines, walls: WallDistance,
                 config: GlobalMatchConfig) -> NDArray[np.float64]:
    """Point-count-weighted fraction of the ``cheap_lines`` strongest observed lines that lie on
    walls (:func:`lines_on_walls`) at each pose (H,)."""
    lines = lines.subset(np.argsort(-lines.n, kind="stable")[: config.cheap_lines])
    weight = lines.n / lines.n.sum()
    return lines_on_walls(poses, lines, walls, config) @ weight


def lines_on_walls(poses: NDArray, lines: Lines, walls: WallDistance,
                   config: GlobalMatchConfig) -> NDArray[np.bool_]:
    """Which observed lines lie on walls at each pose (H×K).

    Line k is sampled at S = ``line_samples`` evenly spaced points ρ n_k + s t_k, s ∈ [s0, s1];
    it lies on walls when ≥ ``min_line_coverage`` of its samples are within
    ``inlier_distance`` of one.
    """
    u = np.linspace(0.0, 1.0, config.line_samples)
    s = lines.s0[:, None] + u[None, :] * (lines.s1 - lines.s0)[:, None]  # K×S
    c, sn = np.cos(lines.theta)[:, None], np.sin(lines.theta)[:, None]
    px = (lines.rho[:, None] * c - s * sn).astype(np.float32)
    py = (lines.rho[:, None] * sn + s * c).astype(np.float32)
    return walls.rows_on_walls(poses, px, py, config.inlier_distance, config.min_line_coverage)


@dataclass(frozen=True)
class PointScores:
    score: NDArray[np.float64]
    inlier_fraction: NDArray[np.float64]
    n_explained: NDArray[np.intp]
    explained: NDArray[np.bool_]  # H×K


def point_scores(poses: NDArray, points: NDArray, members: NDArray[np.bool_],
                 walls: WallDistance, config: GlobalMatchConfig,
                 visible: NDArray[np.bool_] | None = None) -> PointScores:
    """Score every pose with all (subsampled) points, in chunks of hypotheses × points.

    inlier_fraction = mean over points of [d(point) ≤ inlier_distance]; line k is explained when
    the fraction of its member points on walls reaches ``min_line_coverage``;
    score = w · Σ_k n_k [explained_k] / Σ_k n_k + (1 − w) · inlier_fraction.
    ``visible`` (H×N), when given, removes the points seen through a wall from the inliers.
    """
    m = members.astype(np.float32)
    n_k = m.sum(axis=0)
    weight = n_k / max(float(n_k.sum()), 1.0)
    inliers = np.empty(len(poses))
    explained = np.empty((len(poses), members.shape[1]), dtype=bool)
    for sl in row_chunks(len(poses), len(points)):
        on_wall = walls.at(poses[sl], points[:, 0], points[:, 1]) <= config.inlier_distance
        if visible is not None:
            on_wall &= visible[sl]
        on_wall = on_wall.astype(np.float32)
        inliers[sl] = on_wall.mean(axis=1)
        covered = (on_wall @ m) / np.maximum(n_k, 1.0)
        explained[sl] = (covered >= config.min_line_coverage) & (n_k > 0)
    w = config.line_weight
    # float32 × float32 goes to BLAS; bool × float32 took NumPy's own buffered loop, which
    # now and then raised a spurious 'invalid value' flag (the products are 0/1 × finite)
    score = w * (explained.astype(np.float32) @ weight) + (1.0 - w) * inliers
    return PointScores(score, inliers, explained.sum(axis=1), explained)


# ---------------------------------------------------------------------------- 5. clusters
def cluster(poses: NDArray, scores: NDArray, config: GlobalMatchConfig) -> list[int]:
    """Greedy non-maximum suppression in pose space: the best pose absorbs every pose within
    ``cluster_xy`` and ``cluster_theta`` of it. Returns the kept indices, best first."""
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    return _cluster_kernel(np.ascontiguousarray(poses, dtype=float).reshape(-1, 3), order,
                           config.cluster_xy, config.cluster_theta).tolist()


@njit
def _cluster_kernel(poses: NDArray, order: NDArray, radius_xy: float, radius_theta: float
                    ) -> NDArray[np.intp]:
    """:func:`cluster` on poses already ranked (``order``): each pose still free takes, with
    itself, the free poses within ``radius_xy`` (hypot of the differences) and ``radius_theta``
    (the difference wrapped to [−π, π), as :func:`houghloc.geometry.wrap_angle` does)."""
    n = len(poses)
    free = np.ones(n, np.bool_)
    kept = np.empty(len(order), np.intp)
    count, left = 0, n
    for j in order:
        if not free[j]:
            continue
        kept[count] = j
        count += 1
        for i in range(n):
            if (free[i] and within_radius(poses[i, 0] - poses[j, 0], poses[i, 1] - poses[j, 1],
                                          radius_xy)
                    and abs(mod_two_pi(poses[i, 2] - poses[j, 2] + np.pi) - np.pi)
                    <= radius_theta):
                free[i] = False
                left -= 1
        if left == 0:
            break
    return kept[:count]


def refine_hypothesis(pose: NDArray, lines: Lines, max_range: float, pts_s: NDArray,
                      members_s: NDArray, map: SegmentMap, walls: WallDistance,
                      kinds: tuple[str, ...], config: GlobalMatchConfig) -> Hypothesis | None:
    """Weighted least squares on the lines matched at a hypothesis (docs/method.md §5), then
    rescored.

    The hypothesis is treated as a guess with a tight prior (``refine_sigma_*``): the Hough-domain
    gates of :func:`houghloc.matching.associate` then only admit the lines that this pose explains.
    """
    pose = np.array([pose[0], pose[1], float(wrap_angle(pose[2]))])
    # refine_iterations corrections, then one more (cheap) solve at the last linearisation
    # point, to which the covariance belongs
    for step in range(config.refine_iterations + 1):
        found = matched_at(pose, lines, map, kinds, max_range, config)
        if found is None or found[2].rank < 3:
            return None
        refs, matches, disp = found
        if step < config.refine_iterations:
            pose = pose + disp.delta
            pose[2] = float(wrap_angle(pose[2]))
    return scored_hypothesis(pose, disp.cov, refs, matches, pts_s, members_s, map, walls, kinds,
                             max_range, config)


def matched_at(pose: NDArray, lines: Lines, map: SegmentMap, kinds: tuple[str, ...],
                max_range: float, config: GlobalMatchConfig
                ) -> tuple[References, Matches, Displacement] | None:
    """The lines matched at a hypothesis treated as a guess with the tight prior
    ``refine_sigma_*``, and the displacement they give; None when none matches."""
    hc = config.hough
    prior = np.diag([config.refine_sigma_xy**2] * 2 + [config.refine_sigma_theta**2])
    refs = map.references(pose, max_range, kinds, hc.visibility_rays)
    matches, displacement = match_and_solve(lines, refs, pose, prior, hc)
    if len(matches) == 0:
        return None
    return refs, matches, displacement


def scored_hypothesis(pose: NDArray, cov: NDArray, refs: References, matches: Matches,
                      pts_s: NDArray, members_s: NDArray, map: SegmentMap, walls: WallDistance,
                      kinds: tuple[str, ...], max_range: float, config: GlobalMatchConfig,
                      slid: bool = False) -> Hypothesis:
    """A refined pose as a hypothesis: its score on the sampled points, and the line pairs."""
    visible = (seen_directly(pose, pts_s, map, kinds, max_range, config.visibility_margin)[None]
               if config.check_visibility else None)
    s = point_scores(pose[None, :], pts_s, members_s, walls, config, visible)
    pairs = np.column_stack((matches.line, refs.line[matches.ref])).astype(np.intp)
    return Hypothesis(pose, cov, float(s.score[0]), int(s.n_explained[0]),
                      float(s.inlier_fraction[0]), pairs, slid=slid)


def seen_directly(pose: NDArray, points: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                  max_range: float, margin: float,
                  transparent: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
    """Which robot-frame points the map lets the robot see from ``pose`` (N,).

    The ray o + t (q − o), t ∈ (0, 1], from the robot o to the point q in the world crosses wall
    segment p + u e, u ∈ [0, 1], where (Cramer's rule on o + t d = p + u e, d = q − o)
        t = (w × e) / (d × e),   u = (w × d) / (d × e),   w = p − o.
    A crossing more than ``margin`` before the point means the point was seen through that wall.
    A ray through a wall's very end (within ``END_GRAZE`` of it along the wall) passes it: a
    beam at a door frame or an outside corner cannot tell the two sides apart, and a simulated
    one passes them. Only walls occlude; painted lines do not, nor the segments marked
    ``transparent`` (per segment of the map: walls the laser has been seen to pass).
    """
    return _crossed_walls(pose, points, map, kinds, max_range, margin, transparent,
                          nearest=False) < 0


def walls_seen_through(pose: NDArray, points: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                       max_range: float, margin: float,
                       transparent: NDArray[np.bool_] | None = None) -> NDArray[np.intp]:
    """For each robot-frame point, the map segment (its index) that the ray from ``pose`` to it
    crosses first, more than ``margin`` before it (:func:`seen_directly`, which it agrees
    with); −1 where it crosses none."""
    return _crossed_walls(pose, points, map, kinds, max_range, margin, transparent,
                          nearest=True)


def _crossed_walls(pose: NDArray, points: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                   max_range: float, margin: float, transparent: NDArray[np.bool_] | None,
                   nearest: bool) -> NDArray[np.intp]:
    near = map.segments_near(pose[:2], max_range)
    keep = map.kind_mask(kinds)[near] & map.is_wall[near]
    if transparent is not None:
        keep &= ~transparent[near]
    near = near[keep]
    if len(near) == 0 or len(points) == 0:
        return np.full(len(points), -1, dtype=np.intp)
    heading = np.array([pose[2]])  # NumPy's cos and sin, as every other placement of points
    crossed = _crossing(float(pose[0]), float(pose[1]), float(np.cos(heading)[0]),
                        float(np.sin(heading)[0]), np.ascontiguousarray(points, dtype=float),
                        map.starts[near], map.ends[near], margin, nearest)
    return np.where(crossed >= 0, near[np.maximum(crossed, 0)], -1)


@njit
def _crossing(ox: float, oy: float, c: float, s: float, points: NDArray, starts: NDArray,
              ends: NDArray, margin: float, nearest: bool) -> NDArray[np.intp]:
    """:func:`_crossed_walls` for the robot at (ox, oy) heading (c, s) = (cos θ, sin θ): the
    index into ``starts`` of a wall each point's ray crosses (the nearest one when ``nearest``,
    else the first tried), −1 for none.

    A ray crosses a wall's interior only at a bearing the wall spans from the robot, so each
    point tries only the walls listed for its bearing's bin (:func:`_walls_by_bearing`): the
    same answer as trying every wall."""
    crossed = np.full(len(points), -1, np.intp)
    # the fraction of each wall's length that is END_GRAZE: u must lie beyond it from both ends
    graze = np.empty(len(starts))
    for j in range(len(starts)):
        graze[j] = END_GRAZE / max(math.hypot(ends[j, 0] - starts[j, 0],
                                              ends[j, 1] - starts[j, 1]), END_GRAZE)
    first, walls = _walls_by_bearing(ox, oy, starts, ends)
    for i in range(len(points)):
        dx = ox + c * points[i, 0] - s * points[i, 1] - ox  # d = q − o, q in the world
        dy = oy + s * points[i, 0] + c * points[i, 1] - oy
        if not (math.isfinite(dx) and math.isfinite(dy)):
            continue  # no crossing can be computed: every test below fails on NaN
        t_max = 1.0 - margin / max(math.hypot(dx, dy), 1e-9)  # in units of the point's range
        b = math.floor(math.atan2(dy, dx) / BEARING_STEP) % BEARING_BINS
        closest = t_max
        for q in range(first[b], first[b + 1]):
            j = walls[q]
            wx, wy = starts[j, 0] - ox, starts[j, 1] - oy
            ex, ey = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1]
            den = dx * ey - dy * ex
            if abs(den) <= 1e-12:
                continue
            t = (wx * ey - wy * ex) / den
            u = (wx * dy - wy * dx) / den
            if t > 1e-6 and t < closest and u > graze[j] and u < 1.0 - graze[j]:
                crossed[i] = j
                if not nearest:
                    break
                closest = t
    return crossed


BEARING_BINS = 360
BEARING_STEP = TWO_PI / BEARING_BINS


@njit
def _walls_by_bearing(ox: float, oy: float, starts: NDArray, ends: NDArray
                      ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The walls spanning each of ``BEARING_BINS`` bins of bearing from (ox, oy), as ranges
    ``first[b]:first[b + 1]`` of ``walls``. A wall spans the bins between its ends' bearings
    (the shorter way round), one bin wider on each side for rounding; a wall the origin lies on
    or beside, every bin."""
    n = BEARING_BINS
    lo = np.empty(len(starts), np.intp)
    count = np.empty(len(starts), np.intp)
    for j in range(len(starts)):
        lo[j], count[j] = bearing_span(starts[j, 0] - ox, starts[j, 1] - oy, ends[j, 0] - ox,
                                       ends[j, 1] - oy, BEARING_STEP, n)
    first = np.zeros(n + 1, np.intp)
    for j in range(len(starts)):
        for q in range(count[j]):
            first[(lo[j] + q) % n + 1] += 1
    for b in range(n):
        first[b + 1] += first[b]
    fill = first[:-1].copy()
    walls = np.empty(first[n], np.intp)
    for j in range(len(starts)):
        for q in range(count[j]):
            b = (lo[j] + q) % n
            walls[fill[b]] = j
            fill[b] += 1
    return first, walls

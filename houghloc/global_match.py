"""Global set matching, the paper's strategy (ii) (DESIGN §3.6).

When tracking cannot be trusted, the points of several views are accumulated into one robot-centred
frame, their lines are extracted, and the **set** of observed lines is matched against the **set**
of map lines without any pose guess:

1. *Hypotheses from pairs.* Two observed lines i, k that are not parallel (angle ≥
   ``min_pair_angle_deg``) and two oriented map lines a, b with the same angle between them fix the
   pose. With β the world normal pointing from the robot to a line and r_β its signed distance
   (a canonical map line (α, r) gives the two orientations (α, r) and (α + π, −r)):
       θ = β_a − θ_i  (≈ β_b − θ_k; the mean is used),
       x cos β_a + y sin β_a = r_a − ρ_i,   x cos β_b + y sin β_b = r_b − ρ_k   (2×2 solve).
   Map pairs are kept in an *angle index* sorted by δ = β_b − β_a (mod 2π), so the candidates of an
   observed pair are one ``searchsorted`` range, not a scan of all map pairs.
2. *Pose-space votes.* Hypotheses outside the map's bounding box are dropped; the rest are binned
   in (x, y, θ): correct correspondences agree on one pose, wrong ones scatter, so the count per
   cell (the number of line pairs that support it) ranks the cells.
3. *Cheap score.* For the best-voted cells, a few samples along each of the strongest observed
   lines are placed in the world and looked up in a distance-transform grid of the map's walls
   (O(1) per sample): the weighted fraction of lines lying on real walls (lines are infinite,
   segments are not).
4. *Full score* of the top ``max_hypotheses_scored``: all points (subsampled) are looked up,
       score = w · (point-weighted fraction of lines explained) + (1 − w) · (fraction of points
       within ``inlier_distance`` of a wall),
   a line being explained when ≥ ``min_line_coverage`` of its points lie on walls.
5. *Clusters and refinement.* Near-identical poses are merged (best first); each surviving cluster
   is refined by weighted least squares on its matched lines (:func:`houghloc.matching.associate`
   and :func:`houghloc.displacement.estimate_displacement` with a tight prior around the
   hypothesis), which gives an honest covariance, and is scored again.

6. *Sliding*, only when the pairs give no hypothesis (all lines in view parallel: a corridor seen
   along its length): the strongest line is put on each map line and the view slid along it; the
   points on walls (door gaps, what shows through them) fix the position along (``slide_*``).

A symmetric map leaves several hypotheses within ``tie_margin`` of the best: all are reported and
the result is flagged ``ambiguous`` — the caller keeps collecting views, it never picks one.

Cost: with K observed lines (P ≤ ``max_observed_pairs`` pairs), L map lines and H hypotheses, the
index is built once per map in O(L² log L); generation is O(P log L² + H); the votes O(H log H);
the cheap score O(C·K·S) for C ≤ ``max_cells_cheap`` cells and S samples per line; the full score
O(M·N) for M ≤ ``max_hypotheses_scored`` and N ≤ ``max_score_points``. Only generation and votes
grow with the map: H ∝ the number of map pairs at each observed angle, until it reaches
``max_pair_hypotheses``; beyond that only the best-conditioned observed pairs are expanded.
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from houghloc.config import HoughConfig
from houghloc.displacement import Displacement, estimate_displacement
from houghloc.geometry import TWO_PI, wrap_angle
from houghloc.jit import njit
from houghloc.localize import scan_reach
from houghloc.matching import Matches, associate
from houghloc.refine import Lines
from houghloc.segment_map import MapError, References, SegmentMap, check_grid_size


class GlobalMatchConfig(BaseModel):
    """Settings of global set matching. Angles in degrees in the names, radians inside."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # --- hypotheses from pairs
    min_pair_angle_deg: float = Field(
        15.0, gt=0.0, lt=90.0, description="two lines closer to parallel do not fix a pose")
    angle_tol_sigmas: float = Field(3.0, gt=0.0, description="× σ of the observed angle δ")
    angle_tol_floor_deg: float = Field(1.5, ge=0.0, description="model error of map and lines")
    angle_tol_max_deg: float = Field(5.0, gt=0.0, le=30.0, description="cap on the δ window")
    max_observed_lines: int = Field(
        12, ge=2, description="the strongest lines (most points) form the pairs")
    max_observed_pairs: int = Field(
        40, ge=1, description="best-conditioned pairs kept (length product × |sin δ|)")
    max_pair_hypotheses: int = Field(
        150_000, ge=1, description="budget of hypotheses; best-conditioned pairs go first")
    bbox_margin: float = Field(0.0, ge=0.0, description="m; poses beyond the map's box are dropped")
    # --- pose-space votes and cheap score
    vote_cell_xy: float = Field(0.25, gt=0.0, description="m; pose-space vote cell in x and y")
    vote_cell_theta_deg: float = Field(3.0, gt=0.0, description="°; pose-space vote cell in "
                                       "heading")
    max_cells_cheap: int = Field(
        30_000, ge=1, description="best-voted cells given the cheap score")
    line_samples: int = Field(4, ge=2, description="samples along each line for the cheap score")
    cheap_lines: int = Field(6, ge=2, description="strongest lines sampled for the cheap score")
    # --- full score
    max_hypotheses_scored: int = Field(
        120, ge=1, description="top-M by the cheap score that get the point-based score")
    max_score_points: int = Field(1500, ge=10, description="points subsampled for the score")
    dt_cell: float = Field(0.05, gt=0.0, description="m; cell of the distance-transform grid")
    inlier_distance: float = Field(0.12, gt=0.0, description="m; a point this close is on a wall")
    min_line_coverage: float = Field(
        0.6, gt=0.0, le=1.0, description="fraction of a line's points on walls to explain it")
    line_weight: float = Field(0.5, ge=0.0, le=1.0, description="w in the score")
    # Negative evidence, for the refined hypotheses: a point behind a wall that the hypothesis
    # puts between it and the robot was seen *through* that wall, so it does not count. This is
    # what separates two rooms alike but for a pillar that one of them would have shown.
    check_visibility: bool = Field(True, description="points seen through a wall do not count")
    visibility_margin: float = Field(
        0.25, ge=0.0, description="m; also absorbs the baseline between accumulated views")
    # --- only parallel lines in view (a corridor seen along its length): the pose along them
    # is found by sliding the view along each map line and counting the points on walls (door
    # gaps and what shows through them), the only part of the view that fixes it
    slide_along_parallel: bool = Field(True, description="slide a view of parallel lines along "
                                       "them when no pair of lines fixes the pose")
    slide_step: float = Field(0.1, gt=0.0, description="m; coarse step of the slide")
    slide_fine_step: float = Field(0.02, gt=0.0, description="m; step around the best ones")
    slide_points: int = Field(400, ge=10, description="points subsampled for the slide")
    slide_candidates: int = Field(40, ge=1, description="coarse maxima searched finely")
    slide_sigma: float = Field(
        0.1, gt=0.0, description="m; σ along the lines of a pose found by sliding")
    slide_check: float = Field(0.3, gt=0.0, description="m; a found pose slid this far ...")
    slide_min_sharpness: float = Field(
        0.02, ge=0.0, description="... either way must fit worse by this much (weighted "
        "fraction of points): otherwise the view does not fix the position along the lines")
    # --- clusters, refinement, decision
    cluster_xy: float = Field(0.3, gt=0.0, description="m; closer poses are one hypothesis")
    cluster_theta_deg: float = Field(5.0, gt=0.0, description="°; closer headings are one "
                                     "hypothesis")
    max_refined: int = Field(8, ge=1, description="clusters refined and reported")
    refine_sigma_xy: float = Field(0.15, gt=0.0, description="m; prior around a hypothesis")
    refine_sigma_theta_deg: float = Field(3.0, gt=0.0, description="°; prior around a "
                                          "hypothesis")
    refine_iterations: int = Field(2, ge=1, description="matching corrections of a hypothesis")
    min_lines_explained: int = Field(2, ge=2, description="and two of them non-parallel (rank 3)")
    tie_margin: float = Field(
        0.02, ge=0.0, description="hypotheses this close to the best score tie with it")
    # Line extraction for accumulated views (pass it to ``observe_lines``) and the gates and
    # extent checks of the refinement's matching. A peak needs a fraction of *all* points: with
    # 360° of accumulated views that fraction is halved (and more peaks kept), or a short wall
    # seen through a door never becomes a line and the pose stays undetermined.
    hough: HoughConfig = HoughConfig(peak_fraction=0.02, max_peaks=24)

    @property
    def min_pair_angle(self) -> float:
        return math.radians(self.min_pair_angle_deg)

    @property
    def angle_tol_floor(self) -> float:
        return math.radians(self.angle_tol_floor_deg)

    @property
    def angle_tol_max(self) -> float:
        return math.radians(self.angle_tol_max_deg)

    @property
    def vote_cell_theta(self) -> float:
        return math.radians(self.vote_cell_theta_deg)

    @property
    def cluster_theta(self) -> float:
        return math.radians(self.cluster_theta_deg)

    @property
    def refine_sigma_theta(self) -> float:
        return math.radians(self.refine_sigma_theta_deg)


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
    # on a few gap edges, and rivals that the sharpness check dropped are not in the result


@dataclass(frozen=True)
class GlobalResult:
    """Hypotheses best first (distinct poses), whether several tie, and why (or why none)."""

    hypotheses: list[Hypothesis] = field(default_factory=list)
    ambiguous: bool = False
    reason: str = ""
    n_candidates: int = 0  # pose hypotheses generated from line pairs (inside the map)

    @property
    def best(self) -> Hypothesis | None:
        return self.hypotheses[0] if self.hypotheses else None


_DEFAULT_CONFIG = GlobalMatchConfig()


@dataclass(frozen=True)
class Neighbourhood:
    """Poses within ``radius_xy`` (m) and ``radius_theta`` (rad) of ``pose``."""

    pose: NDArray[np.float64]
    radius_xy: float
    radius_theta: float

    def contains(self, poses: NDArray) -> NDArray[np.bool_]:
        d = poses[:, :2] - self.pose[:2]
        return ((np.einsum("ij,ij->i", d, d) <= self.radius_xy**2)
                & (np.abs(wrap_angle(poses[:, 2] - self.pose[2])) <= self.radius_theta))


# ---------------------------------------------------------------------------- per-map caches
@dataclass(frozen=True)
class AngleIndex:
    """Ordered pairs (a, b) of oriented map lines, sorted by δ = β_b − β_a ∈ [0, 2π).

    Entries near 0 and 2π are repeated shifted by ∓2π so a window never needs to wrap. For each
    pair the inverse of N = [[cos β_a, sin β_a], [cos β_b, sin β_b]] is stored: the position of a
    hypothesis is then one 2×2 product, x = N⁻¹ (r − ρ).
    """

    delta: NDArray[np.float64]
    beta_a: NDArray[np.float64]
    beta_b: NDArray[np.float64]
    r_a: NDArray[np.float64]
    r_b: NDArray[np.float64]
    n_inv: NDArray[np.float64]  # E×2×2
    line_a: NDArray[np.intp]
    line_b: NDArray[np.intp]


@dataclass(frozen=True)
class WallDistance:
    """Distance (m) from each cell centre to the nearest wall; ``origin`` is the lower-left corner
    of cell (0, 0), rows along y. Points outside the grid are infinitely far from walls."""

    distance: NDArray[np.float32]
    origin: NDArray[np.float64]
    cell: float

    def lookup(self, x: NDArray, y: NDArray) -> NDArray[np.float32]:
        """Distances at world points (any shape), O(1) each: the value of the cell holding the
        point (the grid's outermost ring holds +inf, so clipping the indices is the only bounds
        check)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return self.at(_IDENTITY, x, y)[0]

    def lookup_smooth(self, x: NDArray, y: NDArray) -> NDArray[np.float32]:
        """Distances interpolated bilinearly between cell centres: continuous in the position,
        where :meth:`lookup` jumps by a cell (a point exactly on a wall may read one cell off)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return self.at(_IDENTITY, x, y, smooth=True)[0]

    def at(self, poses: NDArray, x: NDArray, y: NDArray, smooth: bool = False
           ) -> NDArray[np.float32]:
        """Distances at robot-frame points (``x``, ``y``, any shape S) placed in the world at each
        of ``poses`` (P×3): P×S, the points' world coordinates never stored.

        World point: (x₀ + x cos θ − y sin θ, y₀ + x sin θ + y cos θ). ``smooth``: the bilinear
        value of :meth:`lookup_smooth`, else the cell's of :meth:`lookup`.
        """
        shape = np.shape(x)
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        out = _distances_at(self.distance, self.origin[0], self.origin[1], 1.0 / self.cell,
                            poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]),
                            _flat(x), _flat(y), smooth)
        return out.reshape((len(poses),) + shape)


_IDENTITY = np.zeros((1, 3))


def _flat(values: NDArray) -> NDArray[np.float64]:
    """One contiguous float64 row (the kernels are compiled for that layout only)."""
    return np.ascontiguousarray(np.ravel(values), dtype=float)


@njit
def _distances_at(grid: NDArray, ox: float, oy: float, inv_cell: float, poses: NDArray,
                  cos_t: NDArray, sin_t: NDArray, x: NDArray, y: NDArray, smooth: bool
                  ) -> NDArray[np.float32]:
    h, w = grid.shape
    out = np.empty((len(poses), len(x)), np.float32)
    for p in range(len(poses)):
        c, s, px, py = cos_t[p], sin_t[p], poses[p, 0], poses[p, 1]
        for k in range(len(x)):
            fx = (px + c * x[k] - s * y[k] - ox) * inv_cell
            fy = (py + s * x[k] + c * y[k] - oy) * inv_cell
            if not smooth:  # truncation is floor inside the grid; outside, the +inf ring
                ix, iy = min(max(int(fx), 0), w - 1), min(max(int(fy), 0), h - 1)
                out[p, k] = grid[iy, ix]
                continue
            fx, fy = fx - 0.5, fy - 0.5  # from cell centres
            x0 = min(max(math.floor(fx), 0), w - 2)
            y0 = min(max(math.floor(fy), 0), h - 2)
            ax, ay = min(max(fx - x0, 0.0), 1.0), min(max(fy - y0, 0.0), 1.0)
            top = grid[y0, x0] * (1 - ax) + grid[y0, x0 + 1] * ax
            bottom = grid[y0 + 1, x0] * (1 - ax) + grid[y0 + 1, x0 + 1] * ax
            d = top * (1 - ay) + bottom * ay
            out[p, k] = np.inf if math.isnan(d) else d  # inf · 0 at the rim: far from walls
    return out


_CACHE: weakref.WeakKeyDictionary[SegmentMap, dict] = weakref.WeakKeyDictionary()


def _cached(map: SegmentMap, key: tuple, build):
    """Per-map memo (dropped with the map): the index and the grid are built once per map."""
    store = _CACHE.setdefault(map, {})
    if key not in store:
        store[key] = build()
    return store[key]


def map_lines_of_kinds(map: SegmentMap, kinds: tuple[str, ...]) -> NDArray[np.intp]:
    """Canonical lines with at least one segment of the given kinds."""
    segs = np.isin(map.kinds, kinds)
    return np.unique(map.line_of_segment[segs])


def angle_index(map: SegmentMap, kinds: tuple[str, ...], min_angle: float,
                pad: float) -> AngleIndex:
    """The (cached) angle index of a map's oriented line pairs; ``pad`` ≥ the widest window."""
    return _cached(map, ("angle_index", kinds, min_angle, pad),
                   lambda: _build_angle_index(map, kinds, min_angle, pad))


MAX_INDEX_PAIRS = 10_000_000
"""Oriented line pairs in the angle index (about 100 bytes each: 1 GB): a map of up to 1,580
distinct lines; every real building here has under 400."""


def _build_angle_index(map: SegmentMap, kinds: tuple[str, ...], min_angle: float,
                       pad: float) -> AngleIndex:
    lines = map_lines_of_kinds(map, kinds)
    if (2 * len(lines)) ** 2 > MAX_INDEX_PAIRS:
        raise MapError(f"map {map.source}: {len(lines)} distinct lines make "
                       f"{(2 * len(lines)) ** 2:,} oriented pairs for global matching's angle "
                       f"index (~{(2 * len(lines)) ** 2 * 100 / 2**30:.1f} GiB), more than the "
                       f"{MAX_INDEX_PAIRS:,} allowed")
    beta = np.concatenate((map.line_alpha[lines], map.line_alpha[lines] + np.pi))
    r = np.concatenate((map.line_r[lines], -map.line_r[lines]))
    line = np.concatenate((lines, lines))
    grid_a, grid_b = np.meshgrid(np.arange(len(beta)), np.arange(len(beta)), indexing="ij")
    a, b = grid_a.ravel(), grid_b.ravel()
    delta = np.mod(beta[b] - beta[a], TWO_PI)
    keep = (line[a] != line[b]) & (np.abs(np.sin(delta)) >= math.sin(min_angle))
    a, b, delta = a[keep], b[keep], delta[keep]
    # repeat the ends of the circle so that [δ − tol, δ + tol] is one contiguous range
    low, high = delta < pad, delta > TWO_PI - pad
    a = np.concatenate((a, a[low], a[high]))
    b = np.concatenate((b, b[low], b[high]))
    delta = np.concatenate((delta, delta[low] + TWO_PI, delta[high] - TWO_PI))
    order = np.argsort(delta, kind="stable")
    a, b, delta = a[order], b[order], delta[order]
    ca, sa, cb, sb = np.cos(beta[a]), np.sin(beta[a]), np.cos(beta[b]), np.sin(beta[b])
    det = ca * sb - sa * cb  # = sin δ, bounded away from 0 by min_angle
    n_inv = np.stack((np.stack((sb, -sa), -1), np.stack((-cb, ca), -1)), -2) / det[:, None, None]
    return AngleIndex(delta, beta[a], beta[b], r[a], r[b], n_inv, line[a], line[b])


def wall_distance(map: SegmentMap, kinds: tuple[str, ...], cell: float,
                  margin: float = 1.0) -> WallDistance:
    """The (cached) distance-transform grid of the map's segments of ``kinds``."""
    return _cached(map, ("wall_distance", kinds, cell, margin),
                   lambda: _build_wall_distance(map, kinds, cell, margin))


def _build_wall_distance(map: SegmentMap, kinds: tuple[str, ...], cell: float,
                         margin: float) -> WallDistance:
    segs = np.flatnonzero(np.isin(map.kinds, kinds))
    ends = np.concatenate((map.starts[segs], map.ends[segs]))
    origin = ends.min(axis=0) - margin
    w, h = np.ceil((ends.max(axis=0) + margin - origin) / cell).astype(int) + 1
    check_grid_size((h, w), cell, f"map {map.source}")
    # walls are drawn as 0 on a 255 background; the transform gives each cell's distance (in
    # cells, exact Euclidean) to the nearest wall pixel
    image = np.full((h, w), 255, dtype=np.uint8)
    shift = 4  # sub-pixel precision of the drawn segments
    p0 = np.round((map.starts[segs] - origin) / cell * (1 << shift) - 0.5 * (1 << shift))
    p1 = np.round((map.ends[segs] - origin) / cell * (1 << shift) - 0.5 * (1 << shift))
    for a, b in zip(p0.astype(int), p1.astype(int), strict=True):  # once per map
        cv2.line(image, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 0, 1, cv2.LINE_8, shift)
    dist = (cv2.distanceTransform(image, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * cell)
    dist[[0, -1], :] = dist[:, [0, -1]] = np.inf  # off the grid is far from every wall
    return WallDistance(dist.astype(np.float32), origin, cell)


# ---------------------------------------------------------------------------- the method
def global_match(
    lines: Lines,
    points: ArrayLike,
    map: SegmentMap,
    config: GlobalMatchConfig = _DEFAULT_CONFIG,
    kinds: tuple[str, ...] = ("wall",),
    near: Neighbourhood | None = None,
) -> GlobalResult:
    """Match the set of observed ``lines`` (robot frame, from ``points``) against the map's lines.

    ``points`` (N×2, robot frame) are the accumulated points the lines were extracted from (e.g. by
    :func:`houghloc.localize.observe_lines`). Returns every distinct hypothesis, best first; bad or
    structureless input gives an empty result with a reason, never an exception. With ``near``
    only poses inside that neighbourhood are hypothesised: a local re-search around a
    dead-reckoned pose, where the rest of the building cannot compete.
    """
    kinds = tuple(kinds)
    pts = _as_points(points)
    if pts is None:
        return GlobalResult(reason="points must be an N×2 array of (x, y)")
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        return GlobalResult(reason="no points")
    if not np.isin(map.kinds, kinds).any():
        return GlobalResult(reason=f"the map has no segment of kinds {kinds}")
    if lines is None or len(lines) == 0:
        return GlobalResult(reason="no observed lines")
    if lines.members.shape[0] != len(pts):
        return GlobalResult(reason=f"the lines were extracted from {lines.members.shape[0]} "
                            f"points, not from these {len(pts)}")
    if not finite.all():  # the lines' member rows follow the points: drop both together
        pts = pts[finite]
        lines = dataclasses.replace(lines, members=lines.members[finite])

    result = _match_pairs(lines, pts, map, config, kinds, near)
    if result.hypotheses or not config.slide_along_parallel:
        return result
    slid = _match_sliding(lines, pts, map, config, kinds, near)
    if slid.hypotheses:
        return slid
    return dataclasses.replace(result, reason=f"{result.reason}; {slid.reason}")


def _match_pairs(lines: Lines, pts: NDArray, map: SegmentMap, config: GlobalMatchConfig,
                 kinds: tuple[str, ...], near: Neighbourhood | None = None) -> GlobalResult:
    """Steps 1–5 of the module docstring: hypotheses from pairs of non-parallel lines."""
    pair_i, pair_k = observed_pairs(lines, config)
    if len(pair_i) == 0:
        return GlobalResult(reason=f"fewer than two non-parallel observed lines (angle ≥ "
                            f"{config.min_pair_angle_deg:g}°): the pose is not determined")
    pad = config.angle_tol_max + 1e-9
    index = angle_index(map, kinds, config.min_pair_angle, pad)
    if len(index.delta) == 0:
        return GlobalResult(reason="the map has no two non-parallel lines")
    poses = pair_hypotheses(lines, pair_i, pair_k, index, config, near)
    if near is not None:
        poses = poses[near.contains(poses)]
    poses = poses[_inside_map(poses, map, kinds, config.bbox_margin)]
    n_candidates = len(poses)
    if n_candidates == 0:
        where = "the neighbourhood" if near is not None else "the map"
        return GlobalResult(reason=f"no line pair gives a pose inside {where}")

    cells, votes = vote_cells(poses, config)
    walls = wall_distance(map, kinds, config.dt_cell)
    cheap = cheap_scores(cells, lines, walls, config)
    top = _top(cheap + 1e-6 * votes / votes.max(), config.max_hypotheses_scored)
    cells, cheap = cells[top], cheap[top]
    if cheap[0] <= 0.0:
        return GlobalResult(reason="no hypothesis puts an observed line on a wall",
                            n_candidates=n_candidates)

    sample = _subsample(len(pts), config.max_score_points)
    pts_s, members_s = pts[sample], lines.members[sample]
    scores = point_scores(cells, pts_s, members_s, walls, config)
    keep = cluster(cells, scores.score, config)[: config.max_refined]
    reach = scan_reach(pts)
    refined = [_refined(cells[j], lines, reach, pts_s, members_s, map, walls, kinds, config)
               for j in keep]
    hyps = [h for h in refined if h is not None and _valid(h, config)]
    if not hyps:
        return GlobalResult(reason=f"no hypothesis explains {config.min_lines_explained} "
                            "non-parallel lines", n_candidates=n_candidates)
    hyps.sort(key=lambda h: -h.score)
    final = cluster(np.array([h.pose for h in hyps]), np.array([h.score for h in hyps]), config)
    hyps = [hyps[j] for j in final]
    return _decide(hyps, n_candidates, config)


def _match_sliding(lines: Lines, pts: NDArray, map: SegmentMap, config: GlobalMatchConfig,
                   kinds: tuple[str, ...], near: Neighbourhood | None = None) -> GlobalResult:
    """Hypotheses when no pair of lines fixes the pose: a corridor seen along its length.

    The strongest observed line, put on an oriented map line (β, r), fixes the heading
    θ = β − θ_obs and the position across it, n·p = r − ρ; the position along it, s in
    p = n (r − ρ) + s u, is what the points say. Each s on a coarse grid (``slide_step``) over
    the map is scored by the sample's points weighted 1 − (d / d_in)² by their distance d from
    a wall: door gaps, their jambs and the rooms seen through the doors line up at one s only,
    and the weight peaks there where a plain count of points within d_in is flat over ± d_in.
    The best ``slide_candidates`` local maxima are searched again on a fine grid with d
    interpolated. The survivors get the full score (with visibility) and are reported like any
    other hypothesis; their covariance has ``slide_sigma`` along the lines (the precision of
    the alignment) where a rank-2 estimate would have none.

    Cost: (number of oriented map lines) × (map extent / ``slide_step``) poses × ``slide_points``
    look-ups, about 80 ms on the office map; only run when the pairs give no hypothesis.
    """
    strong = int(np.argmax(lines.n))
    parallel = np.abs(np.sin(lines.theta - lines.theta[strong])) < math.sin(config.min_pair_angle)
    if parallel.sum() < 2:
        return GlobalResult(reason="sliding: fewer than two parallel observed lines")
    mlines = map_lines_of_kinds(map, kinds)
    beta = np.concatenate((map.line_alpha[mlines], map.line_alpha[mlines] + np.pi))
    r = np.concatenate((map.line_r[mlines], -map.line_r[mlines]))
    lo, hi = _bbox(map, kinds)
    corners = np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]]])
    walls = wall_distance(map, kinds, config.dt_cell)
    sample = pts[_subsample(len(pts), config.slide_points)]

    def poses_at(b: NDArray, offset: NDArray, s: NDArray) -> NDArray:
        n, u = np.stack((np.cos(b), np.sin(b)), -1), np.stack((-np.sin(b), np.cos(b)), -1)
        xy = n * offset[:, None] + u * s[:, None]
        return np.column_stack((xy, wrap_angle(b - lines.theta[strong])))

    def fit(poses: NDArray, smooth: bool) -> NDArray:
        """The sample's points weighted 1 − (d / d_in)² by their distance d from the nearest
        wall: peaks where the gaps' edges coincide, where a count of the points within d_in is
        flat over ± d_in. ``smooth``: d interpolated (exact to a fraction of a cell, 4 look-ups
        a point); otherwise the cell's value, less a cell (its quantisation is not evidence)."""
        out = np.empty(len(poses))
        for sl in _chunks(len(poses), len(sample)):
            d = walls.at(poses[sl], sample[:, 0], sample[:, 1], smooth)
            if not smooth:
                d = np.maximum(d - walls.cell, 0.0)
            d = d / config.inlier_distance
            out[sl] = np.clip(1.0 - d * d, 0.0, None).mean(axis=1)
        return out

    # the coarse grid: for each oriented map line, s over the map's extent along it (over the
    # neighbourhood's only, and only the lines that put the robot inside it, when one is given)
    u_all = np.stack((-np.sin(beta), np.cos(beta)), -1)
    s_lo, s_hi = (corners @ u_all.T).min(axis=0), (corners @ u_all.T).max(axis=0)
    if near is not None:
        n_all = np.stack((np.cos(beta), np.sin(beta)), -1)
        across = np.abs(n_all @ near.pose[:2] - (r - lines.rho[strong]))
        turn = np.abs(wrap_angle(beta - lines.theta[strong] - near.pose[2]))
        keep = (across <= near.radius_xy) & (turn <= near.radius_theta)
        if not keep.any():
            return GlobalResult(reason="sliding: no map line near the neighbourhood")
        beta, r, u_all = beta[keep], r[keep], u_all[keep]
        centre = u_all @ near.pose[:2]
        s_lo = np.maximum(s_lo[keep], centre - near.radius_xy)
        s_hi = np.minimum(s_hi[keep], centre + near.radius_xy)
    counts = np.maximum(np.ceil((s_hi - s_lo) / config.slide_step).astype(np.intp) + 1, 0)
    which = np.repeat(np.arange(len(beta)), counts)
    step_i = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    s = s_lo[which] + step_i * config.slide_step
    coarse = poses_at(beta[which], r[which] - lines.rho[strong], s)
    inside = _inside_map(coarse, map, kinds, config.bbox_margin)
    if near is not None:
        inside &= near.contains(coarse)
    coarse, which = coarse[inside], which[inside]
    if len(coarse) == 0:
        return GlobalResult(reason="sliding: no pose inside the map")
    # local maxima along each map line only: a plateau's neighbours would fill every slot
    f = fit(coarse, smooth=False)
    same_prev = np.r_[False, which[1:] == which[:-1]]
    same_next = np.r_[which[:-1] == which[1:], False]
    peak = ((~same_prev | (f >= np.r_[-1.0, f[:-1]]))
            & (~same_next | (f > np.r_[f[1:], -1.0])))
    peaks = np.flatnonzero(peak)
    best = peaks[_top(f[peaks], config.slide_candidates)]
    # the fine grid around each coarse maximum, along its own map line
    offsets = np.arange(-config.slide_step, config.slide_step + 1e-9, config.slide_fine_step)
    b = np.repeat(beta[which[best]], len(offsets))
    u = np.stack((-np.sin(b), np.cos(b)), -1)
    fine = np.repeat(coarse[best], len(offsets), axis=0)
    fine[:, :2] += u * np.tile(offsets, len(best))[:, None]
    fine_fit = fit(fine, smooth=True).reshape(len(best), len(offsets))
    cells = fine.reshape(len(best), len(offsets), 3)[np.arange(len(best)),
                                                      fine_fit.argmax(axis=1)]
    peak_fit = fine_fit.max(axis=1)
    # the view must fix s: slid by ``slide_check`` either way it must fit clearly worse (walls
    # without gaps fit a corridor with doors equally badly almost anywhere)
    u_best = u.reshape(len(best), len(offsets), 2)[:, 0]
    sides = [cells.copy(), cells.copy()]
    sides[0][:, :2] += config.slide_check * u_best
    sides[1][:, :2] -= config.slide_check * u_best
    sharpness = peak_fit - np.maximum(fit(sides[0], smooth=True), fit(sides[1], smooth=True))
    fixed = sharpness >= config.slide_min_sharpness
    if not fixed.any():
        return GlobalResult(reason="sliding: the points do not fix the position along the lines",
                            n_candidates=len(coarse))
    cells, peak_fit = cells[fixed], peak_fit[fixed]
    sample_i = _subsample(len(pts), config.max_score_points)
    pts_s, members_s = pts[sample_i], lines.members[sample_i]
    # the weighted fit ranks the clusters: a plain count is flat around the true s
    keep = cluster(cells, peak_fit, config)[: config.max_refined]
    reach = scan_reach(pts)
    slid = [_slid(cells[j], lines, reach, pts_s, members_s, map, walls, kinds, config)
            for j in keep]
    hyps = [h for h in slid if h is not None and _valid(h, config)]
    if not hyps:
        return GlobalResult(reason="sliding: no pose explains two parallel lines",
                            n_candidates=len(coarse))
    hyps.sort(key=lambda h: -h.score)
    return _decide(hyps, len(coarse), config)


def _slid(pose: NDArray, lines: Lines, max_range: float, pts_s: NDArray, members_s: NDArray,
          map: SegmentMap, walls: WallDistance, kinds: tuple[str, ...],
          config: GlobalMatchConfig) -> Hypothesis | None:
    """A pose found by sliding, scored like a refined one. The lines matched there (all
    parallel: rank 2) refine the heading and the position across them; along them the pose
    stays where the points put it, with σ ``slide_sigma``."""
    found = _matched_at(pose, lines, map, kinds, max_range, config)
    if found is None or len(found[1]) < 2:
        return None
    refs, matches, disp = found
    beta = float(refs.beta[matches.ref[0]])
    n = np.array([math.cos(beta), math.sin(beta)])
    u = np.array([-n[1], n[0]])
    pose = pose.copy()
    if disp.rank >= 1:  # only the observable part: across the lines, and the heading
        pose[:2] += n * float(n @ disp.delta[:2])
        pose[2] = float(wrap_angle(pose[2] + disp.delta[2]))
    cov = np.zeros((3, 3))
    var_n = float(n @ disp.cov[:2, :2] @ n) if disp.rank >= 1 else config.refine_sigma_xy**2
    var_n = min(var_n, config.refine_sigma_xy**2)
    cov[:2, :2] = var_n * np.outer(n, n) + config.slide_sigma**2 * np.outer(u, u)
    cov[2, 2] = min(float(disp.cov[2, 2]), config.refine_sigma_theta**2)
    return _scored(pose, cov, refs, matches, pts_s, members_s, map, walls, kinds, max_range,
                   config, slid=True)


def _decide(hyps: list[Hypothesis], n_candidates: int, config: GlobalMatchConfig) -> GlobalResult:
    best = hyps[0]
    tied = [h for h in hyps if h.score >= best.score - config.tie_margin]
    summary = (f"best explains {best.n_lines_explained} lines, "
               f"{100 * best.inlier_fraction:.0f}% of points on walls (score {best.score:.2f})")
    if len(tied) > 1:
        return GlobalResult(hyps, True, f"{len(tied)} hypotheses within {config.tie_margin:g} "
                            f"of the best score: keep collecting views; {summary}", n_candidates)
    return GlobalResult(hyps, False, summary, n_candidates)


# ---------------------------------------------------------------------------- 1. hypotheses
def observed_pairs(lines: Lines, config: GlobalMatchConfig
                   ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index pairs (i, k), i ≠ k unordered, of strong non-parallel observed lines.

    The best-conditioned pairs come first: long lines (well-determined θ) meeting near 90°
    (well-determined position); only ``max_observed_pairs`` are kept, because one correct pair
    already gives the pose and every pair multiplies the hypotheses.
    """
    strong = np.argsort(-lines.n, kind="stable")[: config.max_observed_lines]
    i, k = np.triu_indices(len(strong), 1)
    i, k = strong[i], strong[k]
    sin_d = np.abs(np.sin(lines.theta[k] - lines.theta[i]))
    ok = sin_d >= math.sin(config.min_pair_angle)
    i, k, sin_d = i[ok], k[ok], sin_d[ok]
    length = lines.s1 - lines.s0
    quality = length[i] * length[k] * sin_d
    order = np.argsort(-quality, kind="stable")[: config.max_observed_pairs]
    return i[order], k[order]


def pair_hypotheses(lines: Lines, pair_i: NDArray[np.intp], pair_k: NDArray[np.intp],
                    index: AngleIndex, config: GlobalMatchConfig,
                    near: Neighbourhood | None = None) -> NDArray[np.float64]:
    """All poses (H×3) from observed pairs and the map pairs with the same angle between them.

    The window half-width is ``angle_tol_sigmas`` σ_δ + ``angle_tol_floor`` (capped), with
    σ_δ² = var θ_i + var θ_k from the lines' covariance; the ragged candidate ranges are walked
    by one compiled loop (:func:`_pair_poses`). With ``near``, poses whose heading is outside it are
    left out before their position is solved (a local search keeps a few percent of them); the
    budget still counts every candidate, so the poses kept are the same as without it.
    """
    d_obs = np.mod(lines.theta[pair_k] - lines.theta[pair_i], TWO_PI)
    sigma = np.sqrt(lines.cov[pair_i, 0, 0] + lines.cov[pair_k, 0, 0])
    tol = np.minimum(config.angle_tol_sigmas * sigma + config.angle_tol_floor,
                     config.angle_tol_max)
    lo = np.searchsorted(index.delta, d_obs - tol, side="left")
    hi = np.searchsorted(index.delta, d_obs + tol, side="right")
    counts = _within_budget(hi - lo, config.max_pair_hypotheses)
    return _pair_poses(lines.theta, lines.rho, pair_i, pair_k, lo, counts, index.beta_a,
                       index.beta_b, index.r_a, index.r_b, index.n_inv, near is not None,
                       near.pose[2] if near is not None else 0.0,
                       near.radius_theta if near is not None else 0.0, float(tol.max()))


@njit
def _pair_poses(theta: NDArray, rho: NDArray, pair_i: NDArray, pair_k: NDArray, lo: NDArray,
                counts: NDArray, beta_a: NDArray, beta_b: NDArray, r_a: NDArray, r_b: NDArray,
                n_inv: NDArray, use_near: bool, near_theta: float, near_radius: float,
                tol_max: float) -> NDArray:
    """The poses of :func:`pair_hypotheses`, ``counts[p]`` index entries from ``lo[p]`` for each
    observed pair p: θ = β − θ_obs from either line, their circular mean; (x, y) = N⁻¹ (r − ρ).
    With a neighbourhood, a pose whose heading is outside it is left out before its position is
    solved (θ is within half the angle window of θ_a: a first cut on θ_a alone)."""
    out = np.empty((counts.sum(), 3))
    h = 0
    for p in range(len(pair_i)):
        i, k = pair_i[p], pair_k[p]
        for e in range(lo[p], lo[p] + counts[p]):
            th_a = beta_a[e] - theta[i]
            if use_near and abs((th_a - near_theta + np.pi) % TWO_PI - np.pi) > (
                    near_radius + tol_max):
                continue
            th_b = beta_b[e] - theta[k]
            half = 0.5 * ((th_b - th_a + np.pi) % TWO_PI - np.pi)
            th = (th_a + half + np.pi) % TWO_PI - np.pi
            if use_near and abs((th - near_theta + np.pi) % TWO_PI - np.pi) > near_radius:
                continue
            rhs_a, rhs_b = r_a[e] - rho[i], r_b[e] - rho[k]
            out[h, 0] = n_inv[e, 0, 0] * rhs_a + n_inv[e, 0, 1] * rhs_b
            out[h, 1] = n_inv[e, 1, 0] * rhs_a + n_inv[e, 1, 1] * rhs_b
            out[h, 2] = th
            h += 1
    return out[:h]


def _within_budget(counts: NDArray[np.intp], budget: int) -> NDArray[np.intp]:
    """Candidate counts with the pairs beyond the budget set to zero.

    The index tells, before any pose is computed, how many map pairs each observed pair matches.
    Pairs arrive best-conditioned first (long lines, well-determined angles); they are taken in
    that order while the total stays within ``budget`` (the first always), so in a large map of
    right angles, where every pair matches thousands of map pairs, the cost stops growing with
    the square of the map. (Taking the rarest angles first would be cheaper still, but a rare
    angle is most often a short spurious piece.)
    """
    take = np.cumsum(counts) <= budget
    take[0] = True
    return np.where(take, counts, 0)


def _inside_map(poses: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                margin: float) -> NDArray[np.bool_]:
    lo, hi = _bbox(map, kinds)
    xy = poses[:, :2]
    return np.all((xy >= lo - margin) & (xy <= hi + margin), axis=1)


def _bbox(map: SegmentMap, kinds: tuple[str, ...]) -> tuple[NDArray, NDArray]:
    segs = np.isin(map.kinds, kinds)
    ends = np.concatenate((map.starts[segs], map.ends[segs]))
    return ends.min(axis=0), ends.max(axis=0)


# ---------------------------------------------------------------------------- 2. votes
def vote_cells(poses: NDArray, config: GlobalMatchConfig) -> tuple[NDArray, NDArray]:
    """Bin poses in (x, y, θ); return one pose per occupied cell (its members' mean) and the count
    of hypotheses in it, best-voted first, at most ``max_cells_cheap``."""
    q = np.column_stack((np.floor(poses[:, :2] / config.vote_cell_xy),
                         np.floor(np.mod(poses[:, 2], TWO_PI) / config.vote_cell_theta)))
    q = q.astype(np.int64)
    q -= q.min(axis=0)
    # one integer key per cell: a 1-D unique is several times faster than unique over rows
    key = np.ravel_multi_index(q.T, tuple(q.max(axis=0) + 1))
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    n_cells = len(counts)
    # mean pose per cell: positions averaged, θ as a circular mean
    sums = np.zeros((n_cells, 4))
    for col, values in enumerate((poses[:, 0], poses[:, 1], np.cos(poses[:, 2]),
                                  np.sin(poses[:, 2]))):
        sums[:, col] = np.bincount(inverse, values, minlength=n_cells)
    cells = np.column_stack((sums[:, :2] / counts[:, None], np.arctan2(sums[:, 3], sums[:, 2])))
    order = _top(counts.astype(float), config.max_cells_cheap)
    return cells[order], counts[order]


def _top(values: NDArray, m: int) -> NDArray[np.intp]:
    """Indices of the m largest values, largest first (a partition, then a small sort)."""
    if len(values) > m:
        part = np.argpartition(-values, m - 1)[:m]
    else:
        part = np.arange(len(values))
    return part[np.argsort(-values[part], kind="stable")]


# ---------------------------------------------------------------------------- 3–4. scores
def _chunks(n_rows: int, cost_per_row: int, budget: int = 2_000_000):
    step = max(1, budget // max(cost_per_row, 1))
    for start in range(0, n_rows, step):
        yield slice(start, min(start + step, n_rows))


def cheap_scores(poses: NDArray, lines: Lines, walls: WallDistance,
                 config: GlobalMatchConfig) -> NDArray[np.float64]:
    """Point-count-weighted fraction of the ``cheap_lines`` strongest observed lines whose samples
    lie on walls (H,).

    Line k is sampled at S evenly spaced points ρ n_k + s t_k, s ∈ [s0, s1]; it counts when
    ≥ ``min_line_coverage`` of its samples are within ``inlier_distance`` of a wall.
    """
    lines = lines.subset(np.argsort(-lines.n, kind="stable")[: config.cheap_lines])
    u = np.linspace(0.0, 1.0, config.line_samples)
    s = lines.s0[:, None] + u[None, :] * (lines.s1 - lines.s0)[:, None]  # K×S
    c, sn = np.cos(lines.theta)[:, None], np.sin(lines.theta)[:, None]
    px = (lines.rho[:, None] * c - s * sn).astype(np.float32)
    py = (lines.rho[:, None] * sn + s * c).astype(np.float32)
    weight = lines.n / lines.n.sum()
    out = np.empty(len(poses))
    for sl in _chunks(len(poses), px.size):
        on_wall = walls.at(poses[sl], px, py) <= config.inlier_distance  # H×K×S
        explained = on_wall.mean(axis=2) >= config.min_line_coverage
        out[sl] = explained @ weight
    return out


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
    for sl in _chunks(len(poses), len(points)):
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
    ``cluster_xy`` and ``cluster_theta`` of it. Returns the kept indices, best first (the loop runs
    once per cluster, not per pose)."""
    order = np.argsort(-scores, kind="stable")
    alive = np.ones(len(poses), dtype=bool)
    kept: list[int] = []
    for j in order:
        if not alive[j]:
            continue
        kept.append(int(j))
        near = (np.hypot(*(poses[:, :2] - poses[j, :2]).T) <= config.cluster_xy) & (
            np.abs(wrap_angle(poses[:, 2] - poses[j, 2])) <= config.cluster_theta)
        alive &= ~near
        if not alive.any():
            break
    return kept


def _refined(pose: NDArray, lines: Lines, max_range: float, pts_s: NDArray,
             members_s: NDArray, map: SegmentMap, walls: WallDistance, kinds: tuple[str, ...],
             config: GlobalMatchConfig) -> Hypothesis | None:
    """Weighted least squares on the lines matched at a hypothesis (DESIGN §3.5), then rescored.

    The hypothesis is treated as a guess with a tight prior (``refine_sigma_*``): the Hough-domain
    gates of :func:`associate` then only admit the lines that this pose explains.
    """
    pose = np.array([pose[0], pose[1], float(wrap_angle(pose[2]))])
    # refine_iterations corrections, then one more (cheap) solve at the last linearisation
    # point, to which the covariance belongs
    for step in range(config.refine_iterations + 1):
        found = _matched_at(pose, lines, map, kinds, max_range, config)
        if found is None or found[2].rank < 3:
            return None
        refs, matches, disp = found
        if step < config.refine_iterations:
            pose = pose + disp.delta
            pose[2] = float(wrap_angle(pose[2]))
    return _scored(pose, disp.cov, refs, matches, pts_s, members_s, map, walls, kinds, max_range,
                   config)


def _matched_at(pose: NDArray, lines: Lines, map: SegmentMap, kinds: tuple[str, ...],
                max_range: float, config: GlobalMatchConfig
                ) -> tuple[References, Matches, Displacement] | None:
    """The lines matched at a hypothesis treated as a guess with the tight prior
    ``refine_sigma_*``, and the displacement they give; None when none matches."""
    hc = config.hough
    prior = np.diag([config.refine_sigma_xy**2] * 2 + [config.refine_sigma_theta**2])
    refs = map.references(pose, max_range, kinds, hc.visibility_rays)
    matches = associate(lines, refs, pose, prior, hc)
    if len(matches) == 0:
        return None
    return refs, matches, estimate_displacement(matches, refs.beta[matches.ref],
                                                hc.max_observable_sigma)


def _scored(pose: NDArray, cov: NDArray, refs: References, matches: Matches, pts_s: NDArray,
            members_s: NDArray, map: SegmentMap, walls: WallDistance, kinds: tuple[str, ...],
            max_range: float, config: GlobalMatchConfig, slid: bool = False) -> Hypothesis:
    """A refined pose as a hypothesis: its score on the sampled points, and the line pairs."""
    visible = (seen_directly(pose, pts_s, map, kinds, max_range, config.visibility_margin)[None]
               if config.check_visibility else None)
    s = point_scores(pose[None, :], pts_s, members_s, walls, config, visible)
    pairs = np.column_stack((matches.line, refs.line[matches.ref])).astype(np.intp)
    return Hypothesis(pose, cov, float(s.score[0]), int(s.n_explained[0]),
                      float(s.inlier_fraction[0]), pairs, slid=slid)


def seen_directly(pose: NDArray, points: NDArray, map: SegmentMap, kinds: tuple[str, ...],
                  max_range: float, margin: float) -> NDArray[np.bool_]:
    """Which robot-frame points the map lets the robot see from ``pose`` (N,).

    The ray o + t (q − o), t ∈ (0, 1], from the robot o to the point q in the world crosses wall
    segment p + u e, u ∈ [0, 1], where (Cramer's rule on o + t d = p + u e, d = q − o)
        t = (w × e) / (d × e),   u = (w × d) / (d × e),   w = p − o.
    A crossing more than ``margin`` before the point means the point was seen through that wall.
    Only walls occlude; painted lines do not.
    """
    near = map.segments_near(pose[:2], max_range)
    near = near[np.isin(map.kinds[near], kinds) & map.is_wall[near]]
    if len(near) == 0 or len(points) == 0:
        return np.ones(len(points), dtype=bool)
    heading = np.array([pose[2]])  # NumPy's cos and sin, as every other placement of points
    return _unoccluded(float(pose[0]), float(pose[1]), float(np.cos(heading)[0]),
                       float(np.sin(heading)[0]), np.ascontiguousarray(points, dtype=float),
                       map.starts[near], map.ends[near], margin)


@njit
def _unoccluded(ox: float, oy: float, c: float, s: float, points: NDArray, starts: NDArray,
                ends: NDArray, margin: float) -> NDArray[np.bool_]:
    """:func:`seen_directly` for the robot at (ox, oy) heading (c, s) = (cos θ, sin θ)."""
    seen = np.ones(len(points), np.bool_)
    for i in range(len(points)):
        dx = ox + c * points[i, 0] - s * points[i, 1] - ox  # d = q − o, q in the world
        dy = oy + s * points[i, 0] + c * points[i, 1] - oy
        t_max = 1.0 - margin / max(math.hypot(dx, dy), 1e-9)  # in units of the point's range
        for j in range(len(starts)):
            wx, wy = starts[j, 0] - ox, starts[j, 1] - oy
            ex, ey = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1]
            den = dx * ey - dy * ex
            if abs(den) <= 1e-12:
                continue
            t = (wx * ey - wy * ex) / den
            u = (wx * dy - wy * dx) / den
            if t > 1e-6 and t < t_max and u >= 0 and u <= 1:
                seen[i] = False
                break
    return seen


def _valid(h: Hypothesis, config: GlobalMatchConfig) -> bool:
    return h.n_lines_explained >= config.min_lines_explained and len(h.matches) >= 2


# ---------------------------------------------------------------------------- input
def _as_points(points: ArrayLike) -> NDArray[np.float64] | None:
    """An N×2 float array (N may be 0), or None when ``points`` cannot be one."""
    try:
        pts = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        return None
    if pts.size == 0:
        return np.empty((0, 2))
    if pts.ndim != 2 or pts.shape[1] != 2:
        return None
    return pts


def _subsample(n: int, m: int) -> NDArray[np.intp]:
    """At most m of n indices, evenly strided (deterministic; keeps every line's share)."""
    if n <= m:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, m).astype(np.intp))

"""Global set matching, the paper's strategy (ii) (docs/method.md §6).

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
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.config import GlobalMatchConfig
from houghloc.geometry import wrap_angle
from houghloc.hypothesis_scores import (
    Hypothesis,
    cheap_scores,
    cluster,
    matched_at,
    point_scores,
    refine_hypothesis,
    scored_hypothesis,
)
from houghloc.localize import scan_reach
from houghloc.map_lookup import (
    WallDistance,
    angle_index,
    inside_map,
    map_bbox,
    map_lines_of_kinds,
    wall_distance,
)
from houghloc.pose_hypotheses import (
    observed_pairs,
    pair_hypotheses,
    row_chunks,
    top_indices,
    vote_cells,
)
from houghloc.refine import Lines
from houghloc.segment_map import SegmentMap

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


"""Oriented line pairs in the angle index (about 100 bytes each: 1 GB): a map of up to 1,580
distinct lines; every real building here has under 400."""


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
    poses = poses[inside_map(poses, map, kinds, config.bbox_margin)]
    n_candidates = len(poses)
    if n_candidates == 0:
        where = "the neighbourhood" if near is not None else "the map"
        return GlobalResult(reason=f"no line pair gives a pose inside {where}")

    cells, votes = vote_cells(poses, config)
    walls = wall_distance(map, kinds, config.dt_cell)
    cheap = cheap_scores(cells, lines, walls, config)
    top = top_indices(cheap + 1e-6 * votes / votes.max(), config.max_hypotheses_scored)
    cells, cheap = cells[top], cheap[top]
    if cheap[0] <= 0.0:
        return GlobalResult(reason="no hypothesis puts an observed line on a wall",
                            n_candidates=n_candidates)

    sample = _subsample(len(pts), config.max_score_points)
    pts_s, members_s = pts[sample], lines.members[sample]
    scores = point_scores(cells, pts_s, members_s, walls, config)
    keep = cluster(cells, scores.score, config)[: config.max_refined]
    reach = scan_reach(pts)
    refined = [refine_hypothesis(cells[j], lines, reach, pts_s, members_s, map, walls, kinds,
                                 config) for j in keep]
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
    lo, hi = map_bbox(map, kinds)
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
        for sl in row_chunks(len(poses), len(sample)):
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
    inside = inside_map(coarse, map, kinds, config.bbox_margin)
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
    best = peaks[top_indices(f[peaks], config.slide_candidates)]
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
    found = matched_at(pose, lines, map, kinds, max_range, config)
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
    return scored_hypothesis(pose, cov, refs, matches, pts_s, members_s, map, walls, kinds,
                             max_range, config, slid=True)


def _decide(hyps: list[Hypothesis], n_candidates: int, config: GlobalMatchConfig) -> GlobalResult:
    best = hyps[0]
    tied = [h for h in hyps if h.score >= best.score - config.tie_margin]
    summary = (f"best explains {best.n_lines_explained} lines, "
               f"{100 * best.inlier_fraction:.0f}% of points on walls (score {best.score:.2f})")
    if len(tied) > 1:
        return GlobalResult(hyps, True, f"{len(tied)} hypotheses within {config.tie_margin:g} "
                            f"of the best score: keep collecting views; {summary}", n_candidates)
    return GlobalResult(hyps, False, summary, n_candidates)


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

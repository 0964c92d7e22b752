"""Step 6 of global matching: a corridor seen along its length, placed by sliding the view
along the map's lines (docs/method.md §6); only when no pair of lines fixes the pose."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from houghloc.config import GlobalMatchConfig
from houghloc.geometry import wrap_angle
from houghloc.hypothesis_scores import (
    Hypothesis,
    cluster,
    lines_on_walls,
    matched_at,
    scored_hypothesis,
)
from houghloc.map_lookup import (
    WallDistance,
    inside_map,
    map_bbox,
    map_lines_of_kinds,
    segment_spans,
    wall_distance,
)
from houghloc.match_result import (
    REFINE_COST,
    STAGE_LOOKUPS,
    GlobalResult,
    Stages,
    decide,
    subsample,
    valid,
)
from houghloc.neighbourhood import Neighbourhood
from houghloc.pose_hypotheses import row_chunks, top_indices
from houghloc.refine import Lines
from houghloc.scan_points import scan_reach
from houghloc.segment_map import SegmentMap


def slide_stages(lines: Lines, pts: NDArray, map: SegmentMap, config: GlobalMatchConfig,
                   kinds: tuple[str, ...], near: Neighbourhood | None = None) -> Stages:
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
    sample = pts[subsample(len(pts), config.slide_points)]

    def poses_at(b: NDArray, offset: NDArray, s: NDArray) -> NDArray:
        n, u = np.stack((np.cos(b), np.sin(b)), -1), np.stack((-np.sin(b), np.cos(b)), -1)
        xy = n * offset[:, None] + u * s[:, None]
        return np.column_stack((xy, wrap_angle(b - lines.theta[strong])))

    def fit(poses: NDArray, smooth: bool) -> NDArray:
        """The sample's points weighted 1 − (d / d_in)² by their distance d from the nearest
        wall: peaks where the gaps' edges coincide, where a count of the points within d_in is
        flat over ± d_in. ``smooth``: d interpolated (exact to a fraction of a cell, 4 look-ups
        a point); otherwise the cell's value, less a cell (its quantisation is not evidence)."""
        return walls.closeness(poses, sample[:, 0], sample[:, 1], config.inlier_distance, smooth)

    # the coarse grid: for each oriented map line, s where the strongest line lies on the map
    # line's segments (over the neighbourhood's only, and only the lines that put the robot
    # inside it, when one is given)
    u_all = np.stack((-np.sin(beta), np.cos(beta)), -1)
    s_lo, s_hi = (corners @ u_all.T).min(axis=0), (corners @ u_all.T).max(axis=0)
    on_line = segment_spans(map, kinds, config.inlier_distance)
    a, b = lines.s0[strong], lines.s1[strong]
    s_lo, s_hi = np.maximum(s_lo, on_line.lo - b), np.minimum(s_hi, on_line.hi - a)
    rows = np.arange(len(beta))
    if near is not None:
        n_all = np.stack((np.cos(beta), np.sin(beta)), -1)
        across = np.abs(n_all @ near.pose[:2] - (r - lines.rho[strong]))
        turn = np.abs(wrap_angle(beta - lines.theta[strong] - near.pose[2]))
        keep = (across <= near.radius_xy) & (turn <= near.radius_theta)
        if not keep.any():
            return GlobalResult(reason="sliding: no map line near the neighbourhood")
        beta, r, u_all, rows = beta[keep], r[keep], u_all[keep], rows[keep]
        centre = u_all @ near.pose[:2]
        s_lo = np.maximum(s_lo[keep], centre - near.radius_xy)
        s_hi = np.minimum(s_hi[keep], centre + near.radius_xy)
    counts = np.maximum(np.ceil((s_hi - s_lo) / config.slide_step).astype(np.intp) + 1, 0)
    which = np.repeat(np.arange(len(beta)), counts)
    step_i = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    s = s_lo[which] + step_i * config.slide_step
    coarse = poses_at(beta[which], r[which] - lines.rho[strong], s)
    inside = inside_map(coarse, map, kinds, config.bbox_margin)
    inside &= on_line.coverage(rows[which], s + a, s + b) > 0.0
    if near is not None:
        inside &= near.contains(coarse)
    coarse, which = coarse[inside], which[inside]
    if len(coarse) == 0:
        return GlobalResult(reason="sliding: no pose inside the map")
    # a pose must put a second parallel line on a wall too, as the slid poses must explain two
    # (a look-up per sample of each: a tenth of the fit's cost)
    others = lines.subset(np.flatnonzero(parallel & (np.arange(len(lines)) != strong)))
    second = np.zeros(len(coarse), bool)
    per_pose = len(others) * config.line_samples
    for sl in row_chunks(len(coarse), 2 * per_pose, STAGE_LOOKUPS):
        second[sl] = lines_on_walls(coarse[sl], others, walls, config).any(axis=1)
        yield 2 * (sl.stop - sl.start) * per_pose  # a look-up and a test per sample
    coarse, which = coarse[second], which[second]
    if len(coarse) == 0:
        return GlobalResult(reason="sliding: no pose puts two parallel lines on walls")
    # local maxima along each map line only: a plateau's neighbours would fill every slot
    f = np.empty(len(coarse))
    for sl in row_chunks(len(coarse), len(sample), STAGE_LOOKUPS):
        f[sl] = fit(coarse[sl], smooth=False)
        yield (sl.stop - sl.start) * len(sample)
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
    sample_i = subsample(len(pts), config.max_score_points)
    pts_s, members_s = pts[sample_i], lines.members[sample_i]
    # the weighted fit ranks the clusters: a plain count is flat around the true s
    keep = cluster(cells, peak_fit, config)[: config.max_refined]
    reach = scan_reach(pts)
    yield 4 * (len(fine) + 2 * len(best)) * len(sample)  # interpolated: 4 look-ups a point
    slid = [_slid(cells[j], lines, reach, pts_s, members_s, map, walls, kinds, config)
            for j in keep]
    yield REFINE_COST * len(keep) * len(pts_s)
    hyps = [h for h in slid if h is not None and valid(h, config)]
    if not hyps:
        return GlobalResult(reason="sliding: no pose explains two parallel lines",
                            n_candidates=len(coarse))
    hyps.sort(key=lambda h: -h.score)
    return decide(hyps, len(coarse), config)


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

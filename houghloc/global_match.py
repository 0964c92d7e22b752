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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.config import GlobalMatchConfig
from houghloc.hypothesis_scores import (
    cheap_scores,
    cluster,
    point_scores,
    refine_hypothesis,
)
from houghloc.map_lookup import (
    AngleIndex,
    angle_index,
    map_box,
    segment_spans,
    wall_distance,
)
from houghloc.match_result import (
    POSE_COST,
    REFINE_COST,
    GlobalResult,
    Stages,
    decide,
    subsample,
    valid,
)
from houghloc.neighbourhood import Neighbourhood
from houghloc.pose_hypotheses import (
    candidate_count,
    observed_pairs,
    pair_hypotheses,
    top_indices,
    vote_cells,
)
from houghloc.refine import Lines
from houghloc.scan_points import scan_reach
from houghloc.segment_map import SegmentMap
from houghloc.slide import slide_stages

_DEFAULT_CONFIG = GlobalMatchConfig()


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

    Every stage at once; :func:`global_match_stages` is the same match one stage per call.
    """
    return finish(global_match_stages(lines, points, map, config, kinds, near))


def finish(stages: Stages) -> GlobalResult:
    """Run a staged match's remaining stages; its result."""
    result = advance(stages, budget=math.inf)
    assert result is not None  # no budget left unspent: every stage ran
    return result


def advance(stages: Stages, budget: float) -> GlobalResult | None:
    """Run a staged match's next stages until they have cost ``budget`` look-ups; its result
    once the last one has run, else None. (Costs are counted, not timed: the same log gives
    the same stages on every machine.)"""
    spent = 0.0
    try:
        while spent < budget:
            spent += next(stages)
    except StopIteration as done:
        return done.value
    return None


def prepare_map(map: SegmentMap, config: GlobalMatchConfig = _DEFAULT_CONFIG,
                kinds: tuple[str, ...] = ("wall",)) -> None:
    """Build (and cache on the map) what matching against it looks up: the angle index of its
    line pairs, the distance transform of its walls and where its lines' segments lie; a match
    then starts at once."""
    kinds = tuple(kinds)
    if map.kind_mask(kinds).any():
        _pair_index(map, kinds, config)
        wall_distance(map, kinds, config.dt_cell)
        segment_spans(map, kinds, config.inlier_distance)


def _pair_index(map: SegmentMap, kinds: tuple[str, ...], config: GlobalMatchConfig
                ) -> AngleIndex:
    """The map's (cached) angle index, padded for the widest angle window."""
    return angle_index(map, kinds, config.min_pair_angle, config.angle_tol_max + 1e-9)


def global_match_stages(
    lines: Lines,
    points: ArrayLike,
    map: SegmentMap,
    config: GlobalMatchConfig = _DEFAULT_CONFIG,
    kinds: tuple[str, ...] = ("wall",),
    near: Neighbourhood | None = None,
) -> Stages:
    """:func:`global_match`, a stage per ``next`` (:data:`Stages`): a caller with a stream
    to keep up with spreads it over several scans (:func:`advance`), so that no scan waits for
    a whole match. The stages: hypotheses from pairs; their votes; the votes' cheap scores;
    the best cells' full scores; their refinement; then, only if the pairs gave none, the
    slide's check for a second line on a wall, its coarse grid (both in pieces of
    ``STAGE_LOOKUPS``), its fine grid, and the slid poses' refinement."""
    kinds = tuple(kinds)
    pts = _as_points(points)
    if pts is None:
        return GlobalResult(reason="points must be an N×2 array of (x, y)")
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        return GlobalResult(reason="no points")
    if not map.kind_mask(kinds).any():
        return GlobalResult(reason=f"the map has no segment of kinds {kinds}")
    if lines is None or len(lines) == 0:
        return GlobalResult(reason="no observed lines")
    if lines.members.shape[0] != len(pts):
        return GlobalResult(reason=f"the lines were extracted from {lines.members.shape[0]} "
                            f"points, not from these {len(pts)}")
    if not finite.all():  # the lines' member rows follow the points: drop both together
        pts = pts[finite]
        lines = dataclasses.replace(lines, members=lines.members[finite])

    result = yield from _match_pairs(lines, pts, map, config, kinds, near)
    if result.hypotheses or not config.slide_along_parallel:
        return result
    slid = yield from slide_stages(lines, pts, map, config, kinds, near)
    if slid.hypotheses:
        return slid
    return dataclasses.replace(result, reason=f"{result.reason}; {slid.reason}")


def _match_pairs(lines: Lines, pts: NDArray, map: SegmentMap, config: GlobalMatchConfig,
                 kinds: tuple[str, ...], near: Neighbourhood | None = None) -> Stages:
    """Steps 1–5 of the module docstring: hypotheses from pairs of non-parallel lines."""
    pair_i, pair_k = observed_pairs(lines, config)
    if len(pair_i) == 0:
        return GlobalResult(reason=f"fewer than two non-parallel observed lines (angle ≥ "
                            f"{config.min_pair_angle_deg:g}°): the pose is not determined")
    index = _pair_index(map, kinds, config)
    if len(index.delta) == 0:
        return GlobalResult(reason="the map has no two non-parallel lines")
    poses = pair_hypotheses(lines, pair_i, pair_k, index, config, near,
                            map_box(map, kinds, config.bbox_margin))
    n_candidates = len(poses)
    if n_candidates == 0:
        where = "the neighbourhood" if near is not None else "the map"
        return GlobalResult(reason=f"no line pair gives a pose inside {where}")

    yield POSE_COST * candidate_count(lines, pair_i, pair_k, index, config)
    cells, votes = vote_cells(poses, config)
    yield 2 * POSE_COST * n_candidates  # a sort
    walls = wall_distance(map, kinds, config.dt_cell)
    cheap = cheap_scores(cells, lines, walls, config)
    yield len(cells) * min(len(lines), config.cheap_lines) * config.line_samples
    top = top_indices(cheap + 1e-6 * votes / votes.max(), config.max_hypotheses_scored)
    cells, cheap = cells[top], cheap[top]
    if cheap[0] <= 0.0:
        return GlobalResult(reason="no hypothesis puts an observed line on a wall",
                            n_candidates=n_candidates)

    sample = subsample(len(pts), config.max_score_points)
    pts_s, members_s = pts[sample], lines.members[sample]
    scores = point_scores(cells, pts_s, members_s, walls, config)
    keep = cluster(cells, scores.score, config)[: config.max_refined]
    reach = scan_reach(pts)
    yield len(cells) * len(pts_s)
    refined = [refine_hypothesis(cells[j], lines, reach, pts_s, members_s, map, walls, kinds,
                                 config) for j in keep]
    yield REFINE_COST * len(keep) * len(pts_s)
    hyps = [h for h in refined if h is not None and valid(h, config)]
    if not hyps:
        return GlobalResult(reason=f"no hypothesis explains {config.min_lines_explained} "
                            "non-parallel lines", n_candidates=n_candidates)
    hyps.sort(key=lambda h: -h.score)
    final = cluster(np.array([h.pose for h in hyps]), np.array([h.score for h in hyps]), config)
    hyps = [hyps[j] for j in final]
    return decide(hyps, n_candidates, config)


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

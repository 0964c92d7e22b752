"""One scan to one pose correction: the paper's five steps, the lines' refinement
(docs/method.md §3) and the pose polished on the scan's points (§5).

    points ─▶ vote ─▶ peaks ─▶ refine ─▶ associate with the map ─▶ displacement ─▶ polish ─▶ pose

This is where a scan becomes a pose. Everything here is a pure function of its arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from houghloc.config import HoughConfig, derived
from houghloc.displacement import (
    UNOBSERVED_VARIANCE,
    Displacement,
    estimate_displacement,
    match_and_solve,
)
from houghloc.geometry import TWO_PI, inverse_3x3, inverse_small, wrap_scalar
from houghloc.jit import njit
from houghloc.map_lookup import wall_cells
from houghloc.matching import Matches, gate_threshold, reassociate
from houghloc.peaks import _peaks_kernel, find_peaks
from houghloc.polish import polish_fix
from houghloc.refine import Lines, _refine_kernel
from houghloc.scan_points import clean_points, scan_reach, what_was_dropped
from houghloc.segment_map import References, SegmentMap
from houghloc.transform import HoughGrid, _vote_kernel, make_grid, vote

_DEFAULT_CONFIG = HoughConfig()
_EYE3 = np.eye(3)


@dataclass
class ScanCorrection:
    """The result of :func:`localize_scan`.

    ``pose`` = guess + ``delta`` (map frame, θ wrapped); ``cov`` its covariance from the matches
    alone (the guess's own uncertainty is not folded in: a filter does that), with
    ``UNOBSERVED_VARIANCE`` along the ``unobservable`` directions; ``rank`` the number of
    observable directions (3: full pose; 2: a corridor; 0: nothing matched). ``ambiguous`` and
    ``reason`` say why the result should not be trusted, or why it is empty. The intermediate
    stages (accumulator, observed lines, references, matches) are kept for inspection.
    """

    guess: NDArray[np.float64]
    pose: NDArray[np.float64]
    delta: NDArray[np.float64]
    cov: NDArray[np.float64]
    information: NDArray[np.float64]
    rank: int
    observable: NDArray[np.float64]
    unobservable: NDArray[np.float64]
    matches: Matches | None
    ambiguous: bool
    reason: str
    n_points: int = 0
    grid: HoughGrid | None = None
    accumulator: NDArray[np.int32] | None = None
    lines: Lines | None = None
    references: References | None = None
    matched_map_lines: NDArray[np.intp] = field(default_factory=lambda: np.empty(0, np.intp))

    @property
    def ok(self) -> bool:
        """A full, unambiguous pose fix."""
        return self.rank == 3 and not self.ambiguous


def _empty(guess: NDArray, reason: str, **stages) -> ScanCorrection:
    return ScanCorrection(guess, guess.copy(), np.zeros(3), np.eye(3) * UNOBSERVED_VARIANCE,
                          np.zeros((3, 3)), 0, np.zeros((3, 0)), np.eye(3), None, False, reason,
                          **stages)


def observe_lines(points: NDArray[np.float64], config: HoughConfig
                  ) -> tuple[HoughGrid, NDArray[np.int32], Lines]:
    """Steps 2–3 and the refinement: vote, find peaks, refine them to lines (strongest first)."""
    grid = make_grid(config)
    if config.refine:  # the usual case: the three steps in one compiled call
        pts = np.ascontiguousarray(points, dtype=float)
        unit = config.range_sigma_growth <= 0
        weights = _NO_WEIGHTS if unit else point_weights(pts, config)
        grid_args, refine_args = derived(config, "observe_lines", lambda: _observe_args(config))
        acc, *found = _observe_kernel(
            pts, weights, unit, *grid_args,
            max(config.peak_min_votes, math.ceil(config.peak_fraction * len(pts))), *refine_args)
        lines = Lines(*found)
    else:
        acc = vote(points, grid)
        peaks = find_peaks(acc, len(points), config, limit=2 * config.max_peaks)
        theta0, rho0 = grid.cell_center(peaks.i_theta, peaks.i_rho)
        lines = _grid_lines(points, theta0, rho0, peaks.votes, grid)
    if len(lines) > config.max_peaks:
        lines = lines.subset(np.argsort(-lines.n, kind="stable")[: config.max_peaks])
    return grid, acc, lines


_NO_WEIGHTS = np.empty(0)


def _observe_args(config: HoughConfig) -> tuple[tuple, tuple]:
    """:func:`_observe_kernel`'s arguments that depend on the configuration alone: those before
    the peaks' vote threshold and those after it."""
    grid = make_grid(config)
    return ((grid.half_trig32, grid.signed_cells, grid.margin_cells, grid.n_rho, grid.theta_step,
             grid.rho_step, grid.rho_min),
            (config.nms_theta_cells, config.nms_rho_cells, 2 * config.max_peaks,
             config.refine_max_band or config.rho_step, config.refine_iterations,
             config.refine_band_sigmas, config.refine_min_band, config.theta_step, config.rho_step,
             config.piece_gap, config.min_piece_points, config.min_line_length,
             config.max_line_sigma, config.point_sigma_floor, config.line_theta_floor,
             config.line_rho_floor))


def point_weights(points: NDArray[np.float64], config: HoughConfig) -> NDArray[np.float64]:
    """Each point's weight 1/σᵢ², relative (mean 1), for a sensor whose noise grows with range
    (σᵢ = σ₀ + k·dᵢ², ``range_sigma_base`` and ``range_sigma_growth``); all 1 for a laser."""
    if config.range_sigma_growth <= 0:
        return np.ones(len(points))
    sigma = config.range_sigma_base + config.range_sigma_growth * (points**2).sum(axis=1)
    weights = 1.0 / sigma**2
    return weights * (len(weights) / weights.sum())


def polish_weights(points: NDArray[np.float64], config: HoughConfig
                   ) -> NDArray[np.float64] | None:
    """The points' weights for :mod:`houghloc.polish`: None (equal weights, its fast path) for a
    laser, :func:`point_weights` for a sensor whose noise grows with range."""
    return None if config.range_sigma_growth <= 0 else point_weights(points, config)


@njit
def _observe_kernel(points: NDArray, weights: NDArray, unit: bool, half_trig32: NDArray,
                    signed_cells: int, margin_cells: int, n_rho: int, cell_theta: float,
                    cell_rho: float, rho_min: float, threshold: int, nms_theta: int,
                    nms_rho: int, limit: int, max_band: float, iterations: int,
                    band_sigmas: float, min_band: float, theta_step: float, rho_step: float,
                    piece_gap: float, min_piece_points: int, min_line_length: float,
                    max_line_sigma: float, point_sigma_floor: float, theta_floor: float,
                    rho_floor: float) -> tuple:
    """:func:`vote`, :func:`find_peaks`, the peak cells' centres (the grid's cells are
    ``cell_theta`` × ``cell_rho``) and :func:`houghloc.refine.refine_lines` as one compiled call,
    through the same kernels: a scan's arrays cross into Python once."""
    acc = np.empty((2 * half_trig32.shape[1], n_rho), np.int32)
    _vote_kernel(points, half_trig32, signed_cells, margin_cells, acc)
    i_theta, i_rho, _ = _peaks_kernel(acc, threshold, nms_theta, nms_rho, limit)
    theta0 = i_theta * cell_theta  # HoughGrid.cell_center
    rho0 = rho_min + (i_rho + 0.5) * cell_rho
    w = np.ones(points.shape[0]) if unit else weights
    theta, rho, cov, n, sigma, s0, s1, members = _refine_kernel(
        points, w, unit, theta0, rho0, max_band, iterations, band_sigmas, min_band, theta_step,
        rho_step, piece_gap, min_piece_points, min_line_length, max_line_sigma,
        point_sigma_floor, theta_floor, rho_floor)
    return acc, theta, rho, cov, n, sigma, s0, s1, members


def localize_scan(
    points_xy: ArrayLike,
    map: SegmentMap,
    guess: ArrayLike,
    config: HoughConfig = _DEFAULT_CONFIG,
    pose_cov: ArrayLike | None = None,
    observed: tuple[HoughGrid, NDArray[np.int32], Lines] | None = None,
) -> ScanCorrection:
    """Correct ``guess`` (x, y, θ) with the robot-frame points of one scan (docs/method.md §1–5).

    ``pose_cov`` is the guess's covariance (e.g. the filter's); it sets the matching gates.
    Without it the guess is assumed good to ``guess_sigma_xy`` and ``guess_sigma_theta_deg``.
    ``observed``: :func:`observe_lines` of these points with this ``config``, when the same scan
    is matched from several guesses (the lines do not depend on the guess).
    Bad input never raises on content: empty, non-finite or structureless scans give an empty
    result with a reason. A wrongly shaped array or a non-finite guess raises ``ValueError``.
    """
    guess = _checked_guess(guess)
    points, n_dropped = clean_points(points_xy)
    dropped = f" ({n_dropped} {what_was_dropped(points_xy)} dropped)" if n_dropped else ""
    if len(points) < config.peak_min_votes:
        return _empty(guess, f"too few points: {len(points)}{dropped}", n_points=len(points))

    grid, acc, lines = observed if observed is not None else observe_lines(points, config)
    stages: dict[str, Any] = {"n_points": len(points), "grid": grid, "accumulator": acc,
                              "lines": lines}
    if len(lines) == 0:
        return _empty(guess, f"no line in the scan{dropped}", **stages)
    max_range = config.max_range or scan_reach(points)
    refs = map.references(guess, max_range, config.reference_kinds, config.visibility_rays)
    stages["references"] = refs
    if len(refs) == 0:
        return _empty(guess, "no map line within range of the guess", **stages)

    if pose_cov is None:
        prior = _default_prior(config.guess_sigma_xy, config.guess_sigma_theta)
    else:
        prior = np.asarray(pose_cov, dtype=float)
        if prior.shape != (3, 3) or not np.isfinite(prior).all():
            raise ValueError("pose_cov must be a finite 3×3 matrix")
    base = np.zeros(3)  # the matches' residuals are relative to guess + base
    matches, disp = match_and_solve(lines, refs, guess, prior, config)
    offset = disp.delta
    for _ in range(config.match_iterations - 1):
        if disp.rank == 0 or len(matches.ambiguous_lines) == 0:
            break  # nothing left to resolve: the estimate is linear, one solve is exact
        # re-match with the prior sharpened by this scan's information: the gates shrink and
        # lines that fitted two references may now fit one. (P⁻¹ + Λ)⁻¹ = (I + PΛ)⁻¹P holds for
        # a singular P too.
        cov = inverse_3x3(_EYE3 + prior @ disp.information) @ prior
        matches = reassociate(matches, lines, refs, _apply(guess, offset), offset - base, cov,
                              config)
        base = offset
        disp = estimate_displacement(matches, refs.beta[matches.ref], config.max_observable_sigma)
        offset = base + disp.delta
    pose = _apply(guess, offset)
    if len(matches) == 0:
        reason = "; ".join(matches.reasons) or "no observed line matches the map"
        return _empty(guess, reason, **stages) if not matches.reasons else _flagged(
            guess, reason, matches, stages)

    # A line inconsistent with the others (obstacle points joined to a wall, a chance alignment)
    # shows in the post-fit χ². While there is redundancy to tell, drop the worst and re-solve.
    limit = config.max_outlier_lines
    while (disp.dof > 0 and disp.chi2 > gate_threshold(config.gate_probability, disp.dof)
           and len(matches) >= 3 and limit > 0):
        worst = int(np.argmax(disp.per_match))
        trial = matches.without(worst)
        redo = estimate_displacement(trial, refs.beta[trial.ref], config.max_observable_sigma)
        if redo.rank < disp.rank:
            break
        offset, matches, disp, limit = base + redo.delta, trial, redo, limit - 1
        pose = _apply(guess, offset)
    # Doubts make the result ambiguous. Lines with two candidate references were left out, not
    # guessed; with a decisive margin set (real maps model one wall by pieces a few degrees
    # apart, and a far wall then fits both) they do not make a full fix doubtful: they stay in
    # the reason as a note.
    lenient = config.decisive_d2_margin is not None and disp.rank == 3
    notes = list(matches.reasons) if lenient else []
    doubts = [] if lenient else list(matches.reasons)
    if disp.dof > 0 and disp.chi2 > gate_threshold(config.gate_probability, disp.dof):
        doubts.append(f"matched lines disagree (χ² {disp.chi2:.1f} on {disp.dof} dof)")
    # The correction must be plausible given both uncertainties: Δᵀ (P + C)⁻¹ Δ in the observable
    # directions, against the χ² gate (a filter will run the same test on its innovation).
    wrapped = _wrapped(offset)
    distance = _correction_distance(wrapped, prior, disp.cov, disp.observable)
    if distance > gate_threshold(config.gate_probability, disp.rank):
        doubts.append("correction far outside the guess's uncertainty")
    rank_note = [] if disp.rank == 3 else [
        f"rank {disp.rank}: unobservable along "
        + ", ".join(_direction_name(v) for v in disp.unobservable.T)]
    ambiguous = bool(doubts) or (len(matches.ambiguous_lines) > 0 and not lenient)
    cov, information = disp.cov, disp.information
    polished = _polished(points, map, pose, disp, config)
    if polished is not None:
        pose, cov, information = polished
        wrapped = _wrapped(np.array([pose[0] - guess[0], pose[1] - guess[1],
                                     pose[2] - guess[2]]))
    return ScanCorrection(
        guess, pose, wrapped, cov, information, disp.rank, disp.observable,
        disp.unobservable, matches, ambiguous, "; ".join(rank_note + doubts + notes),
        n_points=len(points), grid=grid, accumulator=acc, lines=lines, references=refs,
        matched_map_lines=refs.line[matches.ref])


@njit
def _correction_distance(step: NDArray, prior: NDArray, fix_cov: NDArray, basis: NDArray
                         ) -> float:
    """(Bᵀs)ᵀ (BᵀCB)⁻¹ (Bᵀs), C = P + C_fix: the squared Mahalanobis length of ``step`` in the
    directions of ``basis`` B (3×k) under both uncertainties; sᵀC⁻¹s when B spans the pose."""
    cov = prior + fix_cov
    if basis.shape[1] == 3:
        return float(step @ inverse_3x3(cov) @ step)
    transposed = np.ascontiguousarray(basis.T)
    reduced = transposed @ cov @ basis
    seen = transposed @ step
    return float(seen @ (inverse_small(reduced) @ seen))


def _checked_guess(guess: ArrayLike) -> NDArray[np.float64]:
    """(x, y, θ) as floats with θ wrapped, or ``ValueError``."""
    values = np.asarray(guess, dtype=float).reshape(-1)
    if values.shape == (3,):
        x, y, theta = values.tolist()
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(theta):
            return np.array([x, y, wrap_scalar(theta)])
    raise ValueError(f"guess must be three finite numbers (x, y, θ), got {values!r}")


def _polished(points: NDArray, map: SegmentMap, pose: NDArray, disp: Displacement,
              config: HoughConfig) -> tuple[NDArray, NDArray, NDArray] | None:
    """The fix polished on the scan's points (:mod:`houghloc.polish`), in the directions it
    observed, kept within the lines' own χ² gate: its pose, covariance and information; None
    where the points do not pin it or disagree with the lines."""
    if config.polish_gate is None or disp.rank < 2:
        return None
    cells = wall_cells(map, config.reference_kinds, config.polish_gate)
    found = polish_fix(points, polish_weights(points, config), cells, pose, disp.cov,
                       disp.observable, disp.unobservable,
                       gate_threshold(config.gate_probability, disp.rank), UNOBSERVED_VARIANCE,
                       config)
    if found is None:
        return None
    polished, cov, information = found
    polished[2] = wrap_scalar(polished[2])
    return polished, cov, information


def _flagged(guess: NDArray, reason: str, matches: Matches, stages: dict) -> ScanCorrection:
    out = _empty(guess, reason, **stages)
    out.matches = matches
    out.ambiguous = True
    return out


def _apply(guess: NDArray, offset: NDArray) -> NDArray:
    return np.array([guess[0] + offset[0], guess[1] + offset[1],
                     wrap_scalar(guess[2] + offset[2])])


def _wrapped(offset: NDArray) -> NDArray:
    return np.array([offset[0], offset[1], wrap_scalar(offset[2])])


@lru_cache(maxsize=8)
def _default_prior(sigma_xy: float, sigma_theta: float) -> NDArray[np.float64]:
    prior = np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2])
    prior.flags.writeable = False  # shared between calls
    return prior


def _direction_name(v: NDArray) -> str:
    return f"({v[0]:+.2f}, {v[1]:+.2f}) in x, y"


def _grid_lines(points: NDArray, theta: NDArray, rho: NDArray, votes: NDArray,
                grid: HoughGrid) -> Lines:
    """Peaks as lines at their cell centres with the grid's uniform-quantisation covariance
    (δ²/12): the paper's precision, for comparison with the refinement."""
    k = len(theta)
    cov = np.zeros((k, 2, 2))
    cov[:, 0, 0] = grid.theta_step**2 / 12.0
    cov[:, 1, 1] = grid.rho_step**2 / 12.0
    normal = np.vstack((np.cos(theta), np.sin(theta)))
    members = np.abs(points @ normal - rho) <= grid.rho_step
    along = points @ np.vstack((-normal[1], normal[0]))
    s0 = np.where(members, along, np.inf).min(axis=0)
    s1 = np.where(members, along, -np.inf).max(axis=0)
    return Lines(theta % TWO_PI, rho, cov, votes.astype(np.int64), np.full(k, grid.rho_step),
                 np.where(np.isfinite(s0), s0, 0.0), np.where(np.isfinite(s1), s1, 0.0), members)

"""Settings of the Hough method and of global set matching, validated with pydantic (units in the
names; radians inside)."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

MAX_ACCUMULATOR_CELLS = 10_000_000
"""Cells of one Hough accumulator (40 MB of int32): 0.1° × 1 cm to ±20 m is 1.4 million."""

T = TypeVar("T")
_DERIVED: dict[int, tuple[BaseModel, dict[str, Any]]] = {}
_DERIVED_CONFIGS = 32  # configurations remembered (a sweep's tasks each have one)
_DERIVED_LOCK = threading.Lock()


def derived(config: BaseModel, name: str, build: Callable[[], T]) -> T:
    """``build()``, a value computed from the (frozen) ``config`` alone, once per configuration
    object: the per-scan code asks for the same settings at every scan, and computing them
    (properties, χ² quantiles, tuples of a dozen fields) cost more than the compiled work they
    feed. Keyed by the object's identity, which it keeps alive while remembered; not stored on
    the object, since ``model_copy`` would carry it over to a changed copy."""
    entry = _DERIVED.get(id(config))
    if entry is None or entry[0] is not config:
        with _DERIVED_LOCK:
            if len(_DERIVED) >= _DERIVED_CONFIGS:
                del _DERIVED[next(iter(_DERIVED))]
            entry = _DERIVED[id(config)] = (config, {})
    values = entry[1]
    if name not in values:
        values[name] = build()
    return values[name]


class HoughConfig(BaseModel):
    """Grid, peaks, refinement and matching settings. Defaults: the paper's 3° × 10 cm grid.

    The grid only needs to separate lines (docs/method.md §2); precision comes from the refinement.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # --- grid and voting (docs/method.md §2)
    theta_step_deg: float = Field(3.0, gt=0.0, le=45.0, description="° between the grid's θ "
                                  "cells (the paper's 3°: the grid only separates lines)")
    rho_step: float = Field(0.10, gt=0.0, description="m between the grid's ρ cells")
    rho_max: float = Field(20.0, gt=0.0, description="m; votes beyond are dropped")
    rho_margin_cells: int = Field(
        2, ge=0, le=10, description="negative-ρ cells kept: lines through the sensor (ρ ≈ 0) "
        "vote on both sides of the θ ↔ θ+π identity, and noise pushes some votes below zero")
    # --- peaks
    peak_fraction: float = Field(0.04, gt=0.0, lt=1.0, description="fraction of the scan's "
                                 "points a peak needs (or peak_min_votes, the larger)")
    peak_min_votes: int = Field(8, ge=2, description="points a peak needs at least (and a scan, "
                                "to be matched at all)")
    nms_theta_cells: int = Field(2, ge=1, description="half-width in θ cells of the window a "
                                 "peak must be the maximum of")
    nms_rho_cells: int = Field(2, ge=1, description="half-width in ρ cells of the suppression "
                               "window")
    max_peaks: int = Field(16, ge=1, description="lines kept per scan, the best supported first")
    # --- refinement (docs/method.md §3)
    refine: bool = Field(True, description="refine peaks to lines by total least squares "
                         "(false: the grid cell's centre, the paper's precision)")
    refine_iterations: int = Field(2, ge=1, description="total-least-squares refits, each on the "
                                   "points within the band of the last fit")
    refine_band_sigmas: float = Field(4.0, gt=0.0, description="the band's half-width, in σ of "
                                      "the points about the line")
    refine_min_band: float = Field(0.03, gt=0.0, description="m; least half-width of the band "
                                   "of points a line is refitted on")
    refine_max_band: float | None = Field(
        None, gt=0.0, description="m; None: one ρ cell (noisier sensors need more)"
    )
    piece_gap: float = Field(0.5, gt=0.0, description="m; a larger gap splits a line into pieces")
    min_piece_points: int = Field(5, ge=2, description="points a piece of line needs")
    min_line_length: float = Field(0.6, ge=0.0, description="m; shorter pieces are not lines")
    max_line_sigma: float = Field(0.05, gt=0.0, description="m; rougher fits are not lines")
    point_sigma_floor: float = Field(0.003, gt=0.0, description="m; floor on the fitted σ")
    # Sensors whose noise grows with range (a camera's triangulation: σ = σ₀ + k·d²) weight each
    # point by 1/σ²; 0 means uniform noise (a laser), and no weighting.
    range_sigma_growth: float = Field(0.0, ge=0.0, description="k in σ = σ₀ + k·d², 1/m")
    range_sigma_base: float = Field(0.01, gt=0.0, description="σ₀ in σ = σ₀ + k·d², m")
    # A map's segment is no exact wall: built from scans it is off by its mapper's error, and a
    # wall drawn as one line is rarely straight to a centimetre. A simulated map is exact: 0.
    line_theta_floor_deg: float = Field(
        0.5, ge=0.0, description="σ of a line's θ that no fit removes: the map's model error")
    line_rho_floor: float = Field(
        0.02, ge=0.0, description="m; σ of a line's ρ that no fit removes: the map's model error")
    # --- map references (docs/method.md §4)
    max_range: float | None = Field(None, gt=0.0, description="m; None: from the points")
    reference_kinds: tuple[str, ...] = Field(
        ("wall",), description="map segment kinds this sensor sees (a camera also sees lines)")
    visibility_rays: int = Field(180, ge=8, description="rays cast around the guess to find the "
                                 "map lines in view (once per map cell, memoised)")
    # --- correspondence and displacement (docs/method.md §5)
    guess_sigma_xy: float = Field(0.15, gt=0.0, description="m; prior when no covariance given")
    guess_sigma_theta_deg: float = Field(5.0, gt=0.0, description="°; prior when no covariance "
                                         "given")
    gate_probability: float = Field(
        0.9999, gt=0.5, lt=1.0, description="χ²(2) probability that a line's right reference "
        "falls inside its match gate")
    extent_margin: float = Field(0.1, ge=0.0, description="m of slack on segment extents")
    min_extent_coverage: float = Field(
        0.6, gt=0.0, le=1.0, description="fraction of an observed piece that must lie on segments"
    )
    match_iterations: int = Field(2, ge=1, description="re-match at the corrected pose")
    decisive_d2_margin: float | None = Field(
        6.0, gt=0.0, description="a line whose best reference beats the others' Mahalanobis d² "
        "by this much takes it (real maps model one wall by near-duplicate pieces), and lines "
        "still ambiguous are left out of a full fix without flagging it; None: any second "
        "candidate in the gate is ambiguous and flags the fix")
    nearest_neighbour_only: bool = Field(
        False, description="the paper's plain rule: take the nearest reference even when "
        "several fit (for comparison; it locks onto the wrong one of parallel lines)")
    max_outlier_lines: int = Field(
        2, ge=0, description="inconsistent matches that may be dropped when redundancy allows"
    )
    max_observable_sigma: float = Field(
        0.5, gt=0.0, description="m; a direction known worse than this is reported unobservable"
    )
    # --- the fix polished on the scan's points (docs/method.md §5)
    polish_gate: float | None = Field(
        0.12, gt=0.0, description="m; a point farther than this from every wall of the map at the "
        "fix is not on one (clutter, a passer-by) and stays out of the polish; None: the fix as "
        "the lines give it")

    @model_validator(mode="after")
    def _grid_fits_in_memory(self) -> HoughConfig:
        # the accumulator holds θ over 2π and ρ over ±rho_max: refuse a grid of gigabytes
        cells = math.ceil(360.0 / self.theta_step_deg) * (
            2 * math.ceil(self.rho_max / self.rho_step) + 2 * self.rho_margin_cells)
        if cells > MAX_ACCUMULATOR_CELLS:
            raise ValueError(
                f"the Hough grid would have {cells:,} cells (θ every {self.theta_step_deg:g}°, "
                f"ρ every {self.rho_step:g} m to {self.rho_max:g} m), more than the "
                f"{MAX_ACCUMULATOR_CELLS:,} allowed: coarsen theta_step_deg or rho_step")
        # the peaks' suppression window wraps around θ once: it must not span the circle
        n_theta = 2 * max(2, round(math.pi / self.theta_step))  # the grid's rows (transform)
        if 2 * self.nms_theta_cells + 1 > n_theta:
            raise ValueError(
                f"nms_theta_cells = {self.nms_theta_cells}: the peaks' window "
                f"({2 * self.nms_theta_cells + 1} rows) would be wider than the grid's {n_theta} "
                f"θ rows (every {self.theta_step_deg:g}°); at most {(n_theta - 1) // 2}")
        return self

    @property
    def theta_step(self) -> float:
        return math.radians(self.theta_step_deg)

    @property
    def line_theta_floor(self) -> float:
        return math.radians(self.line_theta_floor_deg)

    @property
    def guess_sigma_theta(self) -> float:
        return math.radians(self.guess_sigma_theta_deg)


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

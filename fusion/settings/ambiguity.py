"""The ambiguity manager's settings: when tracking is given up, how views are collected, how a
pose found is judged. Every field's meaning is in its description (houghloc config
--reference); why each default is what it is: docs/experiments.md.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from fusion.settings.hypotheses import HypothesisConfig
from houghloc.config import GlobalMatchConfig


class AmbiguityConfig(BaseModel):
    """When to stop trusting the tracker, and how to find the pose again."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_scans_without_fix: int = Field(
        25, ge=1, description="consecutive scans rejected, ambiguous or unmatched (with "
        "through_wall_scans None, or a sensor that does not see walls)")
    # A scan without a usable fix is no evidence against the belief when its points land where
    # the map has nothing (a room it lacks, furniture, people): the filter carries on by
    # odometry. A scan seen through the map's walls from the belief contradicts it (a right
    # pose sees through walls only by glass and doors the map has closed).
    through_wall_scans: float | None = Field(
        4.0, gt=0.0, description="tracking is given up when the scans without a usable fix "
        "since the last one have seen, together, this many scans' worth of points through the "
        "map's walls from the belief (each counts the fraction of its points beyond a wall by "
        "more than global_match.visibility_margin); None: after max_scans_without_fix of "
        "them, whatever they show")
    max_position_sigma_fraction: float | None = Field(
        None, gt=0.0, description="σ_xy beyond this fraction of the closest parallel-line "
        "spacing makes nearest-neighbour matching unsafe (None: no such check; on a real map "
        "the spacing of two pieces of one wall is centimetres)")
    min_views: int = Field(5, ge=1, description="views accumulated before a global match")
    max_views: int = Field(30, ge=1, description="sliding window of accumulated views")
    view_spacing: float = Field(
        0.03, ge=0.0, description="m travelled (or view_spacing_deg turned) between views: a "
        "robot standing still adds no evidence")
    view_spacing_deg: float = Field(2.0, ge=0.0, description="° turned between views")
    max_points: int = Field(4000, ge=100, description="accumulated points kept (subsampled)")
    match_lookups_per_scan: int = Field(
        500_000, ge=1, description="work of a global match done per scan, in distance look-ups "
        "(5–10 ms): a match spreads over as many scans as it needs, so that no scan waits for "
        "a whole one")
    reinit_sigma_xy: float = Field(0.05, gt=0.0, description="m, floor on the new covariance")
    reinit_sigma_theta_deg: float = Field(1.0, gt=0.0, description="°, floor on the new "
                                          "covariance")
    failures_until_lost: int = Field(3, ge=1, description="global matches without a decisive "
                                     "pose before the state says lost (and retries back off)")
    retry_every: int = Field(3, ge=1, description="scans between global attempts")
    # A fix that puts the scan where the map has no walls is not used, however well it passes
    # the filter's gate: a single matched line (rank 2) after a kidnap can steer the heading
    # wherever the odometry drifts while every innovation stays small.
    misfit_ratio: float = Field(
        0.5, ge=0.0, le=1.0, description="a fix with a fraction of points on walls below this "
        "times the recent typical fraction is a misfit (0 turns the check off)")
    fit_window: int = Field(20, ge=3, description="recent used fixes that set the typical fit")
    # The scan's own points on the map's walls judge a fix that the matcher alone cannot: two
    # lines of a corner matched to the wrong walls pass every gate yet move the scan off the
    # walls; a single-line fix that puts clearly more points on walls than the guess corrects a
    # slip (the measurements: docs/experiments.md, "The fit of a scan on the walls").
    max_fit_loss: float | None = Field(
        0.03, ge=0.0, le=1.0, description="a fix whose fraction of points on walls is below "
        "the guess's by more than this is a misfit (None: no such check)")
    min_fit_gain: float | None = Field(
        0.03, ge=0.0, le=1.0, description="a fix from too few lines, or flagged ambiguous, is "
        "used when its fraction on walls beats the guess's by this much (None: never)")
    # A robot whose predicted pose keeps the scan on the walls as well as when fixes were
    # accepted is not lost, however many scans the matcher cannot use (a wall modelled a degree
    # off makes two lines "disagree" for seconds): such scans do not count towards
    # max_scans_without_fix.
    hold_fit_ratio: float | None = Field(
        0.9, gt=0.0, le=1.0, description="a scan without a fix whose guess has at least this "
        "times the recent accepted scans' fraction on walls does not count as a failure")
    # After a kidnap the pose is more plausibly near where the robot was last known to be than
    # across the building: a displacement prior N(0, σ²) about the last belief (carried by
    # odometry) weighs the followed poses where the views cannot tell them apart. Without such a
    # pose (global start) nothing changes.
    kidnap_prior_sigma: float | None = Field(
        2.0, gt=0.0, description="m; scale of a plausible kidnap (None: never use the prior)")
    kidnap_probability: float = Field(
        0.01, gt=0.0, le=1.0, description="how plausible a pose far beyond the kidnap scale is "
        "next to one where the odometry says the robot is (the displacement prior's floor)")
    # When tracking fails and the prediction no longer fits the scan (guess fit below
    # hold_fit_ratio of the recent ones), the scan's own lines are matched to the map's within a
    # neighbourhood of the dead-reckoned pose before the filter is given up: a wheel slip or a
    # motion the odometry did not report (driving backwards) leaves the robot near it, where the
    # rest of the building cannot compete.
    local_search_xy: float | None = Field(
        1.0, gt=0.0, description="m; radius of the local re-search (None: no local search)")
    local_search_theta_deg: float = Field(
        20.0, gt=0.0, le=180.0, description="°; heading range of the local re-search, at "
        "least (wider when the guess's heading σ is: as far as hough.gate_probability reaches)")
    # What keeps a wrong pose out is a rival, not a level: how much of a scan lies on walls
    # at the right pose varies from room to room (clutter), a margin over every other pose in
    # the neighbourhood does not (docs/experiments.md, "The local re-search").
    local_fit_gain: float = Field(
        0.1, ge=0.0, le=1.0, description="the pose found must put this much more of the scan's "
        "points on walls than the guess ...")
    local_min_fit: float = Field(
        0.5, ge=0.0, le=1.0, description="... at least this times the recent accepted "
        "scans' fraction ...")
    local_rival_margin: float = Field(
        0.1, ge=0.0, le=1.0, description="... and beat every other pose found in the "
        "neighbourhood by this much")
    # A scan that fits nowhere well (a person in front of the laser, a blurred turn) can lead the
    # re-search to a wrong pose that merely fits it a little better: shortly after a used fix the
    # odometry cannot have slipped far, so a pose found is accepted only within reach of the
    # motion since that fix (a reversal the wheels report as forward motion errs by twice it).
    # The heading is not limited: slips in turns are what it recovers.
    local_reach_base: float = Field(
        0.25, gt=0.0, description="m; the pose found may be this far from the guess ...")
    local_reach_per_metre: float | None = Field(
        2.0, gt=0.0, description="... plus this times the distance the odometry moved since the "
        "last accepted fix (None: anywhere within local_search_xy)")
    global_match: GlobalMatchConfig = GlobalMatchConfig()
    hypotheses: HypothesisConfig = Field(
        HypothesisConfig(), description="how a global match's poses are followed, each with "
        "its own filter, until the scans keep fitting one")

"""The hypothesis bank's settings (:mod:`fusion.hypotheses`): how proposed poses are followed
and chosen."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

RECENT_FITS = 10
"""Fits kept per hypothesis, for the verdict's recent mean."""


class HypothesisConfig(BaseModel):
    """How proposed poses are followed and chosen."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_hypotheses: int = Field(
        8, ge=1, description="a global match's best poses followed at once (each costs a Hough "
        "fix per scan)")
    accept_probability: float = Field(
        0.95, gt=0.5, lt=1.0, description="a hypothesis whose weight reaches this is the pose "
        "(19 : 1 against all others together)")
    prune_probability: float = Field(
        1e-3, gt=0.0, lt=0.5, description="a hypothesis whose weight falls below this is dropped")
    merge_probability: float = Field(
        0.99, gt=0.5, lt=1.0, description="two hypotheses within this χ²(3) quantile of their "
        "joint covariance are one pose")
    # How a scan's points fall at the right pose: on the maps of the six buildings of the
    # benchmark (their own and the held-out ones), at the reference poses, 0.28–0.93 of them
    # lie on a wall seen directly and 0.01–0.09 behind one (0.68 and 0.046 pooled;
    # docs/experiments.md). Rounded: they are what a laser meets in an office, not one log's.
    hit_probability: float = Field(
        0.7, gt=0.0, lt=1.0, description="share of a scan's points that lie on a wall the "
        "robot sees directly, at the right pose (within global_match.inlier_distance)")
    through_probability: float = Field(
        0.05, gt=0.0, lt=1.0, description="share of a scan's points seen through a wall at "
        "the right pose (glass, doors the map has closed, wall ends): a pose that sees more "
        "through walls is unlikely, and one whose recent scans see more than this, beyond "
        "their binomial noise at accept_probability, is not taken")
    # Where the map does not show what the scan sees at the reference pose (the benchmark's
    # uncovered poses on held-out maps), 0.03–0.31 of the points still lie on a wall and
    # 0.003–0.06 behind one (0.135 and 0.022 pooled); the held-out maps show it at 0.49–0.95 of
    # the poses (0.66 pooled).
    mapped_probability: float = Field(
        0.65, gt=0.0, lt=1.0, description="probability that the map shows what the robot sees "
        "where it is (else it is in a room the map lacks, and its scans land on nothing)")
    unmapped_hit_probability: float = Field(
        0.15, gt=0.0, lt=1.0, description="share of a scan's points on a wall the robot sees "
        "directly where the map does not show its surroundings")
    unmapped_through_probability: float = Field(
        0.02, gt=0.0, lt=1.0, description="share of a scan's points seen through a wall where "
        "the map does not show the robot's surroundings")
    # A mapped wall may not stop the laser: glass, a door the map shows closed. Seen through
    # onto the walls beyond it, it is one fact about the building, not new evidence with
    # every scan: a followed pose takes it for glass once, at this prior's cost, and sees
    # through it from then on; its points seen through onto nothing stay evidence against it.
    glass_probability: float = Field(
        0.05, gt=0.0, lt=1.0, description="prior probability that a mapped wall does not stop "
        "the laser (glass, a door the map shows closed): a followed pose may take a wall for "
        "one, once, at this cost, when its scan's points seen through the wall onto walls "
        "beyond it outweigh it")
    min_scans: int = Field(
        2, ge=1, le=RECENT_FITS, description="weighed scans a hypothesis needs before it may be "
        "taken: the match's own views are what proposed it")
    fit_quantile: float = Field(
        0.05, ge=0.0, lt=1.0, description="the pose taken must put as many of its scans' points "
        "on walls as all but this fraction of tracking's accepted scans did, within the "
        "sampling noise of its recent fits: when no proposed pose is right, the best of them "
        "still gets most of the weight")
    independent_points: float = Field(
        30.0, gt=0.0, description="independent observations a scan is worth: L = Π_c p_c^(n s_c) "
        "over the shares s_c of its points on walls, through them and neither")
    unexplained_scan_probability: float | None = Field(
        0.05, gt=0.0, lt=1.0, description="how often a scan taken at the right pose fits the "
        "map no better than at a wrong one (furniture moved, a room the map lacks): no scan "
        "weighs more than 1/this against a pose (None: unbounded)")
    # A scan is worth n independent observations only against a view the bank has not weighed
    # yet. Scans a few centimetres apart see the same pane of glass, door jamb or desk from
    # nearly the same place and err together: weighed every 0.1 m, one pane seen along half a
    # metre took a look-alike door one module on at 0.96, and 5 of 65 poses taken on the
    # development seeds were wrong where the weights promised 1.2 (docs/experiments.md). A
    # laser's view changes over about a doorway's width.
    update_distance: float = Field(
        0.6, ge=0.0, description="m travelled (or update_angle_deg turned) between weight "
        "updates: scans closer together repeat one observation (about a doorway's width), and "
        "a robot standing still adds no evidence")
    update_angle_deg: float = Field(5.0, ge=0.0, description="° turned between weight updates")

    @model_validator(mode="after")
    def _kinds_of_point(self) -> HypothesisConfig:
        if self.hit_probability + self.through_probability >= 1.0:
            raise ValueError("hit_probability + through_probability must be below 1: some "
                             "points of a scan at the right pose lie on neither (clutter)")
        if self.unmapped_hit_probability + self.unmapped_through_probability >= 1.0:
            raise ValueError("unmapped_hit_probability + unmapped_through_probability must be "
                             "below 1")
        return self

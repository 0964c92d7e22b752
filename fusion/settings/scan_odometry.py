"""Scan odometry's settings (:mod:`fusion.scan_odometry`, :mod:`fusion.scan_icp`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ScanOdometryConfig(BaseModel):
    """Scan-to-scan matching of one laser, fused into the wheel odometry (on by default)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(True, description="correct the wheels' increments by matching each "
                          "scan to the previous one")
    sensor: str | None = Field(
        None, description="the sensor whose scans are matched; None: the first laser configured "
        "(none: no scan matching)")
    iterations: int = Field(20, ge=1, description="ICP iterations at most")
    max_pair_distance: float = Field(
        0.6, gt=0, description="m, pairing distance of the first iteration; it shrinks to "
        "final_pair_distance, so a start 0.5 m off still converges and outliers end unpaired")
    final_pair_distance: float = Field(0.15, gt=0, description="m, pairing distance of the last "
                                       "iteration")
    max_neighbour_gap: float = Field(
        0.5, gt=0, description="m; a point farther than this from a neighbour in beam order "
        "has no normal and is not paired (the scan jumps between objects there)")
    normal_radius: float = Field(
        0.25, gt=0, description="m; a point's normal is fitted to its neighbours this near "
        "(walls are straight over tens of centimetres: more neighbours, steadier normals)")
    huber: float = Field(0.03, gt=0, description="m, residuals beyond weigh less (robust ICP)")
    min_overlap: float = Field(
        0.5, gt=0, le=1, description="fraction of the scan's points paired at the end; less: the "
        "match is not used (a door passed, a person in front of the laser)")
    min_points: int = Field(30, ge=3, description="scans with fewer points are not matched")
    noise_scale: float = Field(
        20.0, ge=1, description="ICP covariance × this: the residuals are not independent "
        "(one wall's points err together), so the raw covariance is far too confident")
    floor_xy: float = Field(0.01, ge=0, description="m, least σ of a matched increment")
    floor_theta_deg: float = Field(0.3, ge=0, description="least σ of a matched turn")
    max_correction_xy: float = Field(
        0.5, gt=0, description="m; a match farther from the wheels' increment is not used")
    max_correction_theta_deg: float = Field(
        20.0, gt=0, description="°; a match turned farther from the wheels' increment is not "
        "used (nor one turned farther than filter.motion.max_turn_rate over the time between "
        "the scans: the robot cannot turn that fast, so it was carried)")
    max_interval: float = Field(
        60.0, gt=0, description="s; a scan this long after the previous one is not matched to "
        "it but becomes the reference (the odometry history since the previous scan is kept "
        "for the match, one entry per wheel reading)")
    robust_quantile: float | None = Field(
        0.99, gt=0.5, lt=1.0, description="when the wheels and the match disagree beyond this "
        "χ²(3) quantile of their joint noise, the wheels' noise is scaled up to it (None: never)")

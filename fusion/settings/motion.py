"""The odometry motion model's settings (:mod:`fusion.motion`): noise, calibration and the
robot's physical limits."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class OdometryMotionConfig(BaseModel):
    """Odometry noise and plausibility limits. Units: metres, radians, seconds."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    alpha1: float = Field(0.05, ge=0, description="rotation noise from rotation, rad per √rad")
    alpha2: float = Field(0.05, ge=0, description="rotation noise from translation, rad per √m")
    alpha3: float = Field(0.05, ge=0, description="translation noise from translation, m per √m")
    alpha4: float = Field(0.02, ge=0, description="translation noise from rotation, m per √rad")
    floor_xy: float = Field(
        0.05, ge=0, description="isotropic position noise, m per √(m + rad) travelled"
    )
    floor_theta: float = Field(
        0.02, ge=0, description="heading noise, rad per √(m + rad) travelled"
    )
    heading_min_translation: float = Field(
        0.01,
        ge=0,
        description="below this translation the direction of travel is undefined: rot1 = 0",
    )
    translation_scale: float = Field(
        1.0, gt=0, description="calibration: the wheels' distance times this is the true one"
    )
    rotation_scale: float = Field(
        1.0, gt=0, description="calibration: the odometry's turn times this is the true one"
    )
    max_speed: float = Field(2.0, gt=0, description="fastest plausible translation, m/s")
    max_turn_rate: float = Field(3.0, gt=0, description="fastest plausible rotation, rad/s")
    jump_margin: float = Field(2.0, ge=1, description="tolerance factor on the limits")
    jump_min_dt: float = Field(
        0.05, gt=0, description="shorter intervals are judged as this long (timestamp jitter)"
    )
    max_acceleration: float = Field(
        1.0, gt=0, description="m/s², the base's largest acceleration: past the newest odometry "
        "reading its velocity is held, and after T seconds the pose is off by at most ½·this·T² "
        "(taken as σ)")
    max_angular_acceleration: float = Field(
        2.0, gt=0, description="rad/s², the same for the heading")
    max_stall: float = Field(
        1.0, ge=0, description="s; an odometry that repeated its reading for up to this long "
        "may have stalled while the robot moved: the motion its next reading reports is judged "
        "over the stall too (a turn lumped into one reading is not a jump)"
    )

"""The wheel-noise estimator's settings (:mod:`fusion.wheel_noise`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class WheelNoiseConfig(BaseModel):
    """The wheels' random distance noise, learned online from scan matches
    (:mod:`fusion.wheel_noise`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(True, description="learn it (with scan odometry on); off: the motion "
                          "model's `alpha3` and `floor_xy` as they are")
    matches: int = Field(200, ge=10, description="the last good matches whose median ratio is "
                         "the estimate (tens of seconds of driving: a floor or a load changes "
                         "the wheels' noise more slowly)")

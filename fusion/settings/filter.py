"""The filter's settings (:mod:`fusion.tracker`, :mod:`fusion.ekf`): the motion model, the
wheel scale, the initial uncertainty, the gate and the history of late measurements."""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

from fusion.settings.motion import OdometryMotionConfig
from fusion.settings.wheel_noise import WheelNoiseConfig
from fusion.settings.wheel_scale import WheelScaleConfig

GATE_PROBABILITY = 0.9999
"""χ² probability that a right fix passes the filter's NIS gate: one right fix in 10 000 is
refused. The one default of the gate, for the config and for a filter built without one."""


class FilterConfig(BaseModel):
    """The EKF and its history of delayed measurements (docs/method.md §7)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    motion: OdometryMotionConfig = OdometryMotionConfig()
    wheel_scale: WheelScaleConfig = WheelScaleConfig()
    wheel_noise: WheelNoiseConfig = WheelNoiseConfig()
    initial_sigma_xy: float = Field(0.05, gt=0.0,
                                    description="m; σ in x and y of an initial pose given")
    initial_sigma_theta_deg: float = Field(1.0, gt=0.0,
                                           description="°; σ of an initial pose's heading")
    gate_probability: float = Field(
        GATE_PROBABILITY, gt=0.5, lt=1.0,
        description="NIS gate: χ² probability that a right fix passes")
    history_seconds: float = Field(2.0, gt=0.0, description="how late a measurement may be")
    delayed_updates: bool = Field(True, description="apply late measurements at their own time")

    @property
    def initial_cov(self) -> list[list[float]]:
        s, t = self.initial_sigma_xy**2, math.radians(self.initial_sigma_theta_deg) ** 2
        return [[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, t]]

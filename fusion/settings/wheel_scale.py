"""The wheel-scale estimator's settings (:mod:`fusion.wheel_scale`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class WheelScaleConfig(BaseModel):
    """The wheels' distance scale, learned online from full fixes (:mod:`fusion.wheel_scale`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    sigma: float | None = Field(
        0.05, gt=0, description="how far the wheels' true distance per reported metre may be "
        "from `filter.motion.translation_scale`, σ (tyre wear, load, a wrong radius: a few per "
        "cent; the filter carries it as a drift of the path until the scale is learned); None: not "
        "learned, the configured scale is used as it is and taken as exact")
    baseline: float = Field(2.0, gt=0, description="m: the least distance between two full "
                            "fixes that observe the scale; a few fixes' errors (cm) over it "
                            "make one observation good to a per cent or two")
    wheel_noise: float = Field(0.01, ge=0, description="m per √m: the wheels' random distance "
                               "error (a rolling wheel on a floor: millimetres per metre), "
                               "without their scale error; also the least the learned noise "
                               "(`filter.wheel_noise`) credits them with")
    max_turn_deg: float = Field(10.0, gt=0, lt=90, description="°: the path between two fixes "
                                "counts as straight when every full fix on it heads within this "
                                "of their chord (its length is then within 1.5 % of the chord's, "
                                "and is corrected by the headings)")

"""The wheels' random distance noise, learned from the scans matched along the way.

The motion model's translation noise (``alpha3`` and ``floor_xy``, 0.05 m per √m each by
default) must cover any robot's wheels: a slipping caster, a bumpy floor. A robot whose wheels
roll true errs a tenth of that, and a filter that believes the default gives a scan match of
σ 2 cm half of each 5 cm step: where people walk along a featureless corridor, the match follows
them.

Each good match (enough points on several objects, no object moving against the others, no
motion the wheels missed) measures the wheels' step along its direction u: the gap
r = uᵀ(δ_s − δ_w) between the match and the wheels has variance λ·a + b, with a = uᵀ Q_w u the
default model's variance of that step's translation, λ the share of it the wheels really show,
and b the match's. Taking b as zero over-states λ by the match's own error, so the estimate

    λ = median(r²/a) / median(χ²₁)

(the median, as people walking past make a few gaps large) errs toward the default, never
below the wheels' true noise. It is held within [w²/(α₃² + floor²), 1]: at most the default,
at least the least noise a rolling wheel has (w, ``filter.wheel_scale.wheel_noise``, the noise
the scale's learner takes the wheels to have), and used once ``matches``/4 matches
were seen (:attr:`WheelNoiseLearner.factor`, which scales the translation noise along the
direction of travel, α₃² and the floor's share, in
:meth:`fusion.motion.OdometryMotionModel.noise`; across it the floor stands, as the matches do
not measure it).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy.stats import chi2

from fusion.settings.motion import OdometryMotionConfig
from fusion.settings.wheel_noise import WheelNoiseConfig

_CHI2_1_MEDIAN = float(chi2.ppf(0.5, 1))
"""the median of χ²₁: a Gaussian gap's square is this times its variance, half the time"""


class WheelNoiseLearner:
    """Good matches' gaps from the wheels in; the share of the default translation noise the
    wheels show out (``factor``)."""

    def __init__(self, config: WheelNoiseConfig, motion: OdometryMotionConfig,
                 least: float) -> None:
        """``least``: m per √m, the least random distance error the wheels are credited with,
        however well they agree with the matches."""
        self.config = config
        default = motion.alpha3**2 + motion.floor_xy**2
        self._least = min(1.0, least**2 / default) if default > 0.0 else 1.0
        self._ratios: deque[float] = deque(maxlen=config.matches)
        self.factor = 1.0
        """λ: the wheels' translation noise variance over the default model's (1 until
        ``matches``/4 good matches were seen)"""

    def observe(self, gap: float, variance: float) -> None:
        """One good match: ``gap`` (m), the match's step less the wheels' along the wheels'
        direction, and ``variance``, the default model's variance of the wheels' step there."""
        if not (variance > 0.0 and math.isfinite(gap)):
            return
        self._ratios.append(gap * gap / variance)
        if len(self._ratios) >= self.config.matches // 4:
            estimate = float(np.median(self._ratios)) / _CHI2_1_MEDIAN
            self.factor = min(1.0, max(self._least, estimate))

    def summary(self) -> dict[str, float | int]:
        """The factor and the matches it was read from (``metrics.json``'s ``wheel_noise``)."""
        return {"factor": round(self.factor, 6), "matches": len(self._ratios)}

"""Where along a corridor: what a corridor fix leaves to the scan's points.

With only parallel lines in view, a Hough fix measures the heading and the position across
them, and nothing along them (rank 2, ``houghloc.displacement``): the filter would carry the
position along the corridor on odometry alone. The scan usually says more. Its points on door
frames, cross walls and the corridor's end lie on the map's walls at one place along it and
not at others; the lines do not see them, the points do. So the fix's pose is slid along its
unobservable direction v, and the scan weighs each position as the hypothesis bank weighs a
pose (``fusion.hypotheses``):

    log p(s | scan) = n [h(s) log p + (1 − h(s)) log(1 − p)] − s² / (2σ²) + const,

s the offset along v, h(s) the share of the scan's points on walls at fix ⊕ s·v
(``ScanFit.fractions``), n = ``independent_points``, p = ``hit_probability``, and σ² = vᵀPv
the guess's variance along v (the prior). The posterior's mean μ and variance σ_post² are
turned back into the one measurement along v that gives them from that prior:

    1/σ_m² = 1/σ_post² − 1/σ²,   z = μ σ_m² / σ_post²,

and the fix becomes a full one with variance σ_m² along v. Where the scan shows nothing along
the corridor (its posterior no narrower than the prior), or no more than a direction the
displacement would call unobservable (σ_m > ``max_observable_sigma``), the fix stays a
corridor fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.ambiguity.fit import ScanFit
from fusion.settings.hypotheses import HypothesisConfig
from houghloc import HoughConfig, ScanCorrection

STEP = 0.01
"""m between the positions tried along the corridor: a fifth of the distance grid's cell."""
REACH = 4.0
"""The positions tried span ±REACH σ of the guess along the corridor."""
MAX_POSITIONS = 801
"""At most this many positions (±4 m at STEP); a wider prior is sampled more coarsely."""


@dataclass(frozen=True, slots=True)
class CorridorMeasurement:
    """A corridor fix completed along the corridor: a full pose measurement."""

    pose: NDArray[np.float64]
    cov: NDArray[np.float64]
    offset: float
    """m along the corridor from the fix's pose"""
    sigma: float
    """m: the measurement's standard deviation along the corridor"""


@dataclass
class CorridorPlacement:
    """Completes rank-2 fixes along their corridor by the scan's points (module docstring)."""

    fit: ScanFit
    likelihood: HypothesisConfig

    def complete(self, fix: ScanCorrection, guess_cov: NDArray, points: NDArray,
                 hough: HoughConfig) -> CorridorMeasurement | None:
        """The full measurement the scan's ``points`` (robot frame) give for a corridor
        ``fix`` (rank 2) whose guess had covariance ``guess_cov``, or None when they place it
        no better along the corridor than the guess does."""
        if fix.rank != 2 or len(points) == 0:
            return None
        v = fix.unobservable[:, 0]
        prior_var = float(v @ guess_cov @ v)
        if not prior_var > 0.0 or not math.isfinite(prior_var):
            return None
        sigma = math.sqrt(prior_var)
        offsets = _offsets(REACH * sigma)
        poses = fix.pose + offsets[:, None] * v
        on_walls = self.fit.fractions(poses, points, hough.reference_kinds)
        log_post = self._log_likelihood(on_walls) - 0.5 * offsets**2 / prior_var
        weights = np.exp(log_post - log_post.max())
        weights /= weights.sum()
        mean = float(weights @ offsets)
        post_var = float(weights @ (offsets - mean) ** 2)
        # the grid cannot resolve a posterior narrower than its spacing
        post_var = max(post_var, (offsets[1] - offsets[0]) ** 2 / 12.0)
        info = 1.0 / post_var - 1.0 / prior_var
        if not info > 1.0 / hough.max_observable_sigma**2:
            return None
        meas_var = 1.0 / info
        offset = mean * meas_var / post_var
        cov = fix.cov + (meas_var - float(v @ fix.cov @ v)) * np.outer(v, v)
        return CorridorMeasurement(fix.pose + offset * v, cov, offset, math.sqrt(meas_var))

    def _log_likelihood(self, on_walls: NDArray) -> NDArray:
        """n [h log p + (1 − h) log(1 − p)] for the shares h of the points on walls."""
        p, n = self.likelihood.hit_probability, self.likelihood.independent_points
        return n * (on_walls * math.log(p) + (1.0 - on_walls) * math.log(1.0 - p))


def _offsets(half_width: float) -> NDArray[np.float64]:
    """Offsets from −half_width to +half_width, STEP apart or spread over MAX_POSITIONS."""
    count = min(2 * math.ceil(half_width / STEP) + 1, MAX_POSITIONS)
    return np.linspace(-half_width, half_width, max(count, 3))

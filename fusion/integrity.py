"""Integrity: the probability that the reported pose is right, with every estimate.

A pose is *right* when it is within :data:`LOCALIZED_POSITION` and :data:`LOCALIZED_HEADING_DEG`
of the truth — the benchmark's bound for a lost pose, so "reported localized while lost" is one
event, *confident-wrong*. The probability is the product of two factors:

* **the mode** — is the filter's Gaussian around the right place at all? While tracking, 1 less
  the share of the evidence that gives tracking up gathered since the last usable fix (the
  scans' worth of points seen through the map's walls, out of ``through_wall_scans``), the
  scan reported included: the decision and the probability read the same evidence. While
  hypotheses are followed, the leader's weight (its posterior among them) once a global match
  has proposed rivals to it, times the chances that its fits and its points seen through
  walls pass the tests the bank takes a pose by (a share among poses that all fit poorly, or
  see through walls, says nothing, and one not weighed yet is 0:
  ``HypothesisBank.leader_probability``); before that, and while collecting views with no
  hypothesis or lost: 0 (``AmbiguityManager.mode_probability``).
* **the spread** — the Gaussian mass ``P(‖e_xy‖ ≤ r) · P(|e_θ| ≤ h)`` of the filter's
  covariance, position and heading taken as independent (their correlation is small next to the
  bounds). A corridor whose position along it no fix observes has a wide σ along it, and this
  factor says so.

``localized`` (a yes/no for a navigation stack) is the probability at or above
:data:`LOCALIZED_PROBABILITY` (:func:`is_localized`).
"""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

LOCALIZED_POSITION = 0.3
"""m: a pose this close to the truth (and within LOCALIZED_HEADING_DEG) is right; farther, it
is lost (the benchmark's and ``houghloc eval``'s bound, fusion.evaluation.LostFraction)."""
LOCALIZED_HEADING_DEG = 5.0
LOCALIZED_PROBABILITY = 0.95
"""The probability at or above which a pose is reported localized: right 19 times in 20, the
odds at which a followed hypothesis is taken (``hypotheses.accept_probability``). Two look-alike
places that the scans weigh about equally are each a coin's toss: neither is localized."""


def is_localized(probability: float) -> bool:
    """Is a pose with this probability reported localized?"""
    return probability >= LOCALIZED_PROBABILITY

# Gauss–Legendre nodes on [0, 1] for the disc integral below (48 nodes; one call costs a few
# microseconds)
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(48)
_NODES, _WEIGHTS = 0.5 * (_NODES + 1.0), 0.5 * _WEIGHTS


def disc_probability(cov_xy: NDArray[np.float64], radius: float) -> float:
    """``P(‖e‖ ≤ r)`` for ``e ~ N(0, cov_xy)`` (2×2). Along the covariance's axes (σ₁ ≥ σ₂)
    it is ``∫₋ᵣʳ φ(u/σ₁)/σ₁ · erf(√(r² − u²)/(√2 σ₂)) du``; with ``u = r sin φ`` the square root
    becomes ``r cos φ`` and the step of the erf at the disc's edge is damped by ``du = r cos φ
    dφ``, so Gauss–Legendre on [0, π/2] (the integrand is even) converges for any ratio of the
    σ's."""
    var = np.linalg.eigvalsh(0.5 * (cov_xy + cov_xy.T))  # ascending
    s2, s1 = (math.sqrt(max(float(v), 1e-18)) for v in var)
    if radius <= 0.0:
        return 0.0
    phi = 0.5 * math.pi * _NODES
    u, half_chord = radius * np.sin(phi), radius * np.cos(phi)
    inner = erf(half_chord / (math.sqrt(2.0) * s2))
    density = np.exp(-0.5 * (u / s1) ** 2) / (math.sqrt(2.0 * math.pi) * s1)
    integral = 0.5 * math.pi * np.sum(_WEIGHTS * density * inner * half_chord)
    return float(min(1.0, 2.0 * integral))


def spread_probability(cov: NDArray[np.float64], position: float = LOCALIZED_POSITION,
                       heading_deg: float = LOCALIZED_HEADING_DEG) -> float:
    """The Gaussian factor: the mass of ``N(0, cov)`` (3×3, x y θ) within the bounds."""
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (3, 3) or not np.isfinite(cov).all():
        return 0.0
    sigma_theta = math.sqrt(max(float(cov[2, 2]), 1e-18))
    heading = math.erf(math.radians(heading_deg) / (math.sqrt(2.0) * sigma_theta))
    return disc_probability(cov[:2, :2], position) * heading


def localized_probability(cov: NDArray[np.float64], mode: float) -> float:
    """The probability that the pose is right: ``mode`` (the right place at all, in [0, 1])
    times the Gaussian mass of ``cov`` within the bounds."""
    if mode <= 0.0:
        return 0.0
    return min(1.0, max(0.0, float(mode))) * spread_probability(cov)


RELIABILITY_BINS = (0.0, 0.1, 0.5, 0.9, 0.99, 1.0)
"""Edges of the reliability table's bins of reported probability (the last bin includes 1)."""


def reliability_counts(probability: NDArray[np.float64], right: NDArray[np.bool_]
                       ) -> NDArray[np.float64]:
    """Per bin of reported probability (``RELIABILITY_BINS``), the poses, how many of them were
    ``right`` and the sum of their probabilities: counts, so that runs pool by adding them."""
    p = np.asarray(probability, dtype=float)
    ok = np.asarray(right, dtype=bool)
    edges = np.asarray(RELIABILITY_BINS)
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, len(edges) - 2)
    bins = len(edges) - 1
    return np.column_stack((np.bincount(which, minlength=bins),
                            np.bincount(which, weights=ok.astype(float), minlength=bins),
                            np.bincount(which, weights=p, minlength=bins)))


def integrity_scores(probability: NDArray[np.float64], right: NDArray[np.bool_] | None = None
                     ) -> dict[str, object]:
    """What the reported probabilities say, and — given which poses were ``right`` (within the
    bounds of the reference) — how well: the share reported localized; the share
    **confident-wrong** (reported localized while not right); the **Brier score** (mean squared
    difference between the probability and the outcome: 0 is perfect, 0.25 a coin); and the
    reliability table, per bin of reported probability, the poses and the share right."""
    p = np.asarray(probability, dtype=float)
    out: dict[str, object] = {"scans": len(p)}
    if len(p) == 0:
        return out
    reported = p >= LOCALIZED_PROBABILITY
    out["localized_fraction"] = float(np.mean(reported))
    out["mean_probability"] = float(np.mean(p))
    if right is None or len(right) != len(p):
        return out
    ok = np.asarray(right, dtype=bool)
    out["confident_wrong"] = float(np.mean(reported & ~ok))
    out["brier"] = float(np.mean((p - ok) ** 2))
    out["reliability"] = [
        {"from": a, "to": b, "scans": int(n),
         "mean_probability": float(total / n) if n else None,
         "right": float(hits / n) if n else None}
        for (a, b), (n, hits, total) in zip(pairwise(RELIABILITY_BINS),
                                             reliability_counts(p, ok), strict=True)]
    return out

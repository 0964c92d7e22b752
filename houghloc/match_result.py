"""What a global match returns and how its stages count their cost
(:mod:`houghloc.global_match`, :mod:`houghloc.slide`)."""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from houghloc.config import GlobalMatchConfig
from houghloc.hypothesis_scores import Hypothesis


@dataclass(frozen=True)
class GlobalResult:
    """Hypotheses best first (distinct poses), whether several tie, and why (or why none)."""

    hypotheses: list[Hypothesis] = field(default_factory=list)
    ambiguous: bool = False
    reason: str = ""
    n_candidates: int = 0  # pose hypotheses generated from line pairs (inside the map)

    @property
    def best(self) -> Hypothesis | None:
        return self.hypotheses[0] if self.hypotheses else None


Stages = Generator[int, None, GlobalResult]
"""A match in stages: each ``next`` does the next stage and yields its cost in distance
look-ups (or work as long); the last one raises StopIteration with the
:class:`GlobalResult` as its value."""

STAGE_LOOKUPS = 500_000
"""Distance look-ups (5–10 ms) that a stage of the slide's coarse grid does at most."""
POSE_COST = 8
"""Look-ups that generating, filtering and voting one pair hypothesis cost as much as."""
REFINE_COST = 4
"""Look-ups per scored point that refining one hypothesis costs as much as (its matching,
visibility and two scorings)."""


def decide(hyps: list[Hypothesis], n_candidates: int, config: GlobalMatchConfig) -> GlobalResult:
    """The result of hypotheses sorted best first: ambiguous when others come within
    ``tie_margin`` of the best's score."""
    best = hyps[0]
    tied = [h for h in hyps if h.score >= best.score - config.tie_margin]
    summary = (f"best explains {best.n_lines_explained} lines, "
               f"{100 * best.inlier_fraction:.0f}% of points on walls (score {best.score:.2f})")
    if len(tied) > 1:
        return GlobalResult(hyps, True, f"{len(tied)} hypotheses within {config.tie_margin:g} "
                            f"of the best score: keep collecting views; {summary}", n_candidates)
    return GlobalResult(hyps, False, summary, n_candidates)


def valid(h: Hypothesis, config: GlobalMatchConfig) -> bool:
    """Does the hypothesis explain enough lines to be reported?"""
    return h.n_lines_explained >= config.min_lines_explained and len(h.matches) >= 2


def subsample(n: int, m: int) -> NDArray[np.intp]:
    """At most m of n indices, evenly strided (deterministic; keeps every line's share)."""
    if n <= m:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, m).astype(np.intp))

"""The words a run speaks in: the manager's states and what became of each scan.

Both are ``StrEnum``: a status compares equal to its text (``ScanStatus.NO_FIX == "no-fix"``),
so ``metrics.json``, the Rerun log and the counts keep the plain words.
"""

from __future__ import annotations

from enum import StrEnum


class State(StrEnum):
    """The ambiguity manager's state (:mod:`fusion.ambiguity`)."""

    TRACKING = "tracking"  # the filter's pose is trusted; each scan's Hough fix corrects it
    COLLECTING = "collecting"  # tracking given up: views are accumulated for a global match
    RELOCALIZING = "relocalizing"  # a global match is under way or its hypotheses are followed
    LOST = "lost"  # no pose at all (no initial pose, or nothing fitted repeatedly)


class ScanStatus(StrEnum):
    """What became of one scan (:class:`fusion.localizer.Estimate`). While not tracking, a scan
    ends with the manager's state (``collecting``, ``relocalizing``, ``lost``)."""

    ACCEPTED = "accepted"  # the fix updated the filter
    REJECTED = "rejected"  # the fix failed the filter's NIS gate
    AMBIGUOUS = "ambiguous"  # the matcher found several equally good correspondences
    NO_FIX = "no-fix"  # too few lines matched for a fix the matcher or the scan vouches for
    MISFIT = "misfit"  # the fix put the scan off the map's walls
    RE_SEARCHED = "re-searched"  # a local search near the guess re-initialised the filter
    DROPPED = "dropped"  # the scan's time is outside the filter's history or ahead of odometry
    INVALID = "invalid"  # the fix was non-finite or its covariance singular
    RELOCALIZED = "relocalized"  # a global match re-initialised the filter
    COLLECTING = State.COLLECTING.value
    RELOCALIZING = State.RELOCALIZING.value
    LOST = State.LOST.value

    @classmethod
    def of_state(cls, state: State) -> ScanStatus:
        """The status of a scan that ended while the manager was in ``state`` (not tracking)."""
        return cls(state.value)

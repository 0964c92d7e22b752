"""Where the node's localizer starts on activation, as AMCL chooses (:func:`choose_start`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.ros2.saved_pose import load_pose
from fusion.ros2.settings import NodeSettings

RVIZ_SIGMAS = (0.5, 0.5, math.radians(15.0))
"""σ of x, y, yaw for a pose from parameters: RViz's 2D Pose Estimate default."""


@dataclass(frozen=True)
class Start:
    """A pose and its covariance (None: the localizer's own), or None: global localization."""

    pose: NDArray[np.float64] | None
    cov: NDArray[np.float64] | None
    reason: str


GLOBAL = Start(None, None, "global localization")


def choose_start(s: NodeSettings, given_pose: NDArray[np.float64] | None,
                 initial_cov: ArrayLike, say: Callable[[str], object]) -> Start:
    """The pose of the parameters (``set_initial_pose``), else the one given on the command
    line, else the saved pose when recent and in the global frame, else global localization.
    ``initial_cov``: a given pose's covariance; ``say``: where to tell why a saved pose is not
    used."""
    if s.set_initial_pose:
        return Start(np.array((s.initial_pose__x, s.initial_pose__y, s.initial_pose__yaw)),
                     np.diag(np.square(RVIZ_SIGMAS)), "initial pose from parameters")
    if given_pose is not None:
        return Start(given_pose, None, "initial pose given")
    if not (s.initialize_at_saved_pose and s.saved_pose_filepath):
        return GLOBAL
    try:
        saved = load_pose(s.saved_pose_filepath)
    except ValueError as err:
        say(f"{err}: global localization")
        return GLOBAL
    if saved.frame != s.global_frame_id or saved.age() > s.houghloc__saved_pose_max_age:
        say(f"saved pose not used: {saved.age():.0f} s old in frame {saved.frame!r} "
            f"(houghloc.saved_pose_max_age {s.houghloc__saved_pose_max_age:g} s)")
        return GLOBAL
    # the robot may have moved while no node ran: the saved pose is a prior no better than an
    # initial pose given, so its covariance has a given pose's added to it
    return Start(saved.pose, saved.cov + np.asarray(initial_cov),
                 f"saved pose, {saved.age():.0f} s old")

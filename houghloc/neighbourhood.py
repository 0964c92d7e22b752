"""How a global match is asked to stay near a pose: a neighbourhood in (x, y, θ), and the
compiled test of a pose against it that the pair hypotheses and the refined ones share."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from houghloc.geometry import mod_two_pi
from houghloc.jit import njit


@njit
def in_neighbourhood(x: float, y: float, theta: float, near_x: float, near_y: float,
                     near_theta: float, radius_xy_sq: float, radius_theta: float) -> bool:
    """Whether the pose (x, y, θ) lies within √``radius_xy_sq`` and ``radius_theta`` of the
    neighbourhood's centre (the heading difference wrapped to [−π, π))."""
    dx, dy = x - near_x, y - near_y
    return (dx * dx + dy * dy <= radius_xy_sq
            and abs(mod_two_pi(theta - near_theta + np.pi) - np.pi) <= radius_theta)



@dataclass(frozen=True)
class Neighbourhood:
    """Poses within ``radius_xy`` (m) and ``radius_theta`` (rad) of ``pose``."""

    pose: NDArray[np.float64]
    radius_xy: float
    radius_theta: float

    def contains(self, poses: NDArray) -> NDArray[np.bool_]:
        """Which of ``poses`` (P×3) lie in the neighbourhood (:func:`in_neighbourhood`)."""
        return _contains(np.asarray(poses, dtype=float).reshape(-1, 3), *self.kernel_args())

    def kernel_args(self) -> tuple[float, float, float, float, float]:
        """The neighbourhood as the compiled tests take it: centre (x, y, θ), squared radius,
        heading radius."""
        return (float(self.pose[0]), float(self.pose[1]), float(self.pose[2]),
                float(self.radius_xy) ** 2, float(self.radius_theta))


@njit
def _contains(poses: NDArray, near_x: float, near_y: float, near_theta: float,
              radius_xy_sq: float, radius_theta: float) -> NDArray[np.bool_]:
    out = np.empty(len(poses), np.bool_)
    for p in range(len(poses)):
        out[p] = in_neighbourhood(poses[p, 0], poses[p, 1], poses[p, 2], near_x, near_y,
                                  near_theta, radius_xy_sq, radius_theta)
    return out

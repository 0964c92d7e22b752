"""EKF on the planar pose (x, y, θ) in ``map``, built on filterpy's ``ExtendedKalmanFilter``.

filterpy does the algebra (prediction of P, gain, Joseph-form update); this class supplies what
a pose needs: the nonlinear odometry prediction x ← x ⊕ δ, a measurement residual whose angle is
wrapped, the heading wrapped after each update, a symmetric positive-definite P, updates
restricted to the observable directions, and NIS gating.

The wheels' remaining scale error e (true distance = (1 + e) × the calibrated one, e ~ N(0, σ_e²)
with σ_e the wheel-scale estimate's own) is a *consider* parameter (Schmidt–Kalman): the filter
carries its cross-covariance with the pose, c = Cov(x, e) = σ_e² d, but never estimates it (the
learner of :mod:`fusion.wheel_scale` does, robustly, from chords between full fixes). A scale error
is systematic: along a straight path of L metres it moves the pose by e·L, which zero-mean
per-step noise (σ ∝ √L) cannot represent, and where fixes observe only the across-corridor
direction the along-corridor σ must grow with L or the filter is confidently wrong before the
scale is learned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike, NDArray

from fusion.settings.filter import GATE_PROBABILITY
from fusion.status import ScanStatus
from houghloc.geometry import TWO_PI, Pose, compose, positive_definite, wrap_scalar
from houghloc.jit import njit
from houghloc.matching import gate_threshold

_FULL_BASIS = np.eye(3)
_EIGEN_FLOOR = 1e-12  # smallest variance kept when P has to be repaired


@dataclass(frozen=True, slots=True)
class UpdateOutcome:
    """What became of a pose measurement.

    ``status``: ``accepted``, ``rejected`` (outside the NIS gate), ``dropped`` (older than the
    history) or ``invalid`` (non-finite or singular). ``nis`` = yᵀS⁻¹y with ``dof`` degrees of
    freedom; ``dof`` = 0 and an empty ``innovation`` when the measurement was never compared.
    """

    accepted: bool
    nis: float
    dof: int
    innovation: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    status: ScanStatus = ScanStatus.ACCEPTED


def motion_jacobians(
    x: NDArray[np.float64], delta: Pose
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """F = ∂(x ⊕ δ)/∂x and G = ∂(x ⊕ δ)/∂δ, evaluated at the prior x."""
    c, s = math.cos(x[2]), math.sin(x[2])
    dx, dy = float(delta[0]), float(delta[1])
    f = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    g = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return f, g


def symmetric_pd(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """P ← (P + Pᵀ)/2, with eigenvalues raised to a tiny floor if rounding made it indefinite."""
    p = _symmetrized(p)
    if positive_definite(p):
        return p
    w, v = np.linalg.eigh(p)
    return (v * np.maximum(w, _EIGEN_FLOOR)) @ v.T


@njit
def _symmetrized(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """(P + Pᵀ)/2, element by element as NumPy computes it."""
    out = np.empty_like(p)
    for i in range(p.shape[0]):
        for j in range(p.shape[1]):
            out[i, j] = 0.5 * (p[i, j] + p[j, i])
    return out


@njit
def _wrapped_measurement(z: NDArray[np.float64], x: NDArray[np.float64]
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """x + y and y = z − x with its angle wrapped to [-π, π) (:func:`wrap_scalar`): the
    measurement to hand filterpy for a full-rank update, whose plain z − Hx is then y."""
    y = np.array([z[0] - x[0], z[1] - x[1], (z[2] - x[2] + math.pi) % TWO_PI - math.pi])
    return x + y, y


def _constant_jacobian(_x: NDArray[np.float64], h: NDArray[np.float64]) -> NDArray[np.float64]:
    return h


def _project(x: NDArray[np.float64], h: NDArray[np.float64]) -> NDArray[np.float64]:
    return h @ x


class PoseEKF(ExtendedKalmanFilter):
    """x = (x, y, θ) in ``map`` (a 1-D array), P its 3×3 covariance.

    One instance is meant to be reused: assign ``x`` and ``P``, then predict or update — the
    tracker uses it as the engine for every step of its history.
    """

    def __init__(self, pose: ArrayLike, cov: ArrayLike,
                 gate_prob: float | None = GATE_PROBABILITY) -> None:
        super().__init__(dim_x=3, dim_z=3)
        self.x = np.array(pose, dtype=float)
        self.P = np.array(cov, dtype=float)
        self.d = np.zeros(3)
        """the pose's sensitivity to the wheels' scale error, Cov(x, e)/σ_e² (module docstring)"""
        # χ² quantiles per measurement dimension, computed once: gate_prob None disables gating.
        self.gates = {
            k: (math.inf if gate_prob is None else gate_threshold(gate_prob, k)) for k in (1, 2, 3)
        }

    def predict_x(self, u: ArrayLike = 0) -> None:
        """x⁻ = x ⊕ δ: the nonlinear state prediction (filterpy's hook for it)."""
        self.x = compose(self.x, u)

    def predict_odometry(self, delta: Pose, q_delta: NDArray[np.float64],
                         step_scale: NDArray[np.float64] | None = None,
                         scale_variance: float = 0.0) -> None:
        """Predict with an odometry increment δ (robot frame) whose covariance is ``q_delta``
        and whose sensitivity to the wheels' scale error e is ``step_scale`` = ∂δ/∂e (None:
        (δ_x, δ_y, 0), the wheels' own step; a step scan matching measured depends on the
        wheels only as far as they were weighted), e of variance ``scale_variance`` (σ_e²).

        F and G are taken at the prior; filterpy then computes x⁻ = x ⊕ δ and
        P⁻ = F P Fᵀ + Q with Q = G Q_δ Gᵀ (the increment's noise rotated into ``map``) plus the
        scale's share. A scale error e moves x⁻ by b·e, b = G ∂δ/∂e, so for the joint state
        (x, e)
            P⁻ = F P Fᵀ + G Q_δ Gᵀ + σ_e² (F d bᵀ + b dᵀ Fᵀ + b bᵀ),    d⁻ = F d + b.
        """
        f, g = motion_jacobians(self.x, delta)
        self.F = f
        q = g @ q_delta @ g.T
        if step_scale is None:
            step_scale = np.array([float(delta[0]), float(delta[1]), 0.0])
        b = g @ step_scale
        moved = f @ self.d
        if scale_variance > 0.0:
            q = q + scale_variance * (np.outer(moved, b) + np.outer(b, moved) + np.outer(b, b))
        self.Q = q
        self.d = moved + b
        self.predict(u=delta)
        self.P = _symmetrized(self.P)

    def update_pose(
        self, z: ArrayLike, r: ArrayLike, basis: NDArray[np.float64] | None = None
    ) -> UpdateOutcome:
        """Update with an absolute pose z (map frame) of covariance R (3×3), gated by the NIS.

        With ``basis`` U (3×k, orthonormal columns) only the k observable directions are
        measured: z_k = Uᵀz, R_k = UᵀRU, H = Uᵀ. Nothing is measured along the unobserved
        directions: they change only through their prior correlation with the observed ones.
        The residual is y = Uᵀ(z ⊖ x), its angle wrapped; NIS = yᵀ S⁻¹ y with filterpy's own
        S = H P Hᵀ + R_k and S⁻¹ (one call computes both the gate's figure and the update, and
        the prior is put back when the gate refuses it). Inputs are assumed finite and validated
        by the caller (see ``PoseTracker``).
        """
        r = np.asarray(r, dtype=float)
        if basis is None:  # H = I: Hx + y and H R Hᵀ are x + y and R, bit for bit
            h = _FULL_BASIS
            measured, y = _wrapped_measurement(np.asarray(z, dtype=float), self.x)
        else:
            h = basis.T
            d = np.asarray(z, dtype=float) - self.x
            d[2] = wrap_scalar(d[2])
            y = h @ d
            measured, r = h @ self.x + y, h @ r @ h.T
        prior_x, prior_p = self.x, self.P  # filterpy assigns new arrays: these stay the prior
        try:
            # Hand filterpy the measurement H x + y, so its plain subtraction z - Hx yields the
            # wrapped residual y (a measured angle near +π against a state near -π moves the
            # short way); then K = P Hᵀ S⁻¹, x = x + K y, P = (I-KH) P (I-KH)ᵀ + K R Kᵀ
            # (Joseph form).
            super().update(measured, _constant_jacobian, _project, R=r, args=(h,),
                           hx_args=(h,))
        except np.linalg.LinAlgError:
            self.x, self.P = prior_x, prior_p
            return UpdateOutcome(False, 0.0, 0, status=ScanStatus.INVALID)
        if not positive_definite(self.S):  # S must be positive definite, not merely invertible
            self.x, self.P = prior_x, prior_p
            return UpdateOutcome(False, 0.0, 0, status=ScanStatus.INVALID)
        nis = float(self.y @ self.SI @ self.y)
        dof = h.shape[0]
        if not nis <= self.gates[dof]:
            self.x, self.P = prior_x, prior_p
            return UpdateOutcome(False, nis, dof, y, status=ScanStatus.REJECTED)
        self.x[2] = wrap_scalar(self.x[2])
        self.P = symmetric_pd(self.P)
        # Schmidt: e itself is not updated, its cross-covariance is, Cov(x⁺, e) = (I − K H) c
        self.d = self.d - self.K @ (h @ self.d)
        return UpdateOutcome(True, nis, dof, y)

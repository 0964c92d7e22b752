"""Odometry motion model: the increment between two odometry readings and its noise.

The odometry frame is arbitrary (real logs start anywhere), so only increments matter: the motion
δ = (⊖o₁) ⊕ o₂ from one reading to the next, expressed in the robot frame at the first one.

Noise follows the usual α₁…α₄ odometry model: δ is split into a first rotation, a translation and
a second rotation (rot1, trans, rot2), each disturbed independently —

* rotation noise from rotation (α₁) and from translation (α₂),
* translation noise from translation (α₃) and from rotation (α₄),

with one deliberate change: the *variances* grow linearly with the amount travelled (a random walk,
σ² = α²·|amount|) instead of quadratically. With the quadratic form the accumulated noise over a
path depends on the odometry rate (at 50 Hz it is √50 times smaller than at 1 Hz), and splitting
one increment in two — which the tracker does when it applies a measurement between two odometry
readings — would silently remove process noise. With the linear form an α is simply the standard
deviation accrued over one metre or one radian, whatever the rate. Small isotropic floor terms,
also proportional to the motion, keep Q full rank (a turn on the spot otherwise has no lateral
noise). Zero motion gives Q = 0: a robot standing still does not grow uncertain.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.settings.motion import OdometryMotionConfig
from houghloc.geometry import Pose, compose, relative, wrap_scalar

# Below this, an increment is treated as exactly zero (a reading repeated by the driver).
_ZERO_MOTION = 1e-12


class OdometryCalibration:
    """Systematic odometry errors removed before filtering: each increment's translation is
    scaled by ``translation_scale`` and its rotation by ``rotation_scale`` (wheel radii and
    wheel base off their nominal values), and the corrected increments are chained into a new
    odometry frame. Zero-mean noise (the α's) cannot absorb a scale error: along a corridor,
    where only the walls' normal is observed, it becomes a drift of a few per cent."""

    def __init__(self, translation_scale: float = 1.0, rotation_scale: float = 1.0) -> None:
        self.translation_scale = translation_scale
        self.rotation_scale = rotation_scale
        self._raw: NDArray[np.float64] | None = None
        self._calibrated = np.zeros(3)

    @property
    def identity(self) -> bool:
        return self.translation_scale == 1.0 and self.rotation_scale == 1.0

    def __call__(self, x: float, y: float, theta: float) -> tuple[float, float, float]:
        """The calibrated odometry pose for a raw reading (the first reading is kept as is)."""
        raw = np.array((x, y, theta), dtype=float)
        if self._raw is not None:
            step = relative(self._raw, raw)  # ⊖raw_prev ⊕ raw, scaled below
            step *= (self.translation_scale, self.translation_scale, self.rotation_scale)
            self._calibrated = compose(self._calibrated, step)
        else:
            self._calibrated = raw
        self._raw = raw
        x, y, theta = self._calibrated.tolist()
        return x, y, theta


def increment(odom_prev: ArrayLike, odom_next: ArrayLike) -> NDArray[np.float64]:
    """The motion δ = (⊖prev) ⊕ next, in the robot frame at ``odom_prev``.

    Components that are only rounding (far from the odometry's origin, ⊖prev ⊕ prev is not
    exactly zero) are set to zero, so a robot standing still moves and spreads by exactly nothing.
    """
    delta = relative(odom_prev, odom_next)
    delta[np.abs(delta) < _ZERO_MOTION] = 0.0
    return delta


def interpolate(a: ArrayLike, b: ArrayLike, s: float) -> NDArray[np.float64]:
    """The pose a fraction ``s`` ∈ [0, 1] of the way from a to b along the SE(2) geodesic.

    The geodesic is the constant-twist path a ⊕ exp(s·log(δ)): exactly the arc a differential
    drive follows at constant wheel speeds, and consistent under subdivision (interpolating
    between interpolated poses lands on the same path).
    """
    dx, dy, dth = relative(a, b)
    # log: the twist (v, ω) whose exp is δ; V(θ) maps the twist's translation to δ's.
    if abs(dth) < 1e-9:
        vx, vy = dx, dy
    else:
        sin_t, one_minus_cos = math.sin(dth), 1.0 - math.cos(dth)
        det = (sin_t * sin_t + one_minus_cos * one_minus_cos) / (dth * dth)
        vx = (sin_t * dx + one_minus_cos * dy) / (dth * det)
        vy = (-one_minus_cos * dx + sin_t * dy) / (dth * det)
    th = s * dth
    if abs(th) < 1e-9:
        step = (s * vx, s * vy, th)
    else:
        sin_t, one_minus_cos = math.sin(th), 1.0 - math.cos(th)
        step = (
            (sin_t * s * vx - one_minus_cos * s * vy) / th,
            (one_minus_cos * s * vx + sin_t * s * vy) / th,
            th,
        )
    return compose(a, step)


class OdometryMotionModel:
    """Noise of odometry increments and detection of implausible ones (jumps)."""

    def __init__(self, config: OdometryMotionConfig | None = None) -> None:
        self.config = config or OdometryMotionConfig()
        self.scale_variance = 0.0
        """σ_e²: the variance of the calibrated wheels' remaining scale error (their true
        distance is (1 + e) times the calibrated one), which the filter carries as a systematic
        error of the path (:class:`fusion.ekf.PoseEKF`); 0 when the scale is taken as known.
        The noise of an increment (:meth:`noise`) is the wheels' random error only."""
        self.translation_factor = 1.0
        """λ: the share of the configured translation noise along the direction of travel
        (α₃² and floor_xy²'s share) the wheels show, learned from scan matches
        (:mod:`fusion.wheel_noise`); 1: as configured"""

    def noise(self, delta: Pose, translation_factor: float | None = None) -> NDArray[np.float64]:
        """Q: the 3×3 covariance of the increment δ = (dx, dy, dθ), in the robot frame, with
        the translation noise (α₃², floor_xy²) scaled by ``translation_factor`` (None: the
        learned :attr:`translation_factor`).

        δ is decomposed into (rot1, trans, rot2), each gets an independent variance from the
        α's (linear in the amounts), and Q = J diag(σ²) Jᵀ with J = ∂δ/∂(rot1, trans, rot2),
        plus the floor terms. Backward driving is handled as a negative translation along the
        heading (not as a half turn, which would create a large spurious rotation noise).
        """
        c = self.config
        factor = self.translation_factor if translation_factor is None else translation_factor
        dx, dy, dth = float(delta[0]), float(delta[1]), float(delta[2])
        trans = math.hypot(dx, dy)
        if trans < _ZERO_MOTION and abs(dth) < _ZERO_MOTION:
            return np.zeros((3, 3))
        if trans < c.heading_min_translation:
            rot1, signed_trans = 0.0, trans
        else:
            rot1, signed_trans = math.atan2(dy, dx), trans
            if abs(rot1) > math.pi / 2:  # driving backwards
                rot1, signed_trans = wrap_scalar(rot1 - math.pi), -trans
        rot2 = wrap_scalar(dth - rot1)
        # Translation's heading noise is split over the two rotations: α₂² per metre in total.
        var_rot1 = c.alpha1**2 * abs(rot1) + 0.5 * c.alpha2**2 * trans
        var_trans = factor * c.alpha3**2 * trans + c.alpha4**2 * (abs(rot1) + abs(rot2))
        var_rot2 = c.alpha1**2 * abs(rot2) + 0.5 * c.alpha2**2 * trans
        # Q = J diag(var_rot1, var_trans, var_rot2) Jᵀ, J = ∂(dx, dy, dθ)/∂(rot1, trans, rot2)
        # for dx = t cos r1, dy = t sin r1, dθ = r1 + r2; written out, as this runs per reading.
        cos1, sin1 = math.cos(rot1), math.sin(rot1)
        lat_x, lat_y = -signed_trans * sin1, signed_trans * cos1  # ∂(dx, dy)/∂rot1
        amount = trans + abs(dth)
        floor_xy, floor_th = c.floor_xy**2 * amount, c.floor_theta**2 * amount
        if trans >= c.heading_min_translation:
            # the learned share is of the noise along the direction of travel, what the scan
            # matches measure (fusion.wheel_noise); across it the floor stands
            var_trans += (factor - 1.0) * floor_xy
        qxy = lat_x * lat_y * var_rot1 + cos1 * sin1 * var_trans
        qxt, qyt = lat_x * var_rot1, lat_y * var_rot1
        return np.array(
            [
                [lat_x * lat_x * var_rot1 + cos1 * cos1 * var_trans + floor_xy, qxy, qxt],
                [qxy, lat_y * lat_y * var_rot1 + sin1 * sin1 * var_trans + floor_xy, qyt],
                [qxt, qyt, var_rot1 + var_rot2 + floor_th],
            ]
        )

    def is_jump(self, delta: Pose, dt: float) -> bool:
        """True when δ is implausible for the interval ``dt``: faster than the limits allow
        (with the margin), or any motion at all over dt < 0. Equal stamps (dt = 0: coarse or
        repeated stamps) are judged as ``jump_min_dt`` apart: their motion is kept.

        The caller replaces a jump by zero motion with the covariance ``jump_noise(dt)`` and
        counts it: a jump is a glitch or a reset of the odometry, not the robot's motion.
        """
        c = self.config
        trans, dth = math.hypot(float(delta[0]), float(delta[1])), float(delta[2])
        if dt < 0.0:
            return trans > _ZERO_MOTION or abs(dth) > _ZERO_MOTION
        dt_eff = max(dt, c.jump_min_dt)
        return (
            trans > c.jump_margin * c.max_speed * dt_eff
            or abs(dth) > c.jump_margin * c.max_turn_rate * dt_eff
        )

    def jump_noise(self, dt: float) -> NDArray[np.float64]:
        """Covariance replacing a jump: the robot moved somewhere within its limits during dt.

        σ_x = σ_y = max_speed·dt and σ_θ = max_turn_rate·dt (dt at least ``jump_min_dt``) — a
        deliberately wide but bounded uncertainty, so the next measurements can pull it back.
        """
        c = self.config
        dt_eff = max(dt, c.jump_min_dt)
        sigma_xy, sigma_th = c.max_speed * dt_eff, c.max_turn_rate * dt_eff
        return np.diag([sigma_xy**2, sigma_xy**2, sigma_th**2])


def compose_increments(
    steps: NDArray[np.float64], covs: NDArray[np.float64],
    scales: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """One increment Δ = δ₁ ⊕ δ₂ ⊕ … ⊕ δₘ (robot frame at the first), its covariance and its
    sensitivity to the wheels' scale error, from m increments ``steps`` (m×3) with covariances
    ``covs`` (m×3×3), independent of each other, and sensitivities ``scales`` (m×3, ∂δ_k/∂e;
    None: each step's own translation, as a wheel step's).

    Predicting once with (Δ, Q_Δ) gives the same state and covariance as predicting m times: ⊕
    is associative, and by the chain rule the m-step Jacobians are those of Δ, so
        F_m⋯F_1 = F(Δ),    F_m⋯F_{k+1} G_k = G(Δ) J_k,    Q_Δ = Σ_k J_k Q_k J_kᵀ,
    where J_k = ∂Δ/∂δ_k = [[R(φ_k), ⊥(Δ_xy − p_k)], [0, 0, 1]], φ_k the heading before step k,
    p_k the position after it and ⊥(v) = (−v_y, v_x): turning at step k swings the rest of the
    path about p_k. Likewise ∂Δ/∂e = Σ_k J_k ∂δ_k/∂e. The heading of Δ is not wrapped (the
    prediction wraps the state's).
    """
    heading = np.concatenate(([0.0], np.cumsum(steps[:-1, 2])))  # φ_k
    c, s = np.cos(heading), np.sin(heading)
    moved = np.column_stack((c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]))
    after = np.cumsum(moved, axis=0)  # p_k
    total = np.array([after[-1, 0], after[-1, 1], steps[:, 2].sum()])
    jac = np.zeros((len(steps), 3, 3))
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1] = c, -s, s, c
    jac[:, 0, 2] = after[:, 1] - total[1]
    jac[:, 1, 2] = total[0] - after[:, 0]
    jac[:, 2, 2] = 1.0
    if scales is None:
        scales = np.column_stack((steps[:, 0], steps[:, 1], np.zeros(len(steps))))
    return (total, (jac @ covs @ jac.transpose(0, 2, 1)).sum(axis=0),
            (jac @ scales[:, :, None]).sum(axis=0)[:, 0])

"""Wheel odometry corrected by matching each laser scan to the previous one.

Wheels slip in turns and some robots' odometry misreports motion outright (Freiburg 079 never
reports driving backwards). Two consecutive scans of a laser see the same walls and furniture a
fraction of a second apart, so aligning them measures the motion between them to millimetres,
clutter included, where the Hough fixes need walls the map knows. The wheels still count where
the scans cannot: along a featureless corridor the alignment's information matrix is
near-singular and the fusion below keeps the wheels' increment in that direction.

Per scan ``k`` (all increments in the robot frame of scan ``k − 1``)::

    δ_w, Q_w   the wheel increment since scan k − 1 and its noise (the motion model)
    δ_s, Q_s   the point-to-line ICP of scan k onto scan k − 1, started at δ_w
    δ = (Q_w⁻¹ + Q_s⁻¹)⁻¹ (Q_w⁻¹ δ_w + Q_s⁻¹ δ_s)                (information-weighted mean)

and the corrected odometry pose of scan ``k`` is that of scan ``k − 1`` ⊕ δ; later wheel readings
are chained onto it. The filter predicts that step with δ's covariance (Q_w⁻¹ + Q_s⁻¹)⁻¹
(:meth:`fusion.tracker.PoseTracker.correct_odometry`).

Robustly: Q_w is first scaled by d²/χ²₃(0.99) when d² = (δ_s − δ_w)ᵀ (Q_w + Q_s)⁻¹ (δ_s − δ_w)
exceeds that quantile. Wheels that disagree with a good match beyond their joint noise have
slipped or misreport, and would otherwise bias every such step toward their error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from fusion.motion import OdometryMotionModel, WheelScale, increment
from houghloc.geometry import compose, wrap_scalar
from houghloc.jit import fma, njit
from houghloc.matching import gate_threshold

# The wheels' noise while they report no motion is zero; this floor (σ = 1 mm, 0.06°) keeps its
# information finite, and still lets the wheels outweigh a match when the robot stands.
_STILL_NOISE = 1e-6 * np.eye(3)
_DAMPING = 1e-6  # of the ICP's normal equations, against a thousand points' ~1e3 per axis
# Point-to-line ICP converges on walls from a heading within about half of this: when the wheels
# missed a turn, the match is started from headings this far apart over the turn it could be.
_HEADING_START_SPACING = math.radians(20.0)


class ScanOdometryConfig(BaseModel):
    """Scan-to-scan matching of one laser, fused into the wheel odometry (on by default)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(True, description="correct the wheels' increments by matching each "
                          "scan to the previous one")
    sensor: str | None = Field(
        None, description="the sensor whose scans are matched; None: the first laser configured "
        "(none: no scan matching)")
    iterations: int = Field(20, ge=1, description="ICP iterations at most")
    max_pair_distance: float = Field(
        0.6, gt=0, description="m, pairing distance of the first iteration; it shrinks to "
        "final_pair_distance, so a start 0.5 m off still converges and outliers end unpaired")
    final_pair_distance: float = Field(0.15, gt=0, description="m, pairing distance of the last "
                                       "iteration")
    max_neighbour_gap: float = Field(
        0.5, gt=0, description="m; a point farther than this from a neighbour in beam order "
        "has no normal and is not paired (the scan jumps between objects there)")
    normal_radius: float = Field(
        0.25, gt=0, description="m; a point's normal is fitted to its neighbours this near "
        "(walls are straight over tens of centimetres: more neighbours, steadier normals)")
    huber: float = Field(0.03, gt=0, description="m, residuals beyond weigh less (robust ICP)")
    min_overlap: float = Field(
        0.5, gt=0, le=1, description="fraction of the scan's points paired at the end; less: the "
        "match is not used (a door passed, a person in front of the laser)")
    min_points: int = Field(30, ge=3, description="scans with fewer points are not matched")
    noise_scale: float = Field(
        20.0, ge=1, description="ICP covariance × this: the residuals are not independent "
        "(one wall's points err together), so the raw covariance is far too confident")
    floor_xy: float = Field(0.01, ge=0, description="m, least σ of a matched increment")
    floor_theta_deg: float = Field(0.3, ge=0, description="least σ of a matched turn")
    max_correction_xy: float = Field(
        0.5, gt=0, description="m; a match farther from the wheels' increment is not used")
    max_correction_theta_deg: float = Field(20.0, gt=0, description="°; a match turned farther "
                                            "from the wheels' increment is not used")
    wheel_scale_sigma: float | None = Field(
        None, gt=0, description="the wheels' distance scale is estimated online from the "
        "matches, from 1 ± this (how far from nominal a wheel's radius may be, e.g. 0.1; None: "
        "not estimated, each matched increment corrects the wheels' distance by itself)")
    wheel_scale_drift: float = Field(
        0.001, ge=0, description="how fast that scale may change, σ per √m driven")
    robust_quantile: float | None = Field(
        0.99, gt=0.5, lt=1.0, description="when the wheels and the match disagree beyond this "
        "χ²(3) quantile of their joint noise, the wheels' noise is scaled up to it (None: never)")


@dataclass(frozen=True, slots=True)
class IcpResult:
    """The increment that maps the current scan onto the previous one, and its covariance."""

    delta: NDArray[np.float64]
    cov: NDArray[np.float64]
    overlap: float  # fraction of the current scan's points paired at the last iteration


def scan_normals(points: NDArray[np.float64], max_gap: float, radius: float,
                 half_window: int = 8) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Unit normals of a scan in beam order, and which are usable.

    Each normal is the minor axis of the covariance of the point's neighbours within
    ``radius`` (among the ``half_window`` beams either side, not across a jump of more than
    ``max_gap``, where the scan passes from one object to another). A normal from the two
    adjacent points alone turns by tens of degrees with a centimetre of range noise when the
    beams are a centimetre or two apart: along a corridor's walls those tilts add up to
    information along the corridor that the walls do not give. Usable: at least three
    points in the neighbourhood."""
    return _scan_normals(np.ascontiguousarray(points, dtype=float), max_gap, radius,
                         half_window)


@njit
def _scan_normals(points: NDArray, max_gap: float, radius: float, half_window: int
                  ) -> tuple[NDArray, NDArray]:
    n = len(points)
    jump = np.zeros(n, np.intp)  # the object each point belongs to
    for i in range(1, n):
        gap = math.hypot(points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1])
        jump[i] = jump[i - 1] + (gap > max_gap)
    normals = np.empty((n, 2))
    usable = np.empty(n, np.bool_)
    for i in range(n):
        count = sx = sy = sxx = sxy = syy = 0.0
        for j in range(max(0, i - half_window), min(n, i + half_window + 1)):
            dx, dy = points[j, 0] - points[i, 0], points[j, 1] - points[i, 1]
            if math.hypot(dx, dy) <= radius and jump[j] == jump[i]:
                count += 1.0
                sx, sy = sx + dx, sy + dy
                sxx, sxy, syy = sxx + dx * dx, sxy + dx * dy, syy + dy * dy
        safe = max(count, 1.0)
        cxx = sxx / safe - (sx / safe) ** 2
        cxy = sxy / safe - (sx / safe) * (sy / safe)
        cyy = syy / safe - (sy / safe) ** 2
        along = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)  # the major axis: the surface's direction
        normals[i, 0], normals[i, 1] = -math.sin(along), math.cos(along)
        usable[i] = count >= 3
    return normals, usable


def point_to_line_icp(previous: NDArray[np.float64], current: NDArray[np.float64],
                      guess: NDArray[np.float64], config: ScanOdometryConfig) -> IcpResult | None:
    """Align ``current`` (robot frame at k) onto ``previous`` (robot frame at k − 1), started at
    the increment ``guess``: Gauss–Newton on Σ w ρ(nᵢ·(R qᵢ + t − pᵢ)) with Huber weights, pairs
    by nearest neighbour within a distance that shrinks over the iterations. None when too few
    points pair. Cov = σ̂² (JᵀWJ)⁻¹, the Gauss–Newton covariance at the optimum."""
    if len(previous) < config.min_points or len(current) < config.min_points:
        return None
    previous = np.ascontiguousarray(previous, dtype=float)
    normals, usable = scan_normals(previous, config.max_neighbour_gap, config.normal_radius)
    found, x, hessian, sigma2, overlap = _icp(
        previous, normals, usable, np.ascontiguousarray(current, dtype=float),
        np.array(guess, dtype=float), config.iterations, config.max_pair_distance,
        config.final_pair_distance, config.huber, config.min_points)
    if not found:
        return None
    x[2] = wrap_scalar(x[2])
    return IcpResult(x, sigma2 * np.linalg.inv(hessian), overlap)


@njit
def _icp(previous: NDArray, normals: NDArray, usable: NDArray, current: NDArray,
         x: NDArray, iterations: int, max_pair: float, final_pair: float, huber: float,
         min_points: int) -> tuple[bool, NDArray, NDArray, float, float]:
    """The Gauss–Newton iterations of :func:`point_to_line_icp`: (found, x, JᵀWJ + damping,
    σ̂², overlap). Nearest neighbours come from a grid of the previous scan with cells as wide
    as the widest pairing distance, so a pair is always in one of the 3 × 3 cells around."""
    index = _cell_index(previous, max(max_pair, final_pair))
    n = len(current)
    residual, weight = np.zeros(n), np.zeros(n)
    hessian = np.eye(3)
    shrink = max(1.0, 0.6 * iterations)
    paired = 0
    for iteration in range(iterations):
        progress = min(1.0, iteration / shrink)
        reach = max_pair + (final_pair - max_pair) * progress
        c, s = math.cos(x[2]), math.sin(x[2])
        hessian = np.zeros((3, 3))
        gradient = np.zeros(3)
        paired = 0
        for i in range(n):  # q = R(θ) cᵢ + t, as the matrix product [cᵢ]·[[c, s], [−s, c]]
            qx = fma(current[i, 1], -s, current[i, 0] * c) + x[0]
            qy = fma(current[i, 1], c, current[i, 0] * s) + x[1]
            j = _nearest(previous, index, qx, qy, reach)
            if j < 0 or not usable[j]:
                residual[i] = weight[i] = 0.0
                continue
            paired += 1
            nx, ny = normals[j, 0], normals[j, 1]
            r = nx * (qx - previous[j, 0]) + ny * (qy - previous[j, 1])
            ax, ay = qx - x[0], qy - x[1]  # ∂(R q)/∂θ = (−(Rq)_y, (Rq)_x)
            jac = (nx, ny, ny * ax - nx * ay)
            w = 1.0 / max(1.0, abs(r) / huber)
            residual[i], weight[i] = r, w
            for a in range(3):
                gradient[a] += jac[a] * w * r
                for b in range(3):
                    hessian[a, b] += jac[a] * jac[b] * w
        if paired < min_points:
            return False, x, hessian, 0.0, 0.0
        hessian += _DAMPING * np.eye(3)
        # damped: along a featureless corridor one direction has no information; the step
        # leaves it alone and the covariance calls it unknown (σ² ~ σ̂²/damping)
        step = -np.linalg.solve(hessian, gradient)
        x += step
        if np.abs(step).max() < 1e-5:
            break
    dof = max(1, paired - 3)
    sigma2 = max((weight * residual**2).sum() / dof, 1e-6)
    return True, x, hessian, sigma2, paired / n


@njit
def _cell_index(points: NDArray, cell: float) -> tuple:
    """Points bucketed in square cells of side ``cell`` (a counting sort): the grid's origin,
    1/cell, its width and height in cells, and ``start``, ``order`` such that
    ``order[start[c]:start[c + 1]]`` are the points of cell c (row-major)."""
    ox, oy = points[:, 0].min(), points[:, 1].min()
    inv_cell = 1.0 / cell
    nx = int((points[:, 0].max() - ox) * inv_cell) + 1
    ny = int((points[:, 1].max() - oy) * inv_cell) + 1
    of = np.empty(len(points), np.intp)
    counts = np.zeros(nx * ny + 1, np.intp)
    for k in range(len(points)):
        of[k] = int((points[k, 1] - oy) * inv_cell) * nx + int((points[k, 0] - ox) * inv_cell)
        counts[of[k] + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    order = np.empty(len(points), np.intp)
    for k in range(len(points)):
        order[fill[of[k]]] = k
        fill[of[k]] += 1
    return ox, oy, inv_cell, nx, ny, start, order


@njit
def _nearest(points: NDArray, index: tuple, x: float, y: float, reach: float) -> int:
    """The point of :func:`_cell_index` nearest (x, y) and closer than ``reach`` (at most the
    cell's side: it lies in one of the 3 × 3 cells around), or −1."""
    ox, oy, inv_cell, nx, ny, start, order = index
    cx, cy = math.floor((x - ox) * inv_cell), math.floor((y - oy) * inv_cell)
    best, best_d2 = -1, reach * reach
    for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
        for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
            c = gy * nx + gx
            for m in range(start[c], start[c + 1]):
                k = order[m]
                d2 = (points[k, 0] - x) ** 2 + (points[k, 1] - y) ** 2
                if d2 < best_d2 or (d2 == best_d2 and 0 <= k < best):
                    best, best_d2 = k, d2
    return best


@dataclass(frozen=True, slots=True)
class Correction:
    """A proposed corrected odometry pose for a scan; :meth:`ScanOdometry.commit` adopts it."""

    t: float
    pose: NDArray[np.float64]
    since: float  # the time of the reference scan
    step_cov: NDArray[np.float64]  # covariance of the corrected increment since then
    points: NDArray[np.float64]
    wheels: NDArray[np.float64]  # the wheel odometry pose it corrects
    # the wheels' distance (unscaled), the match's along it and that one's variance
    scale_evidence: tuple[float, float, float] | None = None


class ScanOdometry:
    """The odometry stream with each scan's increment corrected by scan matching.

    :meth:`on_wheels` maps a wheel reading into the corrected frame (chained onto the last
    corrected scan); :meth:`match` proposes the corrected pose at a scan, and :meth:`commit`
    adopts it once the filter has taken it. A scan that is not matched or not committed leaves
    the previous one as the reference for the next."""

    def __init__(self, config: ScanOdometryConfig, motion: OdometryMotionModel) -> None:
        self.config = config
        self.motion = motion
        self.matched = 0
        self.unmatched = 0
        self._wheels: NDArray[np.float64] | None = None  # newest wheel reading
        self._anchor_wheels: NDArray[np.float64] | None = None  # wheels at the reference scan
        self._anchor: NDArray[np.float64] | None = None  # corrected pose there
        self._points: NDArray[np.float64] | None = None  # the reference scan
        self._time = -math.inf  # and its time
        self._unmeasured = 0.0  # seconds of motion the wheels missed since the reference scan
        self.scale = (None if config.wheel_scale_sigma is None
                      else WheelScale(config.wheel_scale_sigma, config.wheel_scale_drift))
        floors = (config.floor_xy**2, config.floor_xy**2, math.radians(config.floor_theta_deg)**2)
        self._floor = np.diag(floors)
        self._robust_limit = (math.inf if config.robust_quantile is None
                              else gate_threshold(config.robust_quantile, 3))

    def on_wheels(self, x: float, y: float, theta: float,
                  unmeasured: float = 0.0) -> tuple[float, float, float]:
        """The corrected odometry pose for a wheel reading (``unmeasured``: seconds before it
        whose motion the wheels missed, see :class:`fusion.events.Odometry`)."""
        self._wheels = np.array((x, y, theta), dtype=float)
        self._unmeasured += unmeasured
        if self._anchor is None:
            self._anchor_wheels, self._anchor = self._wheels, self._wheels.copy()
        return tuple(self._corrected_wheels().tolist())

    def match(self, t: float, points: NDArray[np.float64]) -> Correction | None:
        """The corrected odometry pose at a scan taken at t (the wheels are read at their newest
        reading), or None when the scan cannot be matched; the first scan becomes the
        reference. ``points``: finite, robot frame (the Localizer has cleaned them)."""
        if self._wheels is None or len(points) < self.config.min_points:
            return None
        if self._points is None:
            self.skip(t, points)
            return None
        assert self._anchor is not None and self._anchor_wheels is not None  # set with _points
        raw_step = increment(self._anchor_wheels, self._wheels)
        wheel_step = self._scaled(raw_step)
        icp = self._align(points, wheel_step)
        fused = self._fuse(wheel_step, icp)
        if fused is None:
            self.unmatched += 1
            self.skip(t, points)
            return None
        self.matched += 1
        step, cov = fused
        assert icp is not None
        return Correction(t, compose(self._anchor, step), self._time, cov, points, self._wheels,
                          self._scale_evidence(raw_step, icp))

    def commit(self, correction: Correction) -> None:
        """The filter took the corrected pose: the scan becomes the reference for the next."""
        self._points, self._anchor_wheels, self._anchor = (correction.points, correction.wheels,
                                                           correction.pose)
        self._time, self._unmeasured = correction.t, 0.0
        if self.scale is not None and correction.scale_evidence is not None:
            self.scale.update(*correction.scale_evidence)

    def skip(self, t: float, points: NDArray[np.float64]) -> None:
        """The scan was not corrected: it becomes the reference at its uncorrected pose (an older
        reference would drift out of view)."""
        self._anchor = self._corrected_wheels()
        self._points, self._anchor_wheels, self._time = points, self._wheels, t
        self._unmeasured = 0.0

    def _align(self, points: NDArray[np.float64],
               wheel_step: NDArray[np.float64]) -> IcpResult | None:
        """The ICP of the scan onto the reference, started at the wheels' increment; when the
        wheels missed some motion, started from every heading the robot could have turned to
        then as well, and the best-overlapping alignment kept (the nearer turn on a tie)."""
        assert self._points is not None
        reach = self.motion.config.max_turn_rate * self._unmeasured
        count = min(int(reach / _HEADING_START_SPACING), int(math.pi / _HEADING_START_SPACING))
        best: IcpResult | None = None
        for k in sorted(range(-count, count + 1), key=abs):
            start = wheel_step.copy()
            start[2] += k * _HEADING_START_SPACING
            icp = point_to_line_icp(self._points, points, start, self.config)
            if icp is not None and (best is None or icp.overlap > best.overlap):
                best = icp
        return best
    def _corrected_wheels(self) -> NDArray[np.float64]:
        """The newest wheel reading in the corrected frame: chained onto the reference scan."""
        assert self._anchor is not None and self._anchor_wheels is not None
        assert self._wheels is not None
        return compose(self._anchor, self._scaled(increment(self._anchor_wheels, self._wheels)))

    def _scaled(self, step: NDArray[np.float64]) -> NDArray[np.float64]:
        """A wheel increment with its distance scaled by the estimate (the scale is fixed
        between two scans, so scaling the whole step scales each reading's within it)."""
        if self.scale is None:
            return step
        return np.array((step[0] * self.scale.value, step[1] * self.scale.value, step[2]))

    def _scale_evidence(self, raw_step: NDArray[np.float64],
                        icp: IcpResult) -> tuple[float, float, float] | None:
        """What a match says of the wheels' scale (:class:`fusion.motion.WheelScale`): the
        distance the wheels drove, the match's translation along it and that one's variance
        (the match's and the wheels' random noise). None when there is nothing to learn: no
        drive, or motion the wheels missed."""
        distance = math.hypot(raw_step[0], raw_step[1])
        if (self.scale is None or self._unmeasured > 0.0
                or distance < self.motion.config.heading_min_translation):
            return None
        along = raw_step[:2] / distance
        spread = (icp.cov * self.config.noise_scale + self._floor
                  + self.motion.noise(self._scaled(raw_step)))[:2, :2]
        return distance, float(along @ icp.delta[:2]), float(along @ spread @ along)

    def _fuse(self, wheel_step: NDArray[np.float64],
              icp: IcpResult | None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """δ = Q (Q_w⁻¹ δ_w + Q_s⁻¹ δ_s) with Q = (Q_w⁻¹ + Q_s⁻¹)⁻¹, the information-weighted
        increment and its covariance; None when the match is unusable or too far from the
        wheels to be believed."""
        c = self.config
        if icp is None or icp.overlap < c.min_overlap:
            return None
        matched = icp.delta.copy()
        matched[2] = wheel_step[2] + wrap_scalar(matched[2] - wheel_step[2])
        gap = matched - wheel_step
        # motion the wheels missed widens what they can be corrected by, to where the robot
        # could have gone meanwhile
        limits = self.motion.config
        if (math.hypot(gap[0], gap[1]) > c.max_correction_xy + limits.max_speed * self._unmeasured
                or abs(gap[2]) > (math.radians(c.max_correction_theta_deg)
                                  + limits.max_turn_rate * self._unmeasured)):
            return None
        wheel_cov = self.motion.noise(wheel_step) + _STILL_NOISE
        if self._unmeasured > 0.0:
            wheel_cov = wheel_cov + self.motion.jump_noise(self._unmeasured)
        scan_cov = icp.cov * c.noise_scale + self._floor
        if c.robust_quantile is not None:
            # the two disagree beyond their joint noise: the wheels slipped or misreport (a good
            # match does not err by decimetres), so their noise is scaled up until they agree
            # at the quantile, and the increment follows the match
            d2 = float(gap @ np.linalg.solve(wheel_cov + scan_cov, gap))
            if d2 > self._robust_limit:
                wheel_cov = wheel_cov * (d2 / self._robust_limit)
        wheel_info = np.linalg.inv(wheel_cov)
        scan_info = np.linalg.inv(scan_cov)
        cov = np.linalg.inv(wheel_info + scan_info)
        cov = 0.5 * (cov + cov.T)
        return cov @ (wheel_info @ wheel_step + scan_info @ matched), cov


_warmed_up = False


def warm_up() -> None:
    """Compile the matching kernels, or load them from the cache, before the first scan (once
    per process): two views of a rectangular room, 5 cm and 1° apart, are aligned."""
    global _warmed_up
    if _warmed_up:
        return
    s = np.linspace(0.0, 1.0, 60, endpoint=False)[:, None]
    corners = np.array([[-2.0, -1.5], [4.0, -1.5], [4.0, 2.5], [-2.0, 2.5]])
    room = np.concatenate([a + s * (b - a) for a, b in zip(corners, np.roll(corners, -1, 0),
                                                             strict=True)])
    moved = (room - (0.05, 0.0)) @ np.array([[1.0, 0.0175], [-0.0175, 1.0]])
    point_to_line_icp(room, moved, np.zeros(3), ScanOdometryConfig())
    _warmed_up = True

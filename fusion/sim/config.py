"""Scenario configuration: what to simulate, as validated pydantic models.

Every model forbids unknown keys, so a typo in a scenario YAML is an error that names the field.
Angles in configs are degrees (``*_deg``), everything else SI. A whole scenario round-trips through
``ScenarioConfig.model_dump(mode="json")`` and ``ScenarioConfig.model_validate``.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class LaserConfig(_Model):
    """A 2D laser at the robot origin, beams evenly spread over the field of view.

    Beam i points at ``-fov/2 + i·fov/(n_beams-1)`` (robot frame, counter-clockwise, 0 = ahead),
    the layout of CARMEN's ``FLASER`` for a 180° scanner. Measured range of a beam whose first hit
    is at distance r: ``r + N(0, sigma²)``; with probability ``dropout_prob`` the beam reports
    ``max_range`` (no return), with probability ``spurious_prob`` it reports ``U(min_range, r)``.
    """

    n_beams: int = Field(361, ge=2)
    fov_deg: float = Field(180.0, gt=0.0, le=360.0)
    max_range: float = Field(10.0, gt=0.0)
    min_range: float = Field(0.02, ge=0.0)
    sigma: float = Field(0.01, ge=0.0)
    dropout_prob: float = Field(0.01, ge=0.0, le=1.0)
    spurious_prob: float = Field(0.005, ge=0.0, le=1.0)
    rate: float = Field(10.0, gt=0.0, description="scans per second")

    @model_validator(mode="after")
    def _ranges_ordered(self) -> LaserConfig:
        if self.min_range >= self.max_range:
            raise ValueError("min_range must be below max_range")
        return self


class CameraConfig(_Model):
    """A camera whose detected lines are triangulated onto the floor (the paper's sensor).

    It sees painted lines, the bottom edges of walls and clutter, and the near side of moving
    obstacles, inside a sector (``fov_deg`` wide, ``min_range``..``max_range``) and not hidden
    behind walls, clutter or obstacles. Visible parts are sampled every ``point_spacing`` metres;
    each point gets isotropic Gaussian noise ``σ(d) = sigma0 + k·d²`` (triangulation error grows
    with the square of the distance d); ``false_points`` is the mean (Poisson) number of isolated
    false points per frame, uniform over the sector's area. A frame's data is taken at ``t`` and
    arrives at ``t + latency``.

    Default noise: a camera 0.6 m above the floor with a 550 px focal length and one pixel of
    line-detection error has a range error of about d²/(h·f) ≈ 0.003·d²; k = 0.004 adds some
    margin (7 cm at 4 m), σ₀ = 1 cm covers calibration.
    """

    fov_deg: float = Field(60.0, gt=0.0, lt=180.0)
    min_range: float = Field(0.3, ge=0.0)
    max_range: float = Field(4.0, gt=0.0)
    point_spacing: float = Field(0.05, gt=0.0)
    sigma0: float = Field(0.01, ge=0.0)
    k: float = Field(0.004, ge=0.0)
    false_points: float = Field(3.0, ge=0.0)
    see_obstacles: bool = True
    rate: float = Field(5.0, gt=0.0, description="frames per second")
    latency: float = Field(0.0, ge=0.0, description="seconds from capture to arrival")

    @model_validator(mode="after")
    def _ranges_ordered(self) -> CameraConfig:
        if self.min_range >= self.max_range:
            raise ValueError("min_range must be below max_range")
        return self


class OdometryConfig(_Model):
    """Wheel odometry of a differential drive (wheel base ``wheelbase``).

    True wheel travels per step: ``d_l = ds − (b/2)·dθ``, ``d_r = ds + (b/2)·dθ``. Measured:
    ``d̃ = (1 + scale_error)·d + wheel_noise·√|d|·N(0, 1)`` per wheel (random error variance
    proportional to the distance rolled); the odometry assumes the wheel base
    ``b·(1 + wheelbase_error)``. Dead reckoning with the midpoint rule,
    ``θ += dθ̃``, ``x += ds̃·cos(θ − dθ̃/2)`` …, starts at the identity and is reported as
    ``frame_offset ⊕ pose`` (odometry frames are arbitrary; real logs start far from zero).
    Left +2 % / right +1.5 % on a 0.4 m base: distances read about 1.75 % long and the heading
    drifts by −0.0125 rad (0.7°) per metre driven — a typical uncalibrated differential drive.
    """

    wheelbase: float = Field(0.4, gt=0.0)
    left_scale_error: float = Field(0.02, gt=-1.0)
    right_scale_error: float = Field(0.015, gt=-1.0)
    wheelbase_error: float = Field(0.0, gt=-1.0)
    wheel_noise: float = Field(0.005, ge=0.0, description="m per √m rolled, per wheel")
    turn_slip: float = Field(0.0, ge=0.0, lt=1.0, description=(
        "the wheels over-report a turn by this fraction as it tightens: dθ̃ = dθ·(1 + s·c), "
        "c = min(1, |dθ/ds| / 1 rad/m) (0 driving straight, 1 turning in place)"))
    frame_offset: tuple[float, float, float] = (576.5, 0.1, -2.26)


class RobotConfig(_Model):
    """Differential-drive robot and its path-following controller (see ``fusion.sim.robot``)."""

    radius: float = Field(0.25, gt=0.0)
    v_max: float = Field(0.5, gt=0.0, le=2.0)
    omega_max: float = Field(1.0, gt=0.0)
    accel_max: float = Field(0.6, gt=0.0)
    alpha_max: float = Field(3.0, gt=0.0, description="angular acceleration limit, rad/s²")
    lookahead: float = Field(0.4, gt=0.0)
    heading_gain: float = Field(2.5, gt=0.0)


class RouteConfig(_Model):
    """Where the robot drives.

    ``auto``: the map's default route (the RoboCup field: random waypoints ≥ 0.5 m inside the
    walls; the office: a hand-written loop through the corridor and every room; other maps:
    random waypoints in free space joined by straight legs that keep ``clearance``).
    ``random``: random waypoints (inside ``region`` = (x_min, y_min, x_max, y_max) if given).
    ``waypoints``: the given list, driven in order (and repeated when ``loop``).
    """

    kind: Literal["auto", "random", "waypoints"] = "auto"
    waypoints: list[tuple[float, float]] = Field(default_factory=list)
    loop: bool = True
    region: tuple[float, float, float, float] | None = None
    clearance: float = Field(0.5, gt=0.0)
    min_leg: float = Field(1.0, ge=0.0, description="shortest leg between random waypoints, m")

    @model_validator(mode="after")
    def _enough_waypoints(self) -> RouteConfig:
        if self.kind == "waypoints" and len(self.waypoints) < 2:
            raise ValueError("a 'waypoints' route needs at least two waypoints")
        return self


class ObstacleGroup(_Model):
    """Moving discs (robots r ≈ 0.25 m, people r ≈ 0.2 m) wandering through free space.

    Each disc keeps its speed; its heading does a random walk (``turn_noise`` rad/√s) and is
    redrawn at random whenever the next step would come within ``radius`` of a wall or clutter,
    or move towards the robot within ``radius + robot radius + 0.1`` m; a disc that close to the
    robot heads straight away from it (the robot itself does not avoid obstacles).
    """

    count: int = Field(0, ge=0)
    radius: float = Field(0.25, gt=0.0)
    speed: float = Field(0.5, ge=0.0)
    turn_noise: float = Field(0.5, ge=0.0)
    kind: str = "robot"


class ClutterConfig(_Model):
    """Unmapped static boxes (as four wall-like segments each), kept away from the route."""

    count: int = Field(0, ge=0)
    size: tuple[float, float] = (0.2, 0.6)
    route_clearance: float = Field(0.8, ge=0.0, description="min distance from the route, m")

    @model_validator(mode="after")
    def _size_ordered(self) -> ClutterConfig:
        if not 0.0 < self.size[0] <= self.size[1]:
            raise ValueError("size must be (min, max) with 0 < min <= max")
        return self


class Kidnap(_Model):
    """At time ``t`` the true robot is moved by (dx, dy) and turned by dθ in the map frame
    (a collision, or being carried); the odometry does not notice."""

    t: float = Field(ge=0.0)
    dx: float = 0.0
    dy: float = 0.0
    dtheta_deg: float = 0.0

    @property
    def dtheta(self) -> float:
        return math.radians(self.dtheta_deg)


class OdometryGap(_Model):
    """From ``t`` (seconds from the start) for ``duration`` seconds no odometry record is written
    (a driver that stalls); the wheels keep counting, so the next record carries the motion."""

    t: float = Field(ge=0.0)
    duration: float = Field(gt=0.0)


class ScenarioConfig(_Model):
    """One simulated run. ``map`` is a path, or the name of a packaged map
    (``fusion/configs/maps/``)."""

    name: str = "custom"
    map: str = "robocup.yaml"
    duration: float = Field(300.0, gt=0.0, description="seconds")
    seed: int = 0
    start_time: float = Field(0.0, description="timestamp of the first odometry record")
    odom_rate: float = Field(50.0, gt=0.0, description="odometry (and integration) rate, Hz")
    obstacle_dt: float = Field(0.1, gt=0.0, description="moving obstacles' time step, s")
    robot: RobotConfig = RobotConfig()
    route: RouteConfig = RouteConfig()
    odometry: OdometryConfig = OdometryConfig()
    laser: LaserConfig | None = LaserConfig()
    camera: CameraConfig | None = None
    obstacles: list[ObstacleGroup] = Field(default_factory=list)
    clutter: ClutterConfig = ClutterConfig()
    kidnaps: list[Kidnap] = Field(default_factory=list)
    odometry_gaps: list[OdometryGap] = Field(default_factory=list)
    transparent: list[str] = Field(
        default_factory=list, description="ids of map walls the laser sees through (glass)")

    @model_validator(mode="after")
    def _obstacle_steps_small(self) -> ScenarioConfig:
        # A disc that moves less than its radius per step cannot jump over a thin wall, so
        # checking the clearance at the new position is enough (see fusion.sim.world).
        for g in self.obstacles:
            if g.count and g.speed * self.obstacle_dt >= g.radius:
                raise ValueError(
                    f"obstacles of radius {g.radius} m at {g.speed} m/s need obstacle_dt < "
                    f"{g.radius / max(g.speed, 1e-9):.3f} s"
                )
        return self

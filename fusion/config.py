"""Localizer configuration: pydantic groups, YAML overlay on the defaults, clear errors.

The defaults describe a 2D laser with wheel odometry. A YAML file overrides any subset::

    sensors:
      laser: {max_range: 8.0, hough: {theta_step_deg: 2.0}}
    filter: {motion: {alpha3: 0.1}}
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from fusion.resources import find_config
from fusion.settings.ambiguity import AmbiguityConfig
from fusion.settings.filter import FilterConfig
from fusion.settings.scan_odometry import ScanOdometryConfig
from houghloc.config import HoughConfig
from houghloc.yaml_io import read_yaml, validated

METRICS_VERSION_KEY = "houghloc_version"
"""The key that marks a ``metrics.json`` (which also holds its run's ``config``)."""


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file, the field and why."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class SensorConfig(_Strict):
    """One range sensor: where it is on the robot, what it sees, and its Hough settings."""

    kind: Literal["laser", "camera"] = Field("laser", description="laser: ranges and bearings; "
                                             "camera: points triangulated on the floor")
    mount: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="m, m, rad: the sensor's pose on the robot's base (x ahead, "
        "y left, θ counter-clockwise); a ROS bag's /tf_static gives it when it has one")
    min_range: float = Field(0.05, ge=0.0, description="m; nearer returns are the robot itself")
    max_range: float = Field(20.0, gt=0.0, description="m; returns at or beyond it mean no "
                             "return")
    hough: HoughConfig = HoughConfig()
    min_fix_lines: int = Field(
        2, ge=1, description="matched lines a fix needs to be used: a single line cannot be "
        "checked against another, and in clutter it is often matched to a near-parallel wall")

    @model_validator(mode="after")
    def _grid_within_range(self) -> SensorConfig:
        # No line farther than the sensor's range (from the robot's origin, where the points
        # are taken) can be seen: the Hough grid stops there, one cell beyond, and every scan
        # votes into and searches that many fewer cells.
        reach = self.max_range + math.hypot(*self.mount[:2]) + self.hough.rho_step
        if self.hough.rho_max > reach:
            object.__setattr__(self, "hough", self.hough.model_copy(update={"rho_max": reach}))
        return self


class LocalizerConfig(_Strict):
    """Everything the :class:`fusion.Localizer` needs besides the map."""

    sensors: dict[str, SensorConfig] = Field(default_factory=lambda: {"laser": SensorConfig()})
    filter: FilterConfig = FilterConfig()
    ambiguity: AmbiguityConfig = AmbiguityConfig()
    scan_odometry: ScanOdometryConfig = ScanOdometryConfig()
    initial_pose: tuple[float, float, float] | None = Field(
        None, description="m, m, rad: the pose at the first scan, in the map; none means global "
        "localization (an initial pose given to the Localizer or on the command line wins)")

    @model_validator(mode="after")
    def _scan_odometry_sensor_known(self) -> LocalizerConfig:
        so = self.scan_odometry
        if so.enabled and so.sensor is not None and so.sensor not in self.sensors:
            known = ", ".join(self.sensors)
            raise ValueError(f"scan_odometry.sensor {so.sensor!r} is not a configured sensor "
                             f"(configured: {known})")
        return self

    @property
    def scan_odometry_sensor(self) -> str | None:
        """The sensor whose scans correct the wheel odometry, None when none does."""
        so = self.scan_odometry
        if not so.enabled:
            return None
        if so.sensor is not None:
            return so.sensor
        return self.laser

    @classmethod
    def from_yaml(cls, path: str | Path | None) -> LocalizerConfig:
        """Defaults overlaid with the file's values; ``None`` gives the defaults.

        ``path`` may name a packaged configuration (``office-laser``: :mod:`fusion.resources`),
        or be the ``metrics.json`` of an earlier run, whose ``config`` (the whole effective
        configuration, initial pose included) is read: the run is reproduced."""
        if path is None:
            return cls()
        path = find_config(path)
        raw = read_yaml(path, ConfigError, "config") or {}
        if isinstance(raw, dict) and METRICS_VERSION_KEY in raw and "config" in raw:
            raw = raw["config"]
        return cls.from_dict(raw, source=str(path))

    @property
    def laser(self) -> str | None:
        """The first laser sensor's name (what a ROS bag's scans feed), None without one."""
        return next((name for name, s in self.sensors.items() if s.kind == "laser"), None)

    def with_mount(self, sensor: str, mount: tuple[float, float, float]) -> LocalizerConfig:
        """This configuration with ``sensor`` mounted at ``mount`` (validated again: the
        Hough grid's reach depends on the mount)."""
        raw = self.as_dict()
        raw["sensors"][sensor]["mount"] = list(mount)
        return type(self).from_dict(raw, source=f"mount of {sensor}")

    def as_dict(self) -> dict[str, Any]:
        """Every setting, defaults included, as plain YAML/JSON values: what ``from_dict``
        reads back to the same configuration."""
        return self.model_dump(mode="json")

    @classmethod
    def from_dict(cls, raw: object, source: str = "<dict>") -> LocalizerConfig:
        return validated(cls, raw, ConfigError, "config", source)

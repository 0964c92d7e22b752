"""fusion: the filter framework around the Hough method — EKF, streaming localizer, readers,
simulator, Rerun logging and the ``houghloc`` command line.

    from fusion import Localizer
    loc = Localizer.from_config("office-laser", map=m, initial_pose=(x, y, theta))
    loc.on_odometry(t, x_odom, y_odom, theta_odom); est = loc.on_scan(t, ranges, angles)
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from houghloc import __version__

if TYPE_CHECKING:
    from fusion.config import ConfigError, LocalizerConfig, SensorConfig
    from fusion.estimate import Estimate
    from fusion.localizer import Localizer

_EXPORTS = {
    "ConfigError": "fusion.config",
    "Estimate": "fusion.estimate",
    "Localizer": "fusion.localizer",
    "LocalizerConfig": "fusion.config",
    "SensorConfig": "fusion.config",
}
"""The public names, each loaded from its module when first used: ``import fusion.config``
loads the settings, not the localizer."""

__all__ = [
    "ConfigError",
    "Estimate",
    "Localizer",
    "LocalizerConfig",
    "SensorConfig",
    "__version__",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'fusion' has no attribute {name!r}")

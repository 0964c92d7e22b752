"""fusion: the filter framework around the Hough method — EKF, streaming localizer, readers,
simulator, Rerun logging and the ``houghloc`` command line.

    from fusion import Localizer
    loc = Localizer.from_config("office-laser", map=m, initial_pose=(x, y, theta))
    loc.on_odometry(t, x_odom, y_odom, theta_odom); est = loc.on_scan(t, ranges, angles)
"""

from fusion.config import ConfigError, LocalizerConfig, SensorConfig
from fusion.localizer import Estimate, Localizer
from houghloc import __version__

__all__ = ["ConfigError", "Estimate", "Localizer", "LocalizerConfig", "SensorConfig", "__version__"]

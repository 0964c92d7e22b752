"""houghloc: self-localization by the Hough transform (Iocchi & Nardi), as pure functions (the
per-scan steps compiled with Numba, see houghloc.jit).

    from houghloc import SegmentMap, HoughConfig, localize_scan
    m = SegmentMap.from_yaml("fusion/configs/maps/robocup.yaml")
    c = localize_scan(points_xy, m, guess=(x, y, theta), config=HoughConfig())
    c.pose, c.delta, c.cov, c.rank, c.matches
"""

from importlib.metadata import PackageNotFoundError, version

from houghloc.config import HoughConfig
from houghloc.global_match import GlobalMatchConfig, global_match
from houghloc.hypothesis_scores import Hypothesis
from houghloc.localize import ScanCorrection, localize_scan, observe_lines
from houghloc.match_result import GlobalResult
from houghloc.segment_map import MapError, References, SegmentMap

__all__ = [
    "GlobalMatchConfig",
    "GlobalResult",
    "HoughConfig",
    "Hypothesis",
    "MapError",
    "References",
    "ScanCorrection",
    "SegmentMap",
    "__version__",
    "global_match",
    "localize_scan",
    "observe_lines",
]
try:
    __version__ = version("houghloc")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

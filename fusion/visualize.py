"""What the pipeline reports about each stage: the :class:`Logger` protocol. ``NullLogger``
does nothing; :class:`fusion.rerun_logger.RerunLogger` records to Rerun. The pipeline never
tests which one it has."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from fusion.estimate import Estimate
    from houghloc import ScanCorrection, SegmentMap


class Logger(Protocol):
    """Every stage's report, in the order a run makes them."""

    def log_map(self, segment_map: SegmentMap) -> None:
        """The map, once, before the first scan."""

    def log_odometry(self, t: float, odom_pose: ArrayLike) -> None:
        """An odometry pose (x, y, θ) in the odometry's own frame, after calibration."""

    def log_scan(self, t: float, index: int, sensor: str, points: NDArray[np.float64],
                 correction: ScanCorrection | None, estimate: Estimate) -> None:
        """One scan (``index`` from 0): its robot-frame points, the Hough fix when one was
        computed, and the estimate after using it."""

    def log_truth(self, t: float, pose: ArrayLike) -> None:
        """A ground-truth pose, when the run has one."""

    def log_state(self, t: float, state: str, reason: str) -> None:
        """A transition of the ambiguity manager and why."""

    def log_hypotheses(self, t: float, poses: ArrayLike, scores: ArrayLike) -> None:
        """Global localization's candidate poses (N×3) and their scores."""

    def flush(self) -> None:
        """Send what is buffered."""

    def close(self) -> None:
        """Flush and finish the recording."""


class NullLogger:
    """A :class:`Logger` that discards everything (the default: no cost when nobody watches)."""

    def log_map(self, segment_map: SegmentMap) -> None: ...

    def log_odometry(self, t: float, odom_pose: ArrayLike) -> None: ...

    def log_scan(self, t: float, index: int, sensor: str, points: NDArray[np.float64],
                 correction: ScanCorrection | None, estimate: Estimate) -> None: ...

    def log_truth(self, t: float, pose: ArrayLike) -> None: ...

    def log_state(self, t: float, state: str, reason: str) -> None: ...

    def log_hypotheses(self, t: float, poses: ArrayLike, scores: ArrayLike) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...

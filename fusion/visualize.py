"""What the pipeline reports about each stage. ``NullLogger`` does nothing; the Rerun logger
(``fusion.rerun_logger``) has the same methods. The pipeline never tests which one it has."""

from __future__ import annotations

from typing import Any


class NullLogger:
    """A logger that discards everything (the default: no cost when nobody is watching)."""

    def log_map(self, segment_map: Any) -> None: ...

    def log_odometry(self, t: float, odom_pose: Any) -> None: ...

    def log_scan(self, t: float, index: int, sensor: str, points: Any, correction: Any,
                 estimate: Any) -> None: ...

    def log_truth(self, t: float, pose: Any) -> None: ...

    def log_state(self, t: float, state: str, reason: str) -> None: ...

    def log_hypotheses(self, t: float, poses: Any, scores: Any) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...

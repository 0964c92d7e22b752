"""``houghloc ros2``: spin the node until a signal, and end cleanly."""

from __future__ import annotations

import signal
import sys
import threading

import numpy as np
import rclpy
from numpy.typing import NDArray

from fusion.config import LocalizerConfig
from fusion.ros2.node import LocalizerNode
from fusion.visualize import Logger
from houghloc import SegmentMap

STOP_CHECK_SECONDS = 0.1
"""s: how long a signal to stop may wait for the spin to notice it."""


def run_node(segment_map: SegmentMap | None, config: LocalizerConfig | None,
             initial_pose: NDArray[np.float64] | None, logger: Logger,
             ros_args: list[str], managed: bool = False) -> int:
    """``houghloc ros2``: spin the node until Ctrl-C, SIGTERM (as ``ros2 launch`` and systemd
    stop a node) or a shutdown; 0 when it ends cleanly. ``managed``: wait in the unconfigured
    state for a lifecycle manager (nav2's) rather than configure and activate at once."""
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    # A signal only asks the loop below to stop. Raised as an exception (Ctrl-C's
    # KeyboardInterrupt) it could land inside rclpy's own code, an executor half built, and
    # leave a traceback; rclpy's own handlers would shut the context down under the node
    # still being built. So rclpy installs none, and the context ends in the `finally`. A
    # signal the parent set to be ignored stays ignored (a shell without job control starts
    # its background jobs with SIGINT ignored, so that Ctrl-C at the prompt spares them).
    stop = threading.Event()
    previous = {signum: signal.signal(signum, lambda *_: stop.set())
                for signum in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(signum) is not signal.SIG_IGN}
    node: LocalizerNode | None = None
    executor: SingleThreadedExecutor | None = None
    try:
        rclpy.init(args=["houghloc", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
        node = LocalizerNode(segment_map, config, initial_pose, logger, autostart=not managed)
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        while not stop.is_set():
            executor.spin_once(timeout_sec=STOP_CHECK_SECONDS)
    except ExternalShutdownException:
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        # printed, not logged: the ROS context (and /rosout) is shut down by now
        scans, dropped = (node.scans, node.dropped_scans) if node is not None else (0, 0)
        print(f"houghloc: {scans} scans localized, {dropped} dropped", file=sys.stderr)
    return 0

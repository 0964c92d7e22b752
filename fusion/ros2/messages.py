"""ROS messages to and from houghloc's numbers: stamps, planar poses, 3×3 covariances.

Pure functions of the messages' fields (no rclpy import), so that they are shared by the node and
tested on any object with the same attributes.
"""

from __future__ import annotations

import array
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.io.rosbag import yaw_from_quaternion
from fusion.mapping.grid import OccupancyGrid
from houghloc.geometry import compose, inverse

POSE_INDEX = (0, 1, 5)
"""Where x, y and yaw sit in a ROS 6×6 pose covariance (x, y, z, roll, pitch, yaw)."""


def stamp_seconds(stamp: Any) -> float:
    """``builtin_interfaces/Time`` in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def set_stamp(stamp: Any, seconds: float) -> None:
    """Write seconds into a ``builtin_interfaces/Time`` (nanoseconds rounded, carried over)."""
    total = round(seconds * 1e9)
    stamp.sec, stamp.nanosec = divmod(total, 1_000_000_000)


def planar_pose(pose: Any) -> tuple[float, float, float]:
    """``geometry_msgs/Pose`` → (x, y, yaw)."""
    q = pose.orientation
    return (float(pose.position.x), float(pose.position.y),
            yaw_from_quaternion(q.x, q.y, q.z, q.w))


def planar_transform(transform: Any) -> tuple[float, float, float]:
    """``geometry_msgs/Transform`` → (x, y, yaw)."""
    t, q = transform.translation, transform.rotation
    return float(t.x), float(t.y), yaw_from_quaternion(q.x, q.y, q.z, q.w)


def set_planar_transform(transform: Any, xytheta: NDArray[np.float64]) -> None:
    """(x, y, yaw) → ``geometry_msgs/Transform`` on the floor."""
    x, y, theta = (float(v) for v in xytheta)
    transform.translation.x, transform.translation.y, transform.translation.z = x, y, 0.0
    q = transform.rotation
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0)


def set_planar_pose(pose: Any, xytheta: NDArray[np.float64]) -> None:
    """(x, y, yaw) → ``geometry_msgs/Pose`` on the floor (z = 0, rotation about z only)."""
    x, y, theta = (float(v) for v in xytheta)
    pose.position.x, pose.position.y, pose.position.z = x, y, 0.0
    q = pose.orientation
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0)


def planar_covariance(covariance: Any) -> NDArray[np.float64]:
    """The x, y, yaw block of a row-major 6×6 ROS covariance."""
    full = np.asarray(covariance, dtype=float).reshape(6, 6)
    return full[np.ix_(POSE_INDEX, POSE_INDEX)]


def ros_covariance(cov: NDArray[np.float64]) -> list[float]:
    """A 3×3 (x, y, yaw) covariance as ROS's row-major 6×6, z/roll/pitch left at zero."""
    full = np.zeros((6, 6))
    full[np.ix_(POSE_INDEX, POSE_INDEX)] = cov
    return [float(v) for v in full.ravel()]


def map_to_odom(map_pose: NDArray[np.float64],
                odom_pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """The transform from the odometry frame to the map that puts the robot's odometry pose on
    its map pose (what AMCL publishes on /tf): T_map_odom = T_map_base ⊕ T_odom_base⁻¹."""
    return compose(map_pose, inverse(odom_pose))


OCCUPIED_THRESH = 0.65
"""P(occupied) above which a cell is a wall: map_server's ``occupied_thresh`` default."""
FREE_THRESH = 0.196
"""P(occupied) below which a cell is free: map_server's ``free_thresh`` default."""


def grid_from_message(msg: Any, max_cells: int) -> OccupancyGrid:
    """``nav_msgs/OccupancyGrid`` → :class:`~fusion.mapping.OccupancyGrid`: values are percent
    occupied (−1 unknown), rows grow with y as in the message. ValueError naming the field for a
    grid that cannot be used (empty, too large, sizes that disagree, a rotated origin)."""
    info = msg.info
    width, height, resolution = int(info.width), int(info.height), float(info.resolution)
    if width <= 0 or height <= 0:
        raise ValueError(f"the map is empty ({width} × {height} cells)")
    if width * height > max_cells:
        raise ValueError(f"the map has {width} × {height} cells, more than the {max_cells} "
                         "houghloc.max_map_cells allows")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"info.resolution is {resolution}: not a cell size")
    x, y, yaw = planar_pose(info.origin)
    if not (math.isfinite(x) and math.isfinite(y)) or abs(math.remainder(yaw, math.tau)) > 1e-6:
        raise ValueError("info.origin: a rotated or non-finite origin is not supported (the "
                         "segment map is in the map frame)")
    values = np.asarray(msg.data, dtype=np.int8).ravel()  # array.array: no copy per cell
    if values.size != width * height:
        raise ValueError(f"data has {values.size} cells for {width} × {height}")
    percent = values.reshape(height, width).astype(np.float32)
    known = (percent >= 0) & (percent <= 100)
    probability = np.where(known, percent / 100.0, np.nan).astype(np.float32)
    occupied = known & (probability > OCCUPIED_THRESH)
    free = known & (probability < FREE_THRESH)
    probability[~occupied & ~free] = np.nan
    return OccupancyGrid(probability, occupied, free, resolution, (x, y))


def set_grid(msg: Any, grid: OccupancyGrid) -> Any:
    """Fill a ``nav_msgs/OccupancyGrid`` from a grid as ``map_server`` publishes one: 100
    occupied, 0 free, −1 unknown (the inverse of :func:`grid_from_message`)."""
    values = np.full(grid.shape, -1, dtype=np.int8)
    values[grid.free] = 0
    values[grid.occupied] = 100
    rows, cols = grid.shape
    msg.info.resolution = float(grid.resolution)
    msg.info.width, msg.info.height = int(cols), int(rows)
    set_planar_pose(msg.info.origin, np.array((grid.origin[0], grid.origin[1], 0.0)))
    msg.data = array.array("b", values.tobytes())
    return msg

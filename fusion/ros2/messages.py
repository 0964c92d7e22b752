"""ROS messages to and from houghloc's numbers: stamps, planar poses, 3×3 covariances.

Pure functions of the messages' fields (no rclpy import), so that they are shared by the node and
tested on any object with the same attributes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.io.rosbag import yaw_from_quaternion
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

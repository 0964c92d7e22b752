"""What the node publishes, made on configure and dropped on cleanup: the pose as AMCL's
``amcl_pose``, ``map → odom`` on ``/tf``, the hypotheses as a ``PoseArray`` for RViz, the
integrity output (``houghloc/localized``), the state in words, and a ``/diagnostics`` status.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped, TransformStamped
from numpy.typing import NDArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32, String

from fusion.estimate import Estimate
from fusion.integrity import is_localized
from fusion.ros2.messages import (
    map_to_odom,
    ros_covariance,
    set_planar_pose,
    set_planar_transform,
    set_stamp,
)
from fusion.ros2.settings import NodeSettings

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""/tf_static, the map and the state: a late subscriber still gets the last message."""
DIAGNOSTICS_PERIOD = 1.0
"""s between two /diagnostics statuses (diagnostic_updater's default rate)."""


class Outputs:
    """The node's publishers. The pose, the hypotheses and the probability are lifecycle
    publishers (silent unless the node is active); the state and the diagnostics say why."""

    def __init__(self, node: Any, settings: NodeSettings, with_tf: bool) -> None:
        self.node, self.settings = node, settings
        self.pose_pub = node.create_lifecycle_publisher(PoseWithCovarianceStamped,
                                                        settings.houghloc__pose_topic, 10)
        self.cloud_pub = node.create_lifecycle_publisher(PoseArray, "particle_cloud", 2)
        self.localized_pub = node.create_lifecycle_publisher(Float32, "houghloc/localized", 10)
        self.state_pub = node.create_publisher(String, "houghloc/state", LATCHED)
        self.diagnostics_pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.timer = node.create_timer(DIAGNOSTICS_PERIOD, self._diagnose)
        self.tf_pub = None
        if with_tf and settings.tf_broadcast:
            from tf2_msgs.msg import TFMessage

            self._tf_message = TFMessage
            self.tf_pub = node.create_publisher(TFMessage, "/tf", 100)
        self._state_text = ""
        self._probability = float("nan")
        self.state("configured")

    def destroy(self) -> None:
        for pub in (self.pose_pub, self.cloud_pub, self.localized_pub):
            self.node.destroy_lifecycle_publisher(pub)
        for plain in (self.state_pub, self.diagnostics_pub, self.tf_pub):
            if plain is not None:
                self.node.destroy_publisher(plain)
        self.node.destroy_timer(self.timer)

    def state(self, text: str) -> None:
        if text != self._state_text:
            self._state_text = text
            self.state_pub.publish(String(data=text))

    def estimate(self, estimate: Estimate, manager: Any,
                 odom: NDArray[np.float64] | None) -> None:
        s = self.settings
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = s.global_frame_id
        set_stamp(msg.header.stamp, estimate.t)
        set_planar_pose(msg.pose.pose, estimate.pose)
        msg.pose.covariance = ros_covariance(estimate.cov)
        self.pose_pub.publish(msg)
        if self.tf_pub is not None and odom is not None:
            tf = TransformStamped()
            tf.header.frame_id, tf.child_frame_id = s.global_frame_id, s.odom_frame_id
            set_stamp(tf.header.stamp, estimate.t + s.transform_tolerance)
            set_planar_transform(tf.transform, map_to_odom(estimate.pose, odom))
            self.tf_pub.publish(self._tf_message(transforms=[tf]))
        self._cloud(estimate, manager)
        # the integrity output (fusion.integrity): what a navigation stack should trust
        self._probability = float(estimate.localized_probability)
        self.localized_pub.publish(Float32(data=self._probability))
        reason = manager.transitions[-1].reason if manager.transitions else ""
        localized = "localized" if is_localized(self._probability) else "not localized"
        self.state(f"{manager.state.value}, {localized} ({reason})" if reason
                   else f"{manager.state.value}, {localized}")

    def _cloud(self, estimate: Estimate, manager: Any) -> None:
        """The hypotheses followed (RViz's particle cloud), or the one pose while tracking."""
        cloud = PoseArray()
        cloud.header.frame_id = self.settings.global_frame_id
        set_stamp(cloud.header.stamp, estimate.t)
        followed = [pose for pose, _weight in manager.followed] or [estimate.pose]
        for pose in followed:
            p = Pose()
            set_planar_pose(p, pose)
            cloud.poses.append(p)
        self.cloud_pub.publish(cloud)

    def _diagnose(self) -> None:
        """One status: OK when localized, WARN when not (or not yet), ERROR without a map."""
        node = self.node
        status = DiagnosticStatus(name=f"{node.get_name()}: localization",
                                  hardware_id=node.get_fully_qualified_name())
        if node.map is None:
            status.level, status.message = DiagnosticStatus.ERROR, "no map"
        elif is_localized(self._probability):
            status.level, status.message = DiagnosticStatus.OK, self._state_text
        else:
            status.level, status.message = DiagnosticStatus.WARN, self._state_text
        status.values = [KeyValue(key=k, value=v) for k, v in (
            ("localized_probability", f"{self._probability:.4f}"),
            ("scans", str(node.scans)), ("dropped_scans", str(node.dropped_scans)),
            ("map", node.map_source or "none"),
            ("walls", str(len(node.map)) if node.map is not None else "0"))]
        array = DiagnosticArray(status=[status])
        array.header.stamp = node.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)

"""The node's ROS parameters: nav2 AMCL's names where AMCL has the setting, houghloc's own under
``houghloc.``, so that a nav2 bringup's ``amcl:`` block of parameters runs the node unchanged
(AMCL's particle-filter settings, which houghloc has no use for, are accepted and ignored).

Read by :func:`declare` when the node is configured (as AMCL reads its own).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

AMCL_IGNORED = (
    "alpha1", "alpha2", "alpha3", "alpha4", "alpha5", "beam_skip_distance",
    "beam_skip_error_threshold", "beam_skip_threshold", "do_beamskip", "lambda_short",
    "laser_likelihood_max_dist", "laser_max_range", "laser_min_range", "laser_model_type",
    "max_beams", "max_particles", "min_particles", "pf_err", "pf_z", "recovery_alpha_fast",
    "recovery_alpha_slow", "resample_interval", "robot_model_type", "save_pose_rate",
    "sigma_hit", "update_min_a", "update_min_d", "z_hit", "z_max", "z_rand", "z_short",
)
"""nav2 AMCL's particle-filter and sensor-model parameters: declared so that AMCL's YAML loads,
unused (houghloc's own settings are its localizer config, ``houghloc.config``)."""


@dataclass(frozen=True)
class NodeSettings:
    """Every parameter the node reads, with its default; the ROS name of a field is the field's
    name with ``__`` read as ``.`` (``initial_pose__x`` is ``initial_pose.x``)."""

    # --- nav2 AMCL's names and defaults
    base_frame_id: str = "base_footprint"
    odom_frame_id: str = "odom"
    global_frame_id: str = "map"
    scan_topic: str = "scan"
    map_topic: str = "map"
    set_initial_pose: bool = False
    """Start at ``initial_pose.*`` on activation (else the saved pose, else globally)."""
    initial_pose__x: float = 0.0
    initial_pose__y: float = 0.0
    initial_pose__yaw: float = 0.0
    always_reset_initial_pose: bool = False
    """On activation, start from the initial pose again rather than the last estimate."""
    first_map_only: bool = False
    """Keep the first map received on ``map_topic``; later ones are ignored."""
    transform_tolerance: float = 1.0
    """s: map → odom is dated this far after the scan, as AMCL does, so that tf users can look
    it up until the next scan."""
    tf_broadcast: bool = True
    initialize_at_saved_pose: bool = True
    """On activation without ``set_initial_pose``, start at the pose saved in
    ``saved_pose_filepath`` when it is recent (``houghloc.saved_pose_max_age``)."""
    saved_pose_filepath: str = ""
    """Where the last pose is saved every ``houghloc.save_pose_period`` s; empty: nowhere."""

    # --- houghloc's own
    houghloc__map: str = ""
    """A segment map YAML (or a packaged map's name); empty: built from ``map_topic``."""
    houghloc__config: str = ""
    """A localizer YAML (or a packaged config's name); empty: the defaults."""
    houghloc__odom_topic: str = "odom"
    houghloc__odom_wait: float = 0.25
    """s a scan waits for the odometry at its time before it is fused without."""
    houghloc__pose_topic: str = "amcl_pose"
    houghloc__scan_topics: tuple[str, ...] = ()
    """Several lasers: one topic each (empty: ``scan_topic`` alone); each scan's mount is read
    from ``/tf_static`` by its ``frame_id``."""
    houghloc__save_pose_period: float = 2.0
    """s between two saves of the pose (nav2's ``save_pose_rate`` is 0.5 Hz)."""
    houghloc__saved_pose_max_age: float = 300.0
    """s: a saved pose older than this is not used (the robot may have been moved since)."""
    houghloc__max_map_cells: int = 25_000_000
    """An OccupancyGrid with more cells than this (5000 × 5000) is refused, not converted."""

    @staticmethod
    def ros_name(field: str) -> str:
        return field.replace("__", ".")


def declare(node: Any) -> None:
    """Declare every parameter (AMCL's ignored ones too) on ``node``, with its default."""
    for f in fields(NodeSettings):
        name = NodeSettings.ros_name(f.name)
        if isinstance(f.default, tuple):  # an empty list says no type: the type is declared
            node.declare_parameter(name, Parameter.Type.STRING_ARRAY)
        else:
            node.declare_parameter(name, f.default)
    for name in AMCL_IGNORED:
        node.declare_parameter(name, None, ParameterDescriptor(dynamic_typing=True))


def read(node: Any) -> NodeSettings:
    """The parameters' current values, typed as the defaults."""
    values: dict[str, Any] = {}
    for f in fields(NodeSettings):
        name = NodeSettings.ros_name(f.name)
        if isinstance(f.default, tuple):  # declared without a value: may still have none
            value = node.get_parameter_or(name, Parameter(name, value=[])).value
            values[f.name] = tuple(value or ())
        else:
            kind: Any = type(f.default)
            values[f.name] = kind(node.get_parameter(name).value)
    return NodeSettings(**values)

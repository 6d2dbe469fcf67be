"""/robot_description: the Panda URDF as std_msgs/String, transient local (a late subscriber such as
RViz still gets it), as robot_state_publisher publishes it on a full install."""

from __future__ import annotations

from pathlib import Path

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

TOPIC = "robot_description"
QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)


def publish_robot_description(node: Node, urdf_path: str | None = None):
    """Publish the URDF once (latched); returns the publisher (keep it, or the sample goes with it)."""
    if urdf_path is None:
        from vla_common.kinematics import panda_urdf_path

        urdf_path = panda_urdf_path()
    pub = node.create_publisher(String, TOPIC, QOS)
    pub.publish(String(data=Path(urdf_path).read_text()))
    return pub

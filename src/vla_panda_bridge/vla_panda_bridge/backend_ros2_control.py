"""A ros2_control arm as a bridge backend: the filtered command goes out as std_msgs/Float64MultiArray
to a JointGroupVelocityController (`/joint_velocity_controller/commands`), and that system's
sensor_msgs/JointState comes back as the measured state.

Such a controller holds its last command forever (it has no timeout), so the bridge publishes a
filtered command every control period — the safety layer's watchdog and braking live here, upstream.
"""

from __future__ import annotations

import math

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from vla_common.robot import JOINT_NAMES, NUM_JOINTS

from vla_panda_bridge.backend import JointSample


class Ros2ControlBackend:
    kind = "ros2_control"

    def __init__(self, node: Node, command_topic: str, joint_states_topic: str):
        self._node = node
        self._pub = node.create_publisher(Float64MultiArray, command_topic, 10)
        self._sub = node.create_subscription(
            JointState, joint_states_topic, self._on_joint_states, qos_profile_sensor_data
        )
        self._latest: JointSample | None = None
        self.received_at = -math.inf  # node-clock seconds of the latest valid state
        self._index: tuple[tuple[str, ...], np.ndarray | None] | None = None
        self.states_received = 0
        self.states_rejected = 0
        self.last_error = ""

    def read(self) -> JointSample | None:
        return self._latest

    def write(self, dq: np.ndarray) -> None:
        msg = Float64MultiArray()
        msg.data = [float(x) for x in dq]
        self._pub.publish(msg)

    def close(self, ack_timeout: float = 1.0) -> bool:
        """Zero command (the caller brakes through the safety filter first), held until the
        controller has acknowledged it (bounded): the process exits right after, and the controller
        would otherwise keep the last non-zero command it received."""
        self.write(np.zeros(NUM_JOINTS))
        return self._pub.wait_for_all_acked(Duration(seconds=ack_timeout))

    def _on_joint_states(self, msg: JointState) -> None:
        """Pick panda_joint1..7 by name (other joints, e.g. fingers, are ignored)."""
        names = tuple(msg.name)
        if self._index is None or self._index[0] != names:
            try:
                idx = np.array([names.index(n) for n in JOINT_NAMES])
            except ValueError:
                idx = None
            self._index = (names, idx)
        idx = self._index[1]
        if idx is None or len(msg.position) != len(names):
            self._reject(f"joint_states without all of {JOINT_NAMES[0]}..{JOINT_NAMES[-1]} positions")
            return
        pos = np.asarray(msg.position, dtype=float)[idx]
        if not np.all(np.isfinite(pos)):
            self._reject("joint_states with non-finite positions")
            return
        vel = np.asarray(msg.velocity, dtype=float)[idx] if len(msg.velocity) == len(names) else np.zeros(7)
        eff = np.asarray(msg.effort, dtype=float)[idx] if len(msg.effort) == len(names) else np.zeros(7)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self._latest = JointSample(pos, vel, eff, stamp)
        self.received_at = self._node.get_clock().now().nanoseconds * 1e-9
        self.states_received += 1

    def _reject(self, why: str) -> None:
        self.states_rejected += 1
        self.last_error = why
        self._node.get_logger().warn(why, throttle_duration_sec=2.0)

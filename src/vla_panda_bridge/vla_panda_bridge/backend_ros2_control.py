"""A ros2_control arm as a bridge backend: the filtered command goes out as std_msgs/Float64MultiArray
to a JointGroupVelocityController (`/joint_velocity_controller/commands`), and that system's
sensor_msgs/JointState comes back as the measured state.

Such a controller holds its last command forever (it has no timeout), so the bridge publishes a
filtered command every control period — the safety layer's watchdog and braking live here, upstream.
Time is the node's clock: a control timer at `control_rate`, a state relay at `state_rate`.
"""

from __future__ import annotations

import math
import time

import numpy as np
from rclpy.duration import Duration
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from vla_panda_bridge.backend import BackendBase, Host, JointSample


class Ros2ControlBackend(BackendBase):
    kind = "ros2_control"

    def __init__(self, host: Host):
        p = host.params
        self._host = host
        self._names = host.spec.joint_names
        self._no_state = np.full(len(self._names), np.nan)      # invalid on purpose: the filter brakes
        self._dt = 1.0 / p["control_rate"]
        self._state_timeout = p["state_timeout"]
        self._state_topic = p["robot_joint_states_topic"]
        self._pub = host.create_publisher(Float64MultiArray, p["command_topic"], 10)
        self._sub = host.create_subscription(JointState, self._state_topic, self._on_joint_states,
                                             qos_profile_sensor_data)
        self._latest: JointSample | None = None
        self.received_at = -math.inf  # node-clock seconds of the latest valid state
        self._index: tuple[tuple[str, ...], np.ndarray | None] | None = None
        self._stale = True
        self.states_received = 0
        self.states_rejected = 0
        self.last_error = ""
        in_topic = host.resolve_topic_name(self._state_topic)
        self._in_topic = in_topic
        self.publishes_joint_states = in_topic != host.resolve_topic_name("joint_states")
        if not self.publishes_joint_states:
            host.get_logger().info(f"the arm's joint states are already on {in_topic}; not republishing")

    # ---------------------------------------------------------------------------------- protocol
    def start(self, host: Host) -> None:
        host.create_timer(self._dt, host.control_step)
        host.create_timer(1.0 / host.params["state_rate"], self._relay_state)

    def now(self) -> float:
        return self._host.get_clock().now().nanoseconds * 1e-9

    def now_ns(self) -> int:
        return self._host.get_clock().now().nanoseconds

    def filter_position(self) -> np.ndarray:
        """The arm's latest position while it is fresher than state_timeout; else invalid (brake)."""
        sample = self._latest
        if sample is not None and self.now() - self.received_at <= self._state_timeout:
            self._stale = False
            return sample.position
        if not self._stale:
            self._host.get_logger().warn(f"no joint state from {self._state_topic} for "
                                         f"{self._state_timeout:g} s: braking to zero")
        self._stale = True
        return self._no_state

    def position(self) -> np.ndarray | None:
        return None if self._latest is None else self._latest.position

    def latest(self) -> JointSample | None:
        return self._latest

    def write(self, dq: np.ndarray) -> None:
        msg = Float64MultiArray()
        msg.data = [float(x) for x in dq]
        self._pub.publish(msg)

    def advance(self, dt: float) -> None:
        time.sleep(dt)

    def close(self, ack_timeout: float = 1.0) -> bool:
        """Zero command, held until the controller has acknowledged it (bounded): the process exits
        right after, and the controller would otherwise keep the last non-zero command it received."""
        self.write(np.zeros(len(self._names)))
        return self._pub.wait_for_all_acked(Duration(seconds=ack_timeout))

    def describe(self) -> str:
        p = self._host.params
        out = self._host.resolve_topic_name(p["command_topic"])
        return f"ros2_control: {p['control_rate']} Hz safety -> {out}; state from {self._in_topic}"

    # ------------------------------------------------------------------------------------ state
    def _relay_state(self) -> None:
        if self._latest is not None:
            self._host.publish_state()

    def _on_joint_states(self, msg: JointState) -> None:
        """Pick the robot's joints by name (other joints, e.g. fingers, are ignored)."""
        names = tuple(msg.name)
        if self._index is None or self._index[0] != names:
            try:
                idx = np.array([names.index(n) for n in self._names])
            except ValueError:
                idx = None
            self._index = (names, idx)
        idx = self._index[1]
        if idx is None or len(msg.position) != len(names):
            self._reject(f"joint_states without all of {self._names[0]}..{self._names[-1]} positions")
            return
        pos = np.asarray(msg.position, dtype=float)[idx]
        if not np.all(np.isfinite(pos)):
            self._reject("joint_states with non-finite positions")
            return
        n = len(self._names)
        vel = np.asarray(msg.velocity, dtype=float)[idx] if len(msg.velocity) == len(names) else np.zeros(n)
        eff = np.asarray(msg.effort, dtype=float)[idx] if len(msg.effort) == len(names) else np.zeros(n)
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._latest = JointSample(pos, vel, eff, stamp_ns or self.now_ns())
        self.received_at = self.now()
        self.states_received += 1

    def _reject(self, why: str) -> None:
        self.states_rejected += 1
        self.last_error = why
        self._host.get_logger().warn(why, throttle_duration_sec=2.0)

"""What the bridge needs from a robot, as one protocol: each backend is a strategy object behind it.

The node has one control path. Once per control period `Host.control_step()` runs
`filter(command, backend.filter_position(), backend.now())` and hands the result to
`backend.write(dq)`. Everything that differs between robots lives in the backend:

- how time advances: `start(host)` creates whatever calls `host.control_step()` once per control
  period and `host.publish_state()` once per state period (MuJoCo: physics steps paced to the wall
  clock, and /clock; ros2_control: timers on the node clock; libfranka: a 1 kHz loop in a process
  of its own that exchanges only the latest command and state through shared memory, plus a node
  timer). `advance(dt)` moves time on by one period while the node brakes at shutdown;
- the measured state, with its staleness (`filter_position`, `latest`), writing the filtered command
  (`write`), stamps (`now`, `now_ns`, `JointSample.stamp_ns`);
- the publishers and services it adds (`capabilities` names the optional services it serves; the
  node refuses the others with a clear message);
- the hand, if it drives one: `hand`, a non-blocking `gripper.HandDriver` (None: no hand; the
  node's gripper layer, the same for every backend, checks every request before it gets there);
- shutdown: after the node has braked through the filter, `close()` commands zero and waits
  (bounded) for it to be acknowledged.

A new backend is a module with a class that follows `Backend` (it may start from `BackendBase`) and
a row in `backends.BACKENDS`. Nothing here imports rclpy: a backend talks to ROS through the host.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from vla_common.robot import RobotSpec

# Optional services a backend may support (`Backend.capabilities`).
RESET = "reset"          # ~/reset: a new scene and arm pose (simulation only)
TEACHING = "teaching"    # ~/set_teaching: switch the servos off, the arm backdrivable


class BackendError(ValueError):
    """A parameter value the backend refuses at startup (the node exits with code 2)."""


class UnsupportedError(RuntimeError):
    """The backend does not offer this service; the message says why."""


@dataclass
class JointSample:
    """One joint state in the robot's joint order. `stamp_ns` is the time it was measured on the
    backend's clock (the stamp of the joint_states it becomes)."""

    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    stamp_ns: int


class Host(Protocol):
    """What a backend gets from the bridge node (a rclpy Node plus the bridge's own calls)."""

    params: Mapping[str, Any]
    spec: RobotSpec
    base_frame: str                 # frame_id of poses in the robot base
    image_qos: Any                  # the QoS of camera images (vla_common.ros.qos.IMAGE_QOS)

    def control_step(self) -> None:
        """One control period: filter the latest command against the measured state, write it."""

    def publish_state(self) -> None:
        """Publish joint_states and ee_pose from `latest()`."""

    def on_fault(self, text: str) -> None:
        """The robot stopped itself with a reflex (libfranka-like error name in `text`)."""

    def on_stop(self, why: str) -> None:
        """A stop the node's filter did not see (the robot side's own filter, `why` says which): the
        node's filter stops too, and motion needs a zero command (vla_common.arming)."""

    def submit_command(self, values) -> None:
        """A joint-velocity command for the safety filter, as if it came on joint_velocity_cmd."""

    def publish_periodic(self) -> None:
        """What the node publishes at status_rate (~/status, the hand's), when the backend's clock says."""

    def create_wall_timer(self, period: float, callback: Callable[[], None]) -> Any:
        """A timer on the steady clock (pacing that must run with use_sim_time and no /clock)."""

    def create_timer(self, period: float, callback: Callable[[], None]) -> Any: ...
    def create_publisher(self, msg_type: Any, topic: str, qos: Any) -> Any: ...
    def create_subscription(self, msg_type: Any, topic: str, callback: Callable, qos: Any) -> Any: ...
    def create_service(self, srv_type: Any, name: str, callback: Callable) -> Any: ...
    def get_logger(self) -> Any: ...
    def get_clock(self) -> Any: ...
    def resolve_topic_name(self, topic: str) -> str: ...


class Backend(Protocol):
    kind: str
    capabilities: frozenset[str]
    publishes_joint_states: bool    # False: the arm's own joint_states are already on that topic

    def start(self, host: Host) -> None:
        """Begin advancing time: from now on host.control_step() runs once per control period."""

    def now(self) -> float:
        """The control clock (s): command times and the filter's watchdog."""

    def now_ns(self) -> int:
        """The stamp of status messages (ns)."""

    def filter_position(self) -> np.ndarray | None:
        """The position the filter syncs its reference to this period: 7 values; None = no new
        measurement this period (the filter integrates); non-finite = no valid state (it brakes)."""

    def position(self) -> np.ndarray | None:
        """The current measured position (filter re-syncs after a reset, recovery, teaching)."""

    def external_torque(self) -> np.ndarray | None:
        """The measured external torque per joint (Nm) for the filter's contact slowing, or None."""

    def latest(self) -> JointSample | None:
        """The latest joint state to publish, or None if none is known yet."""

    def write(self, dq: np.ndarray) -> None:
        """Send a safety-filtered joint-velocity command."""

    def advance(self, dt: float) -> None:
        """Let one control period pass (used by the node's braking loop at shutdown)."""

    def close(self) -> bool:
        """Command zero and release resources; True once the zero is acknowledged."""

    def describe(self) -> str:
        """One line for the startup log."""

    def reset(self, request: Any, response: Any) -> Any:
        """~/reset (capability RESET); raises UnsupportedError otherwise."""

    def recover(self) -> str:
        """~/recover after a reflex: re-arm the robot's own checks; returns what was done."""

    def set_teaching(self, active: bool) -> str:
        """~/set_teaching (capability TEACHING); raises UnsupportedError otherwise."""


class BackendBase:
    """Defaults for the optional parts of `Backend`: no optional services, nothing to recover, no hand."""

    kind = "base"
    capabilities: frozenset[str] = frozenset()
    publishes_joint_states = True
    hand = None   # a gripper.HandDriver when the robot's hand is driven (the gripper layer wraps it)

    def reset(self, request: Any, response: Any) -> Any:
        raise UnsupportedError(f"~/reset needs the mujoco backend (a {self.kind} arm cannot be reset)")

    def recover(self) -> str:
        return "the robot reported no reflex"

    def external_torque(self) -> np.ndarray | None:
        return None

    def set_teaching(self, active: bool) -> str:
        raise UnsupportedError(f"teaching mode is not available with the {self.kind} backend "
                          "(it cannot switch the arm's servos off)")

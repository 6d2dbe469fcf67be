"""The bridge's gripper on ROS: the `~/gripper` service (vla_interfaces/srv/GripperCommand), the
`~/gripper_action` action (control_msgs/action/GripperCommand, where control_msgs is installed:
gripper_action.py), the `gripper/status` topic (vla_interfaces/msg/GripperStatus) and the finger
joints that join joint_states, around one `gripper.GripperCore` on the backend's hand driver (or
none: a backend without a hand refuses every request, and joint_states keep the 7 arm joints).

The node calls `update()` with every joint state it publishes (the core follows the driver; a change
is published at once) and `publish()` at the status rate; `set_estop`, `reset` follow the arm's.
"""
from __future__ import annotations

import math
from typing import Any

from vla_interfaces.msg import GripperStatus
from vla_interfaces.srv import GripperCommand
from vla_panda_bridge import gripper, gripper_action
from vla_panda_bridge.gripper import GripperCore


class GripperInterface:
    def __init__(self, host: Any, driver: gripper.HandDriver | None, now_fn, stamp_fn) -> None:
        self._host = host
        self._now, self._stamp = now_fn, stamp_fn
        self.core = GripperCore(driver, host.spec.hand) if driver is not None else None
        self.finger_joints: tuple[str, ...] = host.spec.hand.finger_joints if self.core else ()
        self._pub = host.create_publisher(GripperStatus, "gripper/status", 10)
        host.create_service(GripperCommand, "~/gripper", self._on_request)
        self._msg = GripperStatus()
        self.action = None
        if self.core is not None and gripper_action.AVAILABLE:
            self.action = gripper_action.GripperAction(host, self.core, now_fn)
        elif self.core is not None:
            host.get_logger().info("control_msgs is not installed: ~/gripper_action "
                                   "(control_msgs/action/GripperCommand) is not served; ~/gripper is")

    def close(self) -> None:
        """The hand goes with its backend: the action server too (a running goal is aborted)."""
        if self.action is not None:
            self.action.close()
            self.action = None

    # ------------------------------------------------------------------ the node's calls
    def update(self) -> None:
        """Follow the hand; publish a change at once."""
        if self.core is not None and self.core.update(self._now()):
            self.publish()
            self._log_change()
        if self.action is not None:
            self.action.update()

    def finger_state(self) -> tuple[list[float], list[float]]:
        """Positions and velocities of the finger joints (each half the gap) for joint_states."""
        if self.core is None:
            return [], []
        r = self.core.last_reading
        w = self.core.status.width
        v = r.finger_velocity if r is not None else 0.0
        return [w / 2, w / 2], [v / 2, v / 2]

    def set_estop(self, active: bool) -> None:
        if self.core is not None:
            self.core.set_estop(active)
            self.publish()

    def reset(self, text: str) -> None:
        if self.core is not None:
            self.core.reset(text)
            self.publish()

    def summary(self) -> tuple[str, bool]:
        """(the hand in words for ~/status, lost)."""
        if self.core is None:
            return "", False
        st = self.core.status
        return f"{gripper.STATE_NAMES[st.state]}: {st.text}", st.state == gripper.LOST

    def publish(self) -> None:
        msg = self._msg
        msg.header.stamp = self._stamp()
        if self.core is None:
            msg.state, msg.text = GripperStatus.NONE, f"the {self._host.backend.kind} backend has no hand"
            msg.width = msg.target_width = math.nan
            self._pub.publish(msg)
            return
        st = self.core.status
        msg.state, msg.text, msg.width = st.state, st.text, float(st.width)
        msg.target_width, msg.force, msg.holding = float(st.target_width), float(st.force), st.holding
        msg.estop_active = self.core.estop_active
        msg.commands_received, msg.commands_rejected = st.commands_received, st.commands_rejected
        self._pub.publish(msg)

    # ------------------------------------------------------------------ the service
    def _on_request(self, request: GripperCommand.Request, response: GripperCommand.Response):
        if self.core is None:
            response.success = False
            response.message = f"no hand: the {self._host.backend.kind} backend drives none"
            return response
        ok, text = self.core.request(int(request.command), self._now(), width=request.position,
                                     speed=request.speed, force=request.max_effort,
                                     epsilon_inner=request.epsilon_inner, epsilon_outer=request.epsilon_outer)
        response.success, response.message = ok, text
        log = self._host.get_logger()
        if ok:
            log.info(f"gripper: {text}")
        else:
            log.warn(f"gripper request refused: {text}", throttle_duration_sec=1.0)
        self.publish()
        return response

    def _log_change(self) -> None:
        st = self.core.status
        log = self._host.get_logger()
        if st.state in (gripper.GRASP_FAILED, gripper.LOST):
            log.error(f"gripper: {st.text}")
        else:
            log.info(f"gripper: {st.text}")

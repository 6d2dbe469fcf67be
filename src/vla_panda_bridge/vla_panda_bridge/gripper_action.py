"""The bridge's `~/gripper_action`: control_msgs/action/GripperCommand, what MoveIt and franka_ros2
users send a hand, beside our `~/gripper` service and behind the same gripper core (its checks, the
e-stop, the lost hand). Goals and results as `gripper_goal.py` maps them.

control_msgs is not a dependency: it is served only where `control_msgs.action` imports (a full ROS 2
install has it; the PyPI wheels of this machine do not), and the bridge says at startup which.
`AVAILABLE` tells. One goal runs at a time: a new one preempts it (aborted, as ros2_controllers'
gripper_action_controller does). Feedback at most every FEEDBACK_PERIOD s while the hand moves; a
cancel stops the hand where it is (a hand that holds keeps holding). Everything runs on the node's
executor: the goal is executed (finished) from `update()` once its outcome is known, so no callback
ever waits for the hand.
"""
from __future__ import annotations

from typing import Any

from rclpy.action import ActionServer, CancelResponse, GoalResponse

from vla_panda_bridge import gripper
from vla_panda_bridge.gripper_goal import GoalProgress, goal_progress, goal_request

try:
    from control_msgs.action import GripperCommand as GripperCommandAction
    AVAILABLE = True
except ImportError:  # control_msgs not installed: ~/gripper_action is not served
    GripperCommandAction = None
    AVAILABLE = False

NAME = "~/gripper_action"
FEEDBACK_PERIOD = 0.1   # s (franka_gripper: 10 Hz)


class GripperAction:
    """`~/gripper_action` on `core`, the node's gripper core; `update()` on every tick of the node."""

    def __init__(self, node: Any, core: gripper.GripperCore, now_fn) -> None:
        self._node, self.core, self._now = node, core, now_fn
        self._active = None          # (goal handle, target gap, force)
        self._finishing: dict = {}   # goal id -> (progress, text): results for execute()
        self._last_feedback = -float("inf")
        self.server = ActionServer(node, GripperCommandAction, NAME, execute_callback=self._execute,
                                   goal_callback=self._goal, handle_accepted_callback=self._accepted,
                                   cancel_callback=self._cancel)

    def close(self) -> None:
        if self._active is not None:
            self._finish("aborted: the hand was disconnected")
        self.server.destroy()

    # ------------------------------------------------------------------ the action's callbacks
    def _goal(self, goal) -> GoalResponse:
        c = goal.command
        req = goal_request(c.position, c.max_effort, self.core.status.width, self.core.limits.max_width)
        why = self.core.check(req.command, req.width, 0.0, req.force, req.epsilon_inner, req.epsilon_outer)
        if why is not None:
            self._node.get_logger().warn(f"gripper action goal refused: {why}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _accepted(self, handle) -> None:
        if self._active is not None:
            self._finish("aborted: preempted by a new goal")
        c = handle.request.command
        req = goal_request(c.position, c.max_effort, self.core.status.width, self.core.limits.max_width)
        ok, text = self.core.request(req.command, self._now(), width=req.width, force=req.force,
                                     epsilon_inner=req.epsilon_inner, epsilon_outer=req.epsilon_outer)
        self._node.get_logger().info(f"gripper action: {text}")
        self._active = (handle, req.width, req.force)
        self._last_feedback = -float("inf")
        if not ok:                   # the e-stop, requests too close together, a lost hand
            self._finish(f"aborted: {text}")
            return
        self.update()

    def _cancel(self, handle) -> CancelResponse:
        if self._active is None or self._active[0].goal_id != handle.goal_id:
            return CancelResponse.REJECT
        self.core.request(gripper.STOP, self._now())      # stops where it is; a grasp that holds holds
        return CancelResponse.ACCEPT

    def _execute(self, handle):
        progress, text = self._finishing.pop(bytes(handle.goal_id.uuid))
        if handle.is_cancel_requested:
            handle.canceled()
        elif progress.succeeded and not text.startswith("aborted"):
            handle.succeed()
        else:
            handle.abort()
        self._node.get_logger().info(f"gripper action: {text}")
        return _result(progress)

    # ------------------------------------------------------------------ following the hand
    def update(self) -> None:
        """Feedback while the hand moves; the goal finished once the core says it is over."""
        if self._active is None:
            return
        handle, target, force = self._active
        st = self.core.status
        progress = goal_progress(st.state, st.width, target, force)
        if progress.done:                # also after a cancel: the stop ended the motion
            self._finish(st.text)
            return
        now = self._now()
        if not 0.0 <= now - self._last_feedback < FEEDBACK_PERIOD:
            self._last_feedback = now
            handle.publish_feedback(_feedback(progress))

    def _finish(self, text: str) -> None:
        handle, target, force = self._active
        self._active = None
        st = self.core.status
        progress = goal_progress(st.state, st.width, target, force)
        self._finishing[bytes(handle.goal_id.uuid)] = (progress, text)
        handle.execute()


def _feedback(p: GoalProgress):
    return GripperCommandAction.Feedback(position=p.position, effort=p.effort, stalled=p.stalled,
                                         reached_goal=p.reached_goal)


def _result(p: GoalProgress):
    return GripperCommandAction.Result(position=p.position, effort=p.effort, stalled=p.stalled,
                                       reached_goal=p.reached_goal)

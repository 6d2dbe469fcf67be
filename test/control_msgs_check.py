"""Run by test_control_msgs.py where a control_msgs built from its definition is importable: the
bridge (MuJoCo, its simulated Franka Hand) serves control_msgs/action/GripperCommand as
panda_bridge/gripper_action beside its ~/gripper service: open and close with feedback and results,
a cancel that stops the hand where it is, a goal out of range rejected, the e-stop aborting a goal."""
import sys

import rclpy
from action_msgs.msg import GoalStatus
from control_msgs.action import GripperCommand
from rclpy.action import ActionClient
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool
from vla_common.ros.testing import RosHarness
from vla_panda_bridge.bridge_node import PandaBridge

from vla_panda_bridge import gripper_action

PARAMS = {"camera_rate": 0.0, "real_time_factor": 2.0, "scene_rate": 0.0, "seed": 3}


class Client:
    def __init__(self, h: RosHarness):
        self.h = h
        self.bridge = h.add(PandaBridge(context=h.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in PARAMS.items()]))
        self.node = h.add(rclpy.create_node("moveit_like", context=h.context))
        self.client = ActionClient(self.node, GripperCommand, "panda_bridge/gripper_action")
        self.estop = self.node.create_client(SetBool, "panda_bridge/estop")
        self.feedback: list = []
        assert self.client.wait_for_server(20.0), "panda_bridge/gripper_action is not served"

    def send(self, position: float, max_effort: float = 0.0):
        goal = GripperCommand.Goal()
        goal.command.position, goal.command.max_effort = position, max_effort
        self.feedback.clear()
        future = self.client.send_goal_async(goal, lambda m: self.feedback.append(m.feedback))
        assert self.h.spin_until(future.done, 20.0)
        return future.result()

    def result(self, handle):
        future = handle.get_result_async()
        assert self.h.spin_until(future.done, 30.0)
        return future.result()

    def width(self) -> float:
        return self.bridge.gripper.core.status.width


def open_and_close(c: Client) -> None:
    handle = c.send(0.04)                                 # one finger's travel: the gap 0.08 m
    assert handle.accepted
    done = c.result(handle)
    assert done.status == GoalStatus.STATUS_SUCCEEDED, done
    r = done.result
    assert r.reached_goal and not r.stalled and abs(r.position - 0.04) < 0.002, r
    assert c.feedback and all(0.0 <= f.position <= 0.0401 for f in c.feedback)
    assert any(f.position < 0.039 for f in c.feedback)    # fed back while the fingers moved
    handle = c.send(0.0, max_effort=30.0)                 # MoveIt's close, on nothing here
    assert handle.accepted                                # (refused when the open read 0.0801 m)
    done = c.result(handle)
    assert done.status == GoalStatus.STATUS_SUCCEEDED and done.result.reached_goal, done


def cancel_stops_where_it_is(c: Client) -> None:
    c.bridge.gripper.core.min_interval = 0.0
    handle = c.send(0.04)
    assert handle.accepted
    assert c.h.spin_until(lambda: 0.01 < c.width() < 0.05, 20.0)
    cancel = handle.cancel_goal_async()
    assert c.h.spin_until(cancel.done, 10.0) and cancel.result().goals_canceling
    done = c.result(handle)
    assert done.status == GoalStatus.STATUS_CANCELED, done
    stopped = c.width()
    assert 0.01 < stopped < 0.075 and abs(done.result.position - stopped / 2) < 0.002
    c.h.spin_for(1.0)
    assert abs(c.width() - stopped) < 0.001               # stays where the cancel stopped it


def refusals(c: Client) -> None:
    assert not c.send(0.5).accepted                       # a gap of 1 m: outside the hand's range
    assert not c.send(float("nan")).accepted
    handle = c.send(0.04)
    assert handle.accepted
    assert c.h.call(c.estop, SetBool.Request(data=True)).success
    done = c.result(handle)
    assert done.status == GoalStatus.STATUS_ABORTED and not done.result.reached_goal, done
    c.bridge.gripper.core.min_interval = 0.0
    latched = c.result(c.send(0.0))                       # while latched: accepted, then aborted
    assert latched.status == GoalStatus.STATUS_ABORTED, latched
    assert c.h.call(c.estop, SetBool.Request(data=False)).success


def main() -> int:
    assert gripper_action.AVAILABLE
    for check in (open_and_close, cancel_stops_where_it_is, refusals):
        h = RosHarness()
        try:
            check(Client(h))
        finally:
            h.shutdown()
    print("control_msgs gripper action ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())

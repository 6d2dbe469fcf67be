"""control_msgs/action/GripperCommand, as MoveIt and franka_ros2 users send the hand, served by the
bridge beside ~/gripper. control_msgs has no PyPI wheel: a control_msgs with the action's published
definition (ros-controls/control_msgs, the Jazzy release) is built here with colcon, and the bridge
is driven with it in a subprocess (test/control_msgs_check.py). Without control_msgs (the usual case
here) the bridge serves ~/gripper only and says so."""
from pathlib import Path

import interface_package
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

# control_msgs 5.x (ros-controls/control_msgs): msg/GripperCommand.msg and action/GripperCommand.action.
INTERFACES = {
    "msg/GripperCommand.msg": "float64 position\nfloat64 max_effort\n",
    "action/GripperCommand.action": (
        "GripperCommand command\n---\n"
        "float64 position\nfloat64 effort\nbool stalled\nbool reached_goal\n---\n"
        "float64 position\nfloat64 effort\nbool stalled\nbool reached_goal\n"),
}


@pytest.fixture(scope="module")
def control_msgs_install() -> Path:
    return interface_package.build("control_msgs", "5.3.0", INTERFACES, ["action_msgs"])


@pytest.mark.timeout(1800)
def test_the_bridge_serves_gripper_command_with_feedback_and_cancel(control_msgs_install):
    interface_package.run_check(control_msgs_install, "control_msgs_check.py",
                                "control_msgs gripper action ok")


def test_without_control_msgs_the_bridge_serves_the_service_only():
    from vla_panda_bridge import gripper_action

    assert gripper_action.AVAILABLE in (True, False)
    if not gripper_action.AVAILABLE:
        assert gripper_action.GripperCommandAction is None

"""The bridge's gripper with the MuJoCo backend, in-process: the finger joints in joint_states, the
~/gripper service and gripper/status, bad requests refused while the node keeps running, a grasp on
nothing reported once, the e-stop stopping a moving hand, the hand in ~/status."""
import math

import pytest
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool
from vla_common.ros.testing import RosHarness
from vla_panda_bridge.bridge_node import PandaBridge

from vla_interfaces.msg import GripperStatus, SafetyStatus
from vla_interfaces.srv import GripperCommand

pytestmark = pytest.mark.ros
FINGERS = ("panda_finger_joint1", "panda_finger_joint2")


class Bridge:
    def __init__(self):
        self.ros = RosHarness()
        params = {"camera_rate": 0.0, "real_time_factor": 4.0, "scene_rate": 0.0, "seed": 3}
        self.bridge = self.ros.add(PandaBridge(context=self.ros.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        self.probe = self.ros.add(rclpy.create_node("probe", context=self.ros.context))
        self.states: list[JointState] = []
        self.hand: list[GripperStatus] = []
        self.safety: list[SafetyStatus] = []
        self.probe.create_subscription(JointState, "joint_states", self.states.append, 100)
        self.probe.create_subscription(GripperStatus, "gripper/status", self.hand.append, 100)
        self.probe.create_subscription(SafetyStatus, "panda_bridge/status", self.safety.append, 100)
        self.gripper = self.probe.create_client(GripperCommand, "panda_bridge/gripper")
        self.estop = self.probe.create_client(SetBool, "panda_bridge/estop")
        assert self.ros.spin_until(lambda: self.states and self.hand, 20.0)

    def request(self, command, **fields):
        req = GripperCommand.Request(command=command)
        for k, v in fields.items():
            setattr(req, k, v)
        return self.ros.call(self.gripper, req)

    def fingers(self):
        msg = self.states[-1]
        names = list(msg.name)
        return [msg.position[names.index(f)] for f in FINGERS]

    def wait_state(self, state, timeout=20.0):
        return self.ros.spin_until(lambda: self.hand and self.hand[-1].state == state, timeout)


@pytest.fixture
def b():
    bridge = Bridge()
    yield bridge
    bridge.bridge.destroy_node()
    bridge.ros.shutdown()


def test_finger_joints_in_joint_states_follow_an_open(b):
    msg = b.states[-1]
    assert list(msg.name)[-2:] == list(FINGERS) and len(msg.position) == len(msg.name) == 9
    assert len(msg.velocity) == len(msg.effort) == 9
    assert max(b.fingers()) < 0.002                      # a reset hand is closed
    res = b.request(GripperCommand.Request.OPEN, speed=0.08)
    assert res.success, res.message
    assert b.wait_state(GripperStatus.MOVING, 5.0) or b.hand[-1].state == GripperStatus.IDLE
    assert b.wait_state(GripperStatus.IDLE)
    assert b.hand[-1].width == pytest.approx(0.08, abs=2e-3)
    assert b.ros.spin_until(lambda: min(b.fingers()) > 0.039, 5.0)
    assert b.fingers() == pytest.approx([0.04, 0.04], abs=1e-3)


def test_a_grasp_on_nothing_is_reported_once(b):
    assert b.request(GripperCommand.Request.OPEN, speed=0.1).success
    assert b.wait_state(GripperStatus.IDLE)
    b.ros.spin_for(0.3)
    res = b.request(GripperCommand.Request.GRASP, position=0.05, max_effort=30.0, speed=0.1)
    assert res.success, res.message
    assert b.wait_state(GripperStatus.GRASP_FAILED)
    assert "not retried" in b.hand[-1].text
    n = len([m for m in b.hand if m.state == GripperStatus.GRASPING])
    b.ros.spin_for(1.0)
    assert len([m for m in b.hand if m.state == GripperStatus.GRASPING]) == n   # no second attempt
    assert b.hand[-1].state == GripperStatus.GRASP_FAILED


@pytest.mark.parametrize("fields, why", [
    ({"command": 2, "position": math.nan}, "non-finite"),
    ({"command": 2, "position": -0.02}, "outside the hand's range"),
    ({"command": 2, "position": 0.5}, "outside the hand's range"),
    ({"command": 1, "position": 0.05, "max_effort": 1e9}, "rating"),
    ({"command": 1, "position": 0.05, "max_effort": math.inf}, "non-finite"),
    ({"command": 2, "position": 0.05, "speed": 1.0}, "speed"),
    ({"command": 99}, "unknown gripper command"),
])
def test_bad_requests_are_refused_and_the_node_keeps_running(b, fields, why):
    command = fields.pop("command")
    res = b.request(command, **fields)
    assert not res.success and why in res.message, res.message
    n = len(b.states)
    assert b.ros.spin_until(lambda: len(b.states) > n + 20, 10.0)  # joint_states keep flowing
    assert b.hand[-1].commands_rejected >= 1
    assert max(b.fingers()) < 0.002                                # nothing moved


def test_the_estop_stops_a_moving_hand_and_the_hand_shows_in_status(b):
    res = b.request(GripperCommand.Request.OPEN, speed=0.01)      # 8 s to open
    assert res.success
    assert b.ros.spin_until(lambda: 0.005 < sum(b.fingers()) < 0.03, 10.0)
    assert b.ros.call(b.estop, SetBool.Request(data=True)).success
    assert b.wait_state(GripperStatus.STOPPED)
    assert b.hand[-1].estop_active
    stopped = b.hand[-1].width                 # (joint_states reach the probe with some delay)
    assert 0.005 < stopped < 0.03
    assert b.ros.spin_until(lambda: abs(sum(b.fingers()) - stopped) < 1e-3, 10.0)
    b.ros.spin_for(1.0)
    assert sum(b.fingers()) == pytest.approx(stopped, abs=1e-3)   # stays where it stopped
    refused = b.request(GripperCommand.Request.OPEN)
    assert not refused.success and "e-stop" in refused.message
    assert b.ros.call(b.estop, SetBool.Request(data=False)).success
    b.ros.spin_for(0.5)
    assert sum(b.fingers()) == pytest.approx(stopped, abs=1e-3)   # releasing starts nothing
    assert b.ros.spin_until(lambda: b.safety and b.safety[-1].gripper.startswith("STOPPED"), 5.0)
    assert not b.safety[-1].gripper_lost


def test_a_flood_of_toggles_leaves_the_hand_bounded(b):
    replies = [b.request(GripperCommand.Request.TOGGLE) for _ in range(40)]
    assert replies[0].success
    assert any(not r.success and "too soon" in r.message for r in replies)
    b.ros.spin_for(1.0)
    st = b.hand[-1]
    assert st.force <= 70.0 and 0.0 <= st.width <= 0.0801
    assert n_states_flow(b)


def n_states_flow(b) -> bool:
    n = len(b.states)
    return b.ros.spin_until(lambda: len(b.states) > n + 10, 10.0)

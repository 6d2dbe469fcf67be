"""The Franka Hand on the libfranka backend against franka-sim's own gripper server (TCP 1338, its
kinematic hand: a command sets the width at once; a virtual object --gripper-object-width wide between
the fingers). panda_bridge with backend libfranka and gripper on, its hand process in the server's
network namespace (loop_prefix, as the arm's loop); everything through ~/gripper, ~/estop,
gripper/status and joint_states. Homing, a move and a grasp on nothing run the node's driver
(HandProcess) and GripperCore against a server without an object, with pylibfranka's Gripper and
panda-py's (its libfranka 0.9.2 speaks franka-sim's gripper protocol, version 3). Skipped (failed
where VLA_REQUIRE_FRANKA_SIM=1) where franka-sim or namespaces are missing."""

from __future__ import annotations

import math
import time

import pytest
import rclpy
from franka_sim_server import FrankaSimServer, running
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool
from vla_common.ros.testing import RosHarness
from vla_panda_bridge.gripper import GripperCore
from vla_panda_bridge.libfranka_hand import HandProcess
from vla_panda_bridge.libfranka_loop import LoopStatus

from vla_interfaces.msg import GripperStatus, SafetyStatus
from vla_interfaces.srv import GripperCommand
from vla_panda_bridge import gripper

pytestmark = [pytest.mark.slow, pytest.mark.ros]

OBJECT = 0.03            # m: the virtual object between franka-sim's fingers
RT_PRIORITY = 50         # as test_franka_sim_bridge: franka-sim and the loop under SCHED_FIFO
LIGHT = {"control_rate": 250, "state_rate": 250.0}
FR3_SCALES = {"acceleration_scale": 0.4999, "jerk_scale": 0.4999}
FINGERS = ("fr3_finger_joint1", "fr3_finger_joint2")
Req = GripperCommand.Request
# Bound of a condition wait. On these shared 2 cores the node and the test's subscriber starve each
# other at a load average of 10 (joint_states then arrive at a fraction of their rate; see
# test_franka_sim_bridge), so waits are generous: they end as soon as the condition holds.
SLOW = 30.0


@pytest.fixture(scope="module")
def sim():
    with running(priority=RT_PRIORITY, gripper=True, gripper_object_width=OBJECT) as server:
        yield server


class Bridge(RosHarness):
    def __init__(self, server: FrankaSimServer):
        super().__init__()
        from vla_panda_bridge.bridge_node import PandaBridge

        values = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
                  "realtime_config": "ignore", "loop_prefix": " ".join(server.netns.prefix()),
                  "robot_model": "fr3", "loop_priority": RT_PRIORITY, "gripper": True,
                  **LIGHT, **FR3_SCALES}
        self.node = self.add(PandaBridge(context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()]))
        self.io = self.add(rclpy.create_node("franka_sim_gripper_io", context=self.context))
        self.states: list[JointState] = []
        self.hand: list[GripperStatus] = []
        self.safety: list[SafetyStatus] = []
        self.io.create_subscription(JointState, "joint_states", self.states.append, 2000)
        self.io.create_subscription(GripperStatus, "gripper/status", self.hand.append, 200)
        self.io.create_subscription(SafetyStatus, "panda_bridge/status", self.safety.append, 200)
        self.gripper = self.io.create_client(GripperCommand, "panda_bridge/gripper")
        self.estop = self.io.create_client(SetBool, "panda_bridge/estop")

    def request(self, command: int, **fields) -> GripperCommand.Response:
        req = Req(command=command)
        for k, v in fields.items():
            setattr(req, k, v)
        return self.call(self.gripper, req)

    def command(self, command: int, **fields) -> GripperCommand.Response:
        """A request the core takes once the last one is min_interval old (a flood guard, not ours to
        wait out with a sleep: it is asked again until it is no longer 'too soon')."""
        end = time.monotonic() + 5.0
        while True:
            res = self.request(command, **fields)
            if res.success or "too soon" not in res.message or time.monotonic() > end:
                return res
            self.spin_for(0.02)

    def wait(self, state: int, text: str = "", timeout: float = SLOW) -> bool:
        return self.spin_until(lambda: bool(self.hand) and self.hand[-1].state == state
                               and text in self.hand[-1].text, timeout)

    def fingers(self) -> list[float]:
        msg = self.states[-1]
        names = list(msg.name)
        return [msg.position[names.index(f)] for f in FINGERS]

    def settle(self, state: int, text: str = "") -> GripperStatus:
        """The hand in `state` (a motion the core has seen end), and joint_states showing it."""
        assert self.wait(state, text), self.hand[-1] if self.hand else "no gripper/status"
        width = self.hand[-1].width
        assert self.spin_until(lambda: abs(sum(self.fingers()) - width) < 1e-4, SLOW), (
            self.node.backend.status, self.fingers(), width, len(self.states))
        return self.hand[-1]


@pytest.fixture(scope="module")
def bridge(sim):
    b = Bridge(sim)
    try:
        assert b.spin_until(lambda: b.node.backend.status.code == LoopStatus.OK and bool(b.states), 20.0), \
            b.node.backend.status
        assert b.wait(gripper.IDLE, timeout=20.0), b.hand[-1] if b.hand else "no gripper/status"
        yield b
    finally:
        b.shutdown()


def test_the_finger_joints_are_in_joint_states_with_the_hands_width(bridge):
    msg = bridge.states[-1]
    assert list(msg.name)[-2:] == list(FINGERS) and len(msg.position) == len(msg.velocity) == 9
    width = bridge.hand[-1].width                         # franka-sim's hand starts open
    assert width == pytest.approx(0.08, abs=1e-4)
    assert bridge.spin_until(lambda: abs(sum(bridge.fingers()) - width) < 1e-4, SLOW), bridge.fingers()
    assert bridge.fingers()[0] == pytest.approx(bridge.fingers()[1])
    assert bridge.spin_until(lambda: bridge.safety and not bridge.safety[-1].gripper_lost, SLOW)
    assert bridge.safety[-1].gripper.startswith("IDLE")


def test_homing_opens_the_hand(bridge):
    res = bridge.command(Req.HOMING)
    assert res.success, res.message
    st = bridge.settle(gripper.IDLE, "homed")
    assert st.width == pytest.approx(0.08, abs=1e-4)
    assert bridge.fingers() == pytest.approx([0.04, 0.04], abs=1e-4)


def test_a_move_reaches_its_width(bridge):
    assert bridge.command(Req.HOMING).success
    bridge.settle(gripper.IDLE, "homed")
    res = bridge.command(Req.MOVE, position=0.05, speed=0.05)
    assert res.success, res.message
    st = bridge.settle(gripper.IDLE, "moved")
    assert st.width == pytest.approx(0.05, abs=1e-4)
    assert bridge.fingers() == pytest.approx([0.025, 0.025], abs=1e-4)


def test_a_grasp_of_the_virtual_object_holds_it(bridge):
    assert bridge.command(Req.OPEN, speed=0.1).success
    bridge.settle(gripper.IDLE, "moved")
    res = bridge.command(Req.GRASP, position=OBJECT, speed=0.05, max_effort=30.0)
    assert res.success, res.message
    st = bridge.settle(gripper.HOLDING)
    assert st.width == pytest.approx(OBJECT, abs=1e-4) and st.force == 30.0
    assert bridge.spin_until(lambda: bridge.safety and bridge.safety[-1].gripper.startswith("HOLDING"), SLOW)
    # A grasp expecting a wider object closes on this one too, and is reported, once, not retried.
    assert bridge.command(Req.OPEN, speed=0.1).success
    bridge.settle(gripper.IDLE, "moved")
    assert bridge.command(Req.GRASP, position=0.06, max_effort=20.0).success
    bridge.settle(gripper.GRASP_FAILED, "not retried")
    n = sum(m.state == gripper.GRASPING for m in bridge.hand)
    bridge.spin_for(0.5)
    assert sum(m.state == gripper.GRASPING for m in bridge.hand) == n
    assert bridge.hand[-1].state == gripper.GRASP_FAILED


def test_the_estop_during_a_move_stops_the_hand_and_its_release_starts_nothing(bridge):
    assert bridge.command(Req.OPEN, speed=0.1).success
    bridge.settle(gripper.IDLE, "moved")
    core = bridge.node.gripper.core
    # The move and the e-stop in one go on the node (its ~/gripper and ~/estop handlers), so the
    # e-stop lands while the core still runs the move: franka-sim's hand is kinematic (a move ends
    # at once), so over the wire it would only ever see a finished one.
    def move():
        return bridge.node.gripper._on_request(Req(command=Req.MOVE, position=0.02, speed=0.05),
                                               GripperCommand.Response())
    res = move()
    while not res.success and "too soon" in res.message:      # min_interval after the open
        bridge.spin_for(0.02)
        res = move()
    assert res.success and core.status.state == gripper.MOVING, res.message
    assert bridge.node._on_estop(SetBool.Request(data=True), SetBool.Response()).success
    assert core.status.state == gripper.STOPPED and "e-stop" in core.status.text
    # Where the hand stops depends on how far the move got: not sent yet (the stop dropped it: open),
    # in flight (franka-sim runs it, then the stop, which opens its hand) or done (at the object).
    hand = bridge.node.backend.hand
    assert bridge.spin_until(lambda: not hand.read().moving, SLOW)
    stopped = hand.read().width
    assert stopped == pytest.approx(0.08, abs=1e-4) or stopped == pytest.approx(OBJECT, abs=1e-4), stopped
    assert bridge.spin_until(lambda: abs(sum(bridge.fingers()) - stopped) < 1e-4, SLOW), bridge.fingers()
    assert bridge.wait(gripper.STOPPED) and bridge.hand[-1].estop_active
    refused = bridge.request(Req.OPEN)
    assert not refused.success and "e-stop" in refused.message
    assert bridge.call(bridge.estop, SetBool.Request(data=False)).success
    n = len(bridge.states)
    assert bridge.spin_until(lambda: len(bridge.states) > n + 50, SLOW)
    assert sum(bridge.fingers()) == pytest.approx(stopped, abs=1e-4)     # nothing started by itself
    assert hand.read().width == pytest.approx(stopped, abs=1e-4) and not hand.read().moving
    assert bridge.hand[-1].state == gripper.STOPPED and not bridge.hand[-1].estop_active


@pytest.mark.parametrize("fields, why", [
    ({"command": Req.MOVE, "position": math.nan}, "non-finite"),
    ({"command": Req.MOVE, "position": -0.02}, "outside the hand's range"),
    ({"command": Req.MOVE, "position": 0.5}, "outside the hand's range"),
    ({"command": Req.GRASP, "position": 0.03, "max_effort": 1e9}, "rating"),
    ({"command": Req.GRASP, "position": 0.03, "max_effort": -5.0}, "rating"),
    ({"command": Req.MOVE, "position": 0.05, "speed": math.inf}, "non-finite"),
    ({"command": 77}, "unknown gripper command"),
])
def test_bad_requests_are_refused_before_the_hand(bridge, sim, fields, why):
    before = sim.log().count("Gripper command")
    hand = bridge.node.backend.hand
    assert bridge.spin_until(lambda: not hand.read().moving, SLOW)
    width = hand.read().width
    res = bridge.request(**fields)
    assert not res.success and why in res.message, res.message
    n = len(bridge.states)
    assert bridge.spin_until(lambda: len(bridge.states) > n + 20, SLOW)     # the node keeps running
    assert sim.log().count("Gripper command") == before     # franka-sim logs each command it fails: none
    assert hand.read().width == pytest.approx(width, abs=1e-4) and not hand.read().moving


def test_a_flood_of_toggles_is_refused_not_obeyed(bridge):
    t0 = time.monotonic()
    replies = [bridge.request(Req.TOGGLE) for _ in range(30)]
    span = time.monotonic() - t0         # at most one accepted per MIN_INTERVAL of it (load stretches it)
    accepted = sum(r.success for r in replies)
    assert replies[0].success and accepted <= 1 + span / gripper.MIN_INTERVAL, [r.message for r in replies]
    assert accepted < len(replies)
    assert any("too soon" in r.message for r in replies if not r.success)
    n = len(bridge.states)
    assert bridge.spin_until(lambda: len(bridge.states) > n + 20, SLOW)
    st = bridge.hand[-1]
    assert st.state != gripper.LOST and 0.0 <= st.width <= 0.08 and st.force <= 70.0


def test_a_killed_server_makes_the_hand_lost_and_the_arm_keeps_its_bridge(bridge, sim):
    """Last: franka-sim killed; the hand reads LOST in gripper/status and ~/status, then answers again."""
    sim.kill()
    assert bridge.wait(gripper.LOST, timeout=15.0), bridge.hand[-1]
    assert bridge.spin_until(lambda: bridge.safety and bridge.safety[-1].gripper_lost, SLOW)
    refused = bridge.request(Req.OPEN)
    assert not refused.success and "lost" in refused.message
    sim.start()
    assert bridge.wait(gripper.IDLE, "answers again", timeout=20.0), bridge.hand[-1]
    assert bridge.command(Req.MOVE, position=0.06).success
    assert bridge.wait(gripper.IDLE, "moved to 0.060")


@pytest.mark.parametrize("binding", ["pylibfranka", "panda_py"])
def test_a_grasp_on_nothing_is_grasp_failed(binding):
    """franka-sim without an object: the fingers close to 0, outside the band around 0.04 m. Both
    bindings: panda-py's libfranka 0.9.2 speaks the same gripper protocol (version 3) as franka-sim."""
    with running(priority=RT_PRIORITY, gripper=True) as server:
        hand = HandProcess("127.0.0.1", 0.08, binding, server.netns.prefix())
        try:
            core = GripperCore(hand)
            clock = iter(range(1, 10**9))

            def until(cond, timeout=SLOW) -> bool:
                end = time.monotonic() + timeout
                while time.monotonic() < end:
                    core.update(next(clock))
                    if cond():
                        return True
                    time.sleep(0.005)     # a poll period (the core is polled, as the node's timer does)
                return False

            def done(text: str) -> bool:
                return until(lambda: core.status.state == gripper.IDLE and text in core.status.text)
            assert until(lambda: core.status.state == gripper.IDLE), core.status
            assert core.request(gripper.HOMING, next(clock))[0]
            assert done("homed to 0.080"), core.status
            assert core.request(gripper.MOVE, next(clock), width=0.05)[0]
            assert done("moved to 0.050"), core.status
            ok, text = core.request(gripper.GRASP, next(clock), width=0.04, force=20.0)
            assert ok, text
            assert until(lambda: core.status.state == gripper.GRASP_FAILED), core.status
            assert core.status.width == pytest.approx(0.0, abs=1e-4) and core.holding == ""
            assert "not retried" in core.status.text
        finally:
            hand.close()

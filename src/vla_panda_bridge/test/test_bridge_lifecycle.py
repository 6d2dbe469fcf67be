"""The bridge as a managed (lifecycle) node, driven through its standard `~/change_state` service as a
lifecycle manager (or `ros2 lifecycle set`) drives it: configure connects, activate moves, deactivate
brakes and holds, cleanup disconnects; every way back to motion needs a zero command. On MuJoCo and on
franka-sim (skip or fail by VLA_REQUIRE_FRANKA_SIM, as the other franka-sim tests)."""

from __future__ import annotations

import time

import pytest
import rclpy
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool
from vla_common.ros.testing import RosHarness
from vla_common.safety_status import SafetyCode
from vla_panda_bridge.bridge_node import PandaBridge

from vla_interfaces.msg import SafetyStatus
from vla_interfaces.srv import ResetScene

pytestmark = pytest.mark.ros
JOINT = 6
MOVE = [0.0] * JOINT + [0.3]
ZERO = [0.0] * 7


class Managed:
    """The bridge with autostart off, a lifecycle manager's clients, and a command stream."""

    def __init__(self, h: RosHarness, **params):
        self.h = h
        self.bridge = h.add(PandaBridge(context=h.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in {"autostart": False, **params}.items()]))
        self.io = io = h.add(rclpy.create_node("manager", context=h.context))
        self.states: list[JointState] = []
        self.status: list[SafetyStatus] = []
        io.create_subscription(JointState, "joint_states", self.states.append, 100)
        io.create_subscription(SafetyStatus, "panda_bridge/status", self.status.append, 50)
        self.cmd = io.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        self.stick = list(ZERO)
        self.gaps = False            # the stick held with 0.3 s gaps in its stream (a lossy link)
        io.create_timer(0.02, self._send)
        self._change = io.create_client(ChangeState, "panda_bridge/change_state")
        self._get = io.create_client(GetState, "panda_bridge/get_state")

    def _send(self) -> None:
        if not (self.gaps and time.monotonic() % 0.6 >= 0.3):
            self.cmd.publish(Float64MultiArray(data=self.stick))

    def transition(self, tid: int) -> bool:
        return self.h.call(self._change, ChangeState.Request(transition=Transition(id=tid))).success

    def state(self) -> int:
        return self.h.call(self._get, GetState.Request()).current_state.id

    def velocity(self) -> float:
        return abs(self.states[-1].velocity[JOINT]) if self.states else 0.0

    def why(self) -> str:
        loop = getattr(self.bridge.backend, "status", "")
        return f"node filter armed {self.bridge.filter.arming.armed}, {loop}"

    def moving(self) -> bool:
        return self.velocity() > 0.25

    def at_rest(self) -> bool:
        return self.velocity() < 1e-3

    def armed(self) -> bool:
        """The bridge took the operator's zero, and so did the libfranka loop (which waits for one after
        every connection): motion may follow."""
        loop = getattr(self.bridge.backend, "status", None)
        return self.bridge.filter.arming.armed and (loop is None
                                                    or loop.filter_code != SafetyCode.AWAITING_ZERO)

    def still_for(self, n: int) -> bool:
        """The joint stays at rest over the next n joint states (the stick held meanwhile)."""
        start = len(self.states)
        ok = self.h.spin_until(lambda: len(self.states) >= start + n, 20.0)
        return ok and max(abs(s.velocity[JOINT]) for s in self.states[start:]) < 1e-3


def drive_through_the_lifecycle(m: Managed) -> None:
    h = m.h
    assert m.state() == State.PRIMARY_STATE_UNCONFIGURED
    m.stick = MOVE
    h.spin_for(0.3)
    assert not m.states                                  # nothing connected, nothing moves

    assert m.transition(Transition.TRANSITION_CONFIGURE)
    assert m.state() == State.PRIMARY_STATE_INACTIVE
    assert m.transition(Transition.TRANSITION_ACTIVATE)
    assert m.state() == State.PRIMARY_STATE_ACTIVE
    m.stick = ZERO
    assert h.spin_until(m.armed, 20.0)
    m.stick = MOVE
    assert h.spin_until(m.moving, 20.0)

    assert m.transition(Transition.TRANSITION_DEACTIVATE)  # brakes and holds, the stick still held
    assert h.spin_until(m.at_rest, 10.0)
    assert m.still_for(40)
    assert m.status[-1].code == SafetyStatus.AWAITING_ZERO and "deactivated" in m.status[-1].text

    assert m.transition(Transition.TRANSITION_ACTIVATE)  # active again, the stick held: no motion,
    m.gaps = True                                        # with or without 0.3 s gaps in its stream
    assert m.still_for(200)
    m.gaps = False
    assert m.still_for(40)
    assert m.status[-1].code == SafetyStatus.AWAITING_ZERO
    m.stick = ZERO                                       # the operator's neutral, then motion
    assert h.spin_until(m.armed, 20.0), m.why()
    m.stick = MOVE
    assert h.spin_until(m.moving, 20.0)

    assert m.transition(Transition.TRANSITION_DEACTIVATE)
    assert h.spin_until(m.at_rest, 10.0)
    assert m.transition(Transition.TRANSITION_CLEANUP)  # disconnected: no loop, no states
    assert m.state() == State.PRIMARY_STATE_UNCONFIGURED
    assert m.bridge.backend is None
    n = m.bridge.states_published
    h.spin_for(0.3)
    assert m.bridge.states_published == n
    estop = m.io.create_client(SetBool, "panda_bridge/estop")
    assert h.call(estop, SetBool.Request(data=True)).success    # the e-stop works in every state
    assert h.call(estop, SetBool.Request(data=False)).success

    assert m.transition(Transition.TRANSITION_CONFIGURE)  # connected again: a stop like any other
    assert m.transition(Transition.TRANSITION_ACTIVATE)
    assert m.still_for(40)
    m.stick = ZERO
    assert h.spin_until(m.armed, 20.0), m.why()
    m.stick = MOVE
    assert h.spin_until(m.moving, 20.0)
    assert m.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    assert m.state() == State.PRIMARY_STATE_FINALIZED
    assert m.bridge.backend is None


def test_mujoco_bridge_through_configure_activate_deactivate_cleanup_shutdown():
    h = RosHarness()
    try:
        m = Managed(h, camera_rate=0.0, real_time_factor=1.0, command_timeout=0.5)
        reset = m.io.create_client(ResetScene, "panda_bridge/reset")
        answer = h.call(reset, ResetScene.Request(use_seed=True, seed=3))
        assert not answer.success and "not configured" in answer.message
        drive_through_the_lifecycle(m)
    finally:
        h.shutdown()


def test_a_configure_that_fails_leaves_the_node_unconfigured_with_the_reason():
    """libfranka without a robot_ip: configure answers failure, the node stays unconfigured."""
    h = RosHarness()
    try:
        m = Managed(h, backend="libfranka", robot_ip="")
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == State.PRIMARY_STATE_UNCONFIGURED
        assert m.bridge._config_error
    finally:
        h.shutdown()


def test_franka_sim_bridge_through_the_lifecycle():
    from franka_sim_server import running

    with running(priority=50) as sim:
        h = RosHarness()
        try:
            m = Managed(h, backend="libfranka", robot_ip="127.0.0.1", driver="pylibfranka",
                        realtime_config="ignore", loop_prefix=" ".join(sim.netns.prefix()),
                        loop_priority=50, control_rate=250, robot_model="fr3", gripper=False,
                        acceleration_scale=0.4999, jerk_scale=0.4999, command_timeout=0.5)
            drive_through_the_lifecycle(m)
        finally:
            h.shutdown()


def test_deactivate_ends_teaching_mode_and_holds_the_arm_against_a_push():
    """The README: deactivate brakes and holds. In teaching mode (servos off, the arm backdrivable) a
    deactivate left the servos off, and a hand pushing the arm moved it. Now deactivate leaves teaching
    mode (servos on, holding the pose), a push moves nothing, and teaching cannot start while inactive."""
    h = RosHarness()
    try:
        m = Managed(h, camera_rate=0.0, real_time_factor=1.0, command_timeout=0.5)
        assert m.transition(Transition.TRANSITION_CONFIGURE) and m.transition(Transition.TRANSITION_ACTIVATE)
        assert h.spin_until(m.armed, 20.0) and m.still_for(20)
        teaching = m.io.create_client(SetBool, "panda_bridge/set_teaching")
        assert h.call(teaching, SetBool.Request(data=True)).success
        sim = m.bridge.backend.sim
        assert sim.teaching
        assert m.transition(Transition.TRANSITION_DEACTIVATE)
        assert not sim.teaching and not m.bridge.filter.teaching
        assert m.status[-1].code == SafetyStatus.AWAITING_ZERO and "deactivated" in m.status[-1].text
        q0, hand = sim.q, sim.model.body("panda_hand").id
        sim.data.xfrc_applied[hand, :3] = [0.0, 8.0, 0.0]      # a hand pulls sideways for 1 s
        start = len(m.states)
        assert h.spin_until(lambda: len(m.states) >= start + 200, 20.0)
        sim.data.xfrc_applied[hand, :3] = 0.0
        assert abs(sim.q - q0).max() < 0.01, sim.q - q0       # held (in teaching mode: > 0.02 rad)
        answer = h.call(teaching, SetBool.Request(data=True))
        assert not answer.success and "deactivated" in answer.message, answer.message
        assert not sim.teaching
    finally:
        h.shutdown()

"""The arming rule end to end (issue 20): after every kind of stop the operator did not choose, a
stick held through it — with its messages coming in bursts and gaps of 0.15-0.5 s — never moves the
arm until the operator returns to neutral; then the same stick moves it.

The graph is the one users run, in process: controller_node (the shipped model) and panda_bridge,
on MuJoCo and on franka-sim (libfranka protocol, pylibfranka, a private network namespace), with
joystick and detection messages from the test. The rule itself lives in vla_common.arming.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from require import missing
from sensor_msgs.msg import JointState, Joy
from std_srvs.srv import SetBool, Trigger
from vla_common.ros.testing import RosHarness

from vla_interfaces.msg import ControllerStatus, Detection, DetectionArray, SafetyStatus

pytestmark = [pytest.mark.slow, pytest.mark.ros]
GAPS = (0.15, 0.3, 0.5)      # s without a joystick message while the stick is held
STILL = 0.02                 # rad/s: the largest joint speed that counts as "did not move"
MOVING = 0.1                 # rad/s: the arm moves again once the operator asks properly
RT_PRIORITY = 50


class Graph:
    """controller_node + panda_bridge + the test's joystick, detections and observers."""

    def __init__(self, bridge_params: dict, arm: int = 7):
        from vla_latent_controller.controller_node import ControllerNode
        from vla_panda_bridge.bridge_node import PandaBridge

        self.h = h = RosHarness()
        self.arm = arm
        self.sign = -1.0           # drives alternate toward and away from the task: the arm stays near
        self.bridge = h.add(PandaBridge(context=h.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in bridge_params.items()]))
        self.controller = h.add(ControllerNode(context=h.context, parameter_overrides=[
            Parameter("joy_timeout", value=0.1)]))
        io = self.io = h.add(rclpy.create_node("arming_test_io", context=h.context))
        self.states: list[JointState] = []
        self.ctrl: list[ControllerStatus] = []
        self.safety: list[SafetyStatus] = []
        io.create_subscription(JointState, "joint_states", self.states.append, 2000)
        io.create_subscription(ControllerStatus, "controller_node/status", self.ctrl.append, 200)
        io.create_subscription(SafetyStatus, "panda_bridge/status", self.safety.append, 200)
        self.joy = io.create_publisher(Joy, "joy", 10)
        self.det = io.create_publisher(DetectionArray, "detections", 10)
        assert h.spin_until(lambda: bool(self.states) and self.joy.get_subscription_count() > 0, 30.0)

    # ------------------------------------------------------------------------------ the operator
    def _inputs(self, axis: float | None) -> None:
        msg = DetectionArray(image_width=640, image_height=480)
        msg.detections = [Detection(class_id="bread", score=0.9, center_x=320.0, center_y=300.0)]
        self.det.publish(msg)
        if axis is not None:
            self.joy.publish(Joy(axes=[float(axis), 0.0], buttons=[0, 0, 0, 0]))

    def speed(self) -> float:
        return float(np.abs(np.array(self.states[-1].velocity[:self.arm])).max())

    def stick(self, axis: float | None, seconds: float) -> float:
        """Hold the stick at `axis` (None: no joystick messages) for `seconds`, messages at 50 Hz;
        the largest joint speed seen meanwhile."""
        fastest, end = 0.0, time.monotonic() + seconds
        while time.monotonic() < end:
            self._inputs(axis)
            self.h.spin_for(0.02)
            fastest = max(fastest, self.speed())
        return fastest

    def held_with_gaps(self, rounds: int = 2) -> float:
        """The stick held through the stop, the way it was pushed: bursts of messages with gaps of
        0.15-0.5 s between them; the largest joint speed seen."""
        axis, fastest = 0.8 * self.sign, 0.0
        for _ in range(rounds):
            for gap in GAPS:
                fastest = max(fastest, self.stick(axis, 0.25), self.stick(None, gap))
        return fastest

    def at_rest(self, timeout: float = 15.0) -> None:
        assert self.h.spin_until(lambda: self.speed() < 1e-3, timeout), self.speed()

    def drive(self) -> float:
        """The operator returns to neutral, then pushes: the largest joint speed while pushing."""
        self.sign = -self.sign
        self.stick(0.0, 0.5)
        return self.stick(0.8 * self.sign, 1.5)

    def call(self, srv, name: str, request):
        return self.h.call(self.io.create_client(srv, name), request, 10.0)

    def close(self) -> None:
        self.h.shutdown()


# ----------------------------------------------------------------------------------- the stops
def estop(g: Graph) -> None:
    assert g.call(SetBool, "panda_bridge/estop", SetBool.Request(data=True)).success
    g.stick(0.8 * g.sign, 0.5)
    g.at_rest()
    assert g.call(SetBool, "panda_bridge/estop", SetBool.Request(data=False)).success


def recover(g: Graph) -> None:
    assert g.call(Trigger, "panda_bridge/recover", Trigger.Request()).success   # while moving


def reflex(g: Graph) -> None:
    g.bridge.on_fault("injected: joint_reflex")          # what a backend reports when the robot stops
    g.stick(0.8 * g.sign, 0.5)
    g.at_rest()
    assert g.call(Trigger, "panda_bridge/recover", Trigger.Request()).success


def teaching(g: Graph) -> None:
    g.stick(0.0, 0.5)                                     # teaching starts only at rest
    g.at_rest()
    assert g.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=True)).success
    g.stick(0.8 * g.sign, 0.5)
    assert g.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=False)).success


def joy_timeout(g: Graph) -> None:
    g.stick(None, 0.3)                                    # two lost repeats and a little more


def joystick_link_cut(g: Graph) -> None:
    g.stick(None, 1.5)                                    # the joystick's host is gone for a while


def command_watchdog(g: Graph) -> None:
    """The controller's commands stop reaching the bridge (its process stalls, or the link between
    them is cut): the bridge's watchdog brakes."""
    ex = g.h.executor
    ex.remove_node(g.controller)
    try:
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            g._inputs(0.8 * g.sign)
            g.h.spin_for(0.02)
    finally:
        ex.add_node(g.controller)


MUJOCO_STOPS = {f.__name__: f for f in (estop, recover, reflex, teaching, joy_timeout, joystick_link_cut,
                                         command_watchdog)}


def check(g: Graph, stop) -> None:
    assert g.drive() > MOVING, "the graph does not move the arm at all"
    stop(g)
    g.at_rest()
    fastest = g.held_with_gaps()
    assert fastest < STILL, f"{stop.__name__}: the held stick moved the arm at {fastest:.3f} rad/s"
    waiting = {c.code for c in g.ctrl[-20:]} | {s.code for s in g.safety[-5:]}
    assert waiting & {ControllerStatus.AWAITING_NEUTRAL, SafetyStatus.AWAITING_ZERO}, waiting
    assert g.drive() > MOVING, f"{stop.__name__}: neutral, then the stick, did not move the arm"


@pytest.fixture(scope="module")
def mujoco():
    g = Graph({"camera_rate": 0.0, "real_time_factor": 1.0, "scene_rate": 0.0})
    yield g
    g.close()


@pytest.mark.parametrize("stop", sorted(MUJOCO_STOPS))
def test_mujoco_a_held_stick_waits_for_neutral_after(mujoco, stop):
    check(mujoco, MUJOCO_STOPS[stop])


# -------------------------------------------------------------------------------------- franka-sim
@pytest.fixture(scope="module")
def franka_sim():
    from franka_sim_server import FrankaSimServer, Netns, unavailable

    reason = unavailable()
    if reason is None:
        try:
            import pylibfranka  # noqa: F401
        except ImportError:
            reason = "pylibfranka==0.21.3 is not installed in this venv"
    if reason:
        missing("FRANKA_SIM", reason)
    ns = Netns()
    server = FrankaSimServer(ns, enforce_motion_limits=True, enforce_comm_constraints=False,
                             priority=RT_PRIORITY)
    g = None
    try:
        server.start()
        g = Graph({"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
                   "realtime_config": "ignore", "loop_prefix": " ".join(ns.prefix()), "robot_model": "fr3",
                   "loop_priority": RT_PRIORITY, "control_rate": 250,
                   "acceleration_scale": 0.4999, "jerk_scale": 0.4999})
        g.controller.set_parameters([Parameter("joint_map", value=[f"fr3_joint{i}:panda_joint{i}"
                                                                  for i in range(1, 8)])])
        g.server = server
        yield g
    finally:
        if g is not None:
            g.close()
        server.stop()
        ns.close()


def silence(seconds: float):
    def robot_silence(g: Graph) -> None:
        """The robot stops answering mid-motion (SIGSTOP of the simulator), then answers again."""
        pid = g.server.proc.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                g._inputs(0.8 * g.sign)
                g.h.spin_for(0.01)
        finally:
            os.kill(pid, signal.SIGCONT)
    robot_silence.__name__ = f"robot_silence_{seconds}"
    return robot_silence


FRANKA_STOPS = {f.__name__: f for f in (silence(0.15), silence(0.5), estop, joy_timeout)}


@pytest.mark.parametrize("stop", sorted(FRANKA_STOPS))
def test_franka_sim_a_held_stick_waits_for_neutral_after(franka_sim, stop):
    check(franka_sim, FRANKA_STOPS[stop])

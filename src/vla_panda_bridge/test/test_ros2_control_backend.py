"""The bridge with backend:=ros2_control against a fake ros2_control system (in-process, private Context).

The fake stands in for a JointGroupVelocityController (holds the last command forever, no timeout)
and a joint_state_broadcaster (publishes /joint_states with the fingers and in its own joint order).
"""
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool
from vla_common.robot import DDQ_MAX, DQ_MAX, READY_POSE
from vla_common.ros.context import end_context
from vla_panda_bridge.bridge_node import PandaBridge

from vla_interfaces.msg import SafetyStatus
from vla_interfaces.srv import ResetScene

pytestmark = pytest.mark.ros

RATE = 250                      # bridge control rate here (Hz)
ORDER = ["panda_finger_joint1", "panda_joint3", "panda_joint1", "panda_joint2", "panda_joint7",
         "panda_joint4", "panda_joint5", "panda_joint6", "panda_finger_joint2"]


class FakeArm(Node):
    def __init__(self, context, prefix: str = "panda"):
        super().__init__("fake_ros2_control", context=context)
        self.order = [n.replace("panda_", prefix + "_") for n in ORDER]
        self.joints = {f"{prefix}_joint{i + 1}": i for i in range(7)}
        self.q = READY_POSE.copy()
        self.v = np.zeros(7)
        self.commands: list[np.ndarray] = []
        self.publishing = True
        self.create_subscription(Float64MultiArray, "/joint_velocity_controller/commands", self._on_cmd, 100)
        self.pub = self.create_publisher(JointState, "/joint_states", 10)
        self._last = time.monotonic()
        self.create_timer(0.01, self._tick)

    def _on_cmd(self, msg):
        self._integrate()
        self.v = np.array(msg.data)
        self.commands.append(self.v.copy())

    def _integrate(self):
        now = time.monotonic()
        self.q += self.v * (now - self._last)
        self._last = now

    def _tick(self):
        self._integrate()
        if not self.publishing:
            return
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        by_name = self.joints
        msg.name = self.order
        msg.position = [float(self.q[by_name[n]]) if n in by_name else 0.04 for n in self.order]
        msg.velocity = [float(self.v[by_name[n]]) if n in by_name else 0.0 for n in self.order]
        msg.effort = [0.0] * len(self.order)
        self.pub.publish(msg)


@pytest.fixture(params=["panda"])
def rig(request):
    model = request.param
    ctx = Context()
    rclpy.init(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    arm = FakeArm(ctx, prefix=model)
    bridge = PandaBridge(context=ctx, namespace="arm", parameter_overrides=[
        Parameter("backend", value="ros2_control"), Parameter("control_rate", value=RATE),
        # Timeouts with room for this process' own timers on a loaded machine: a late state or command
        # is a stop that waits for a zero command (the arming rule), which would stall a test.
        Parameter("state_rate", value=50.0), Parameter("command_timeout", value=0.5),
        Parameter("state_timeout", value=0.5), Parameter("robot_model", value=model)])
    probe = rclpy.create_node("probe", context=ctx)
    for n in (arm, bridge, probe):
        ex.add_node(n)
    r = type("Rig", (), {})()
    r.ctx, r.ex, r.arm, r.bridge, r.probe = ctx, ex, arm, bridge, probe
    r.states, r.status = [], []
    probe.create_subscription(JointState, "/arm/joint_states", r.states.append, 50)
    probe.create_subscription(SafetyStatus, "/arm/panda_bridge/status", r.status.append, 50)
    r.cmd_pub = probe.create_publisher(Float64MultiArray, "/arm/joint_velocity_cmd", 10)
    r.cmd = None
    probe.create_timer(0.02, lambda: r.cmd is not None and r.cmd_pub.publish(
        Float64MultiArray(data=[float(x) for x in r.cmd])))

    def wait(pred, timeout=10.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return True
            ex.spin_once(timeout_sec=0.01)
        return bool(pred())

    def reach(cmd, timeout=20.0):
        """Command `cmd` until the arm gets it. A stop on the way (a state or command late past its
        timeout on a loaded machine: the watchdog) waits for a zero command (the arming rule): given
        first, as an operator would, then `cmd` again."""
        end = time.monotonic() + timeout
        r.cmd = cmd
        while time.monotonic() < end:
            if np.array_equal(arm.commands[-1], cmd):
                return True
            if r.status and r.status[-1].code == SafetyStatus.AWAITING_ZERO:
                r.cmd = np.zeros(7)
                left = max(0.0, end - time.monotonic())
                wait(lambda: r.status[-1].code != SafetyStatus.AWAITING_ZERO, left)
                r.cmd = cmd
            ex.spin_once(timeout_sec=0.01)
        return bool(np.array_equal(arm.commands[-1], cmd))

    r.wait, r.reach = wait, reach
    assert wait(lambda: r.cmd_pub.get_subscription_count() > 0 and r.states and arm.commands)
    yield r
    if bridge.context.ok():
        bridge.destroy_node()
    arm.destroy_node()
    probe.destroy_node()
    ex.shutdown()
    end_context(ctx)


def _accel(commands: list[np.ndarray]) -> np.ndarray:
    return np.abs(np.diff(np.array(commands), axis=0)) * RATE


def test_forwards_filtered_commands_and_relays_joint_states(rig):
    assert np.all(rig.arm.commands[-1] == 0.0)           # at rest it holds the controller at zero
    n0 = len(rig.arm.commands)
    cmd = np.array([0.3, -0.2, 0.1, 0.2, -0.3, 0.25, 0.4])
    assert rig.reach(cmd)
    ramp = rig.arm.commands[n0 - 1:]
    assert np.all(_accel(ramp) <= DDQ_MAX * (1 + 1e-6))   # a ramp within the acceleration limits
    assert len(ramp) > 5
    # Relayed in panda_joint1..7 order from the arm's own (shuffled, with fingers) message.
    n = len(rig.states)
    assert rig.wait(lambda: len(rig.states) > n + 2)
    js = rig.states[-1]
    assert list(js.name) == [f"panda_joint{i}" for i in range(1, 8)]
    np.testing.assert_allclose(js.velocity, cmd, atol=1e-12)
    assert abs(js.position[0] - rig.arm.q[0]) < 0.3 * 0.05  # the arm's q, one publish period old at most


def test_over_limit_nan_and_silence_are_filtered_before_the_controller(rig):
    rig.cmd = np.array([3.0, 0, 0, 0, 0, 0, 0])               # 1.4x the limit: scaled
    assert rig.wait(lambda: rig.arm.commands[-1][0] == pytest.approx(DQ_MAX[0]))
    assert max(c[0] for c in rig.arm.commands) <= DQ_MAX[0]
    rig.cmd = np.array([1e9, 0, 0, 0, 0, 0, 0])               # not physical: rejected, braked to zero
    assert rig.wait(lambda: np.all(rig.arm.commands[-1] == 0.0))
    assert any(s.code == SafetyStatus.IMPLAUSIBLE_COMMAND for s in rig.status)
    rig.cmd = np.array([np.nan] * 7)
    assert rig.wait(lambda: np.all(rig.arm.commands[-1] == 0.0))
    assert all(np.all(np.isfinite(c)) for c in rig.arm.commands)
    assert rig.wait(lambda: any(s.code == SafetyStatus.NON_FINITE_COMMAND for s in rig.status))
    assert rig.reach(np.full(7, 0.2))
    rig.cmd = None                                        # silence: the watchdog brakes to zero
    assert rig.wait(lambda: np.all(rig.arm.commands[-1] == 0.0))
    assert any(s.code == SafetyStatus.COMMAND_TIMEOUT for s in rig.status)
    assert np.all(_accel(rig.arm.commands) <= DDQ_MAX * (1 + 1e-6))


def test_stale_joint_states_brake_and_estop_latches(rig):
    assert rig.reach(np.full(7, 0.2))
    rig.arm.publishing = False
    assert rig.wait(lambda: np.all(rig.arm.commands[-1] == 0.0))
    assert any(s.code == SafetyStatus.INVALID_STATE for s in rig.status)
    rig.arm.publishing = True                             # the state is back; the held command is not
    n = len(rig.arm.commands)                             # enough: a lost state is a stop (arming rule)
    assert rig.wait(lambda: len(rig.arm.commands) > n + 50)
    assert all(np.all(c == 0.0) for c in rig.arm.commands[n:])
    assert rig.wait(lambda: rig.status[-1].code == SafetyStatus.AWAITING_ZERO)
    cmd, rig.cmd = rig.cmd, np.zeros(7)                   # the operator's neutral, then the stick again
    assert rig.wait(lambda: rig.status[-1].code != SafetyStatus.AWAITING_ZERO)
    assert rig.reach(cmd)
    client = rig.probe.create_client(SetBool, "/arm/panda_bridge/estop")
    assert client.wait_for_service(timeout_sec=5.0)
    fut = client.call_async(SetBool.Request(data=True))
    assert rig.wait(fut.done) and fut.result().success
    assert rig.wait(lambda: np.all(rig.arm.commands[-1] == 0.0))
    n = len(rig.arm.commands)
    assert rig.wait(lambda: len(rig.arm.commands) > n + 20)
    assert all(np.all(c == 0.0) for c in rig.arm.commands[n:])   # latched despite the command stream
    reset = rig.probe.create_client(ResetScene, "/arm/panda_bridge/reset")
    assert reset.wait_for_service(timeout_sec=5.0)
    fut = reset.call_async(ResetScene.Request())
    assert rig.wait(fut.done) and not fut.result().success and "mujoco" in fut.result().message
    teaching = rig.probe.create_client(SetBool, "/arm/panda_bridge/set_teaching")
    assert teaching.wait_for_service(timeout_sec=5.0)
    fut = teaching.call_async(SetBool.Request(data=True))
    assert rig.wait(fut.done) and not fut.result().success and "ros2_control" in fut.result().message


def test_shutdown_brakes_and_leaves_the_controller_at_zero(rig):
    cmd = np.full(7, 0.5)
    assert rig.reach(cmd)
    n = len(rig.arm.commands)
    rig.bridge.destroy_node()                             # brakes through the filter, then zero
    assert rig.wait(lambda: len(rig.arm.commands) > n and np.all(rig.arm.commands[-1] == 0.0), 5.0)
    tail = rig.arm.commands[n - 1:]
    assert len(tail) > 3                                  # a braking ramp, not a jump to zero
    assert np.all(_accel(tail) <= DDQ_MAX * 1.5)          # (wall-clock pacing of the final loop)


@pytest.mark.parametrize("rig", ["fr3"], indirect=True)
def test_an_fr3_gets_its_joint_names_and_its_own_limit_table(rig):
    """robot_model fr3: joints picked and relayed as fr3_joint1..7; joint 5 may run at the FR3's
    5.26 rad/s (the Panda's limit is 2.61); its position limits are the FR3's."""
    from vla_common.robot import FR3

    assert rig.bridge.filter.robot is FR3
    np.testing.assert_array_equal(rig.bridge.filter.v_max, FR3.dq_max)
    rig.arm.q[4] = -2.6                                   # room to reach 4 rad/s however late the timers
    n = len(rig.states)
    assert rig.wait(lambda: len(rig.states) > n + 2)
    cmd = np.array([0.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0])
    assert rig.reach(cmd), [s.text for s in rig.status[-3:]]
    n = len(rig.states)
    assert rig.wait(lambda: len(rig.states) > n + 2)
    assert list(rig.states[-1].name) == [f"fr3_joint{i}" for i in range(1, 8)]
    assert rig.bridge._pose.header.frame_id == "fr3_link0"

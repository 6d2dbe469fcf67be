"""panda_bridge with backend:=libfranka driver:=pylibfranka against franka-sim (the libfranka-protocol
FR3 simulator), each server in a private network namespace. Skipped, with the reason, where the
franka-sim venv (scripts/setup_franka_sim.sh), pylibfranka or network namespaces are missing.

One server (motion limits and communication constraints enforced, as on the FCI) and one bridge for
the module, in this order: connect and stream, move as integrated, watchdog, malformed commands,
teaching, a stalled loop (reflex, recover), the server killed mid-motion (and back), shutdown; then
the installed node stopped by SIGINT."""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from franka_sim_server import FrankaSimServer, running
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from vla_common.kinematics import PandaKinematics
from vla_common.ros.testing import RosHarness
from vla_common.safety_status import SafetyCode
from vla_launch.run import find_executable
from vla_panda_bridge.libfranka_loop import LoopStatus

from vla_interfaces.msg import SafetyStatus

pytestmark = [pytest.mark.slow, pytest.mark.ros]

SIM_Q0 = np.array([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785])   # every fresh franka-sim process
# Until vla_common.robot's FR3 carries the FCI's own table (10 rad/s^2, 5000 rad/s^3 on every joint;
# it has the Panda's), these scales keep the filter inside it.
FR3_SCALES = {"acceleration_scale": 0.4999, "jerk_scale": 0.4999}
# franka-sim and the loop process under SCHED_FIFO, as on a real-time PC: on these shared 2 cores a
# loop process left to the normal scheduler stalled up to 0.6 s at a load average of 7, which the
# enforced communication constraints (20 lost cycles) answer with a reflex.
RT_PRIORITY = 50
# The module's bridge runs its filter and joint_states at 250 Hz (the loop still at 1 kHz): on a loaded
# machine a 1 kHz node and a 1 kHz subscriber in this one process starve each other (2 states in 0.5 s
# seen at a load average of 10); only the streaming test runs a bridge at 1000 Hz.
LIGHT = {"control_rate": 250, "state_rate": 250.0}
FR3_JOINTS = [f"fr3_joint{i}" for i in range(1, 8)]


@pytest.fixture(scope="module")
def sim():
    with running(priority=RT_PRIORITY) as server:
        yield server


class Bridge(RosHarness):
    """The bridge under test and an io node: joint_states, ~/status, commands."""

    def __init__(self, server: FrankaSimServer, **params):
        super().__init__()
        from vla_panda_bridge.bridge_node import PandaBridge

        values = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
                  "realtime_config": "ignore", "loop_prefix": " ".join(server.netns.prefix()),
                  "robot_model": "fr3", "loop_priority": RT_PRIORITY, "gripper": False,   # --no-gripper
                  **LIGHT, **FR3_SCALES, **params}
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.node = self.add(PandaBridge(context=self.context, parameter_overrides=overrides))
        self.backend = self.node.backend
        self.io = self.add(rclpy.create_node("franka_sim_test_io", context=self.context))
        self.states: list[JointState] = []
        self.status: list[SafetyStatus] = []
        self.io.create_subscription(JointState, "joint_states", self.states.append, 2000)
        self.io.create_subscription(SafetyStatus, "panda_bridge/status", self.status.append, 100)
        self.pub = self.io.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        assert self.spin_until(lambda: self.pub.get_subscription_count() > 0, 10.0)
        self.arrivals: list[float] = []                  # wall time of each command at the bridge
        for sub in self.node.subscriptions:
            if sub.topic_name.endswith("joint_velocity_cmd"):
                sub.callback = self._arrived(sub.callback)

    def _arrived(self, callback):
        def traced(msg):
            self.arrivals.append(time.time())
            callback(msg)
        return traced

    def connected(self, timeout: float = 15.0) -> bool:
        return self.spin_until(lambda: self.backend.status.code == LoopStatus.OK and bool(self.states),
                               timeout)

    def armed(self) -> bool:
        """Both filters (the node's and the loop's) let commands through."""
        return self.node.filter.arming.armed and self.backend.status.filter_code != SafetyCode.AWAITING_ZERO

    def _send(self, values) -> None:
        """Publish `values` as the controller would for an operator: zero while a filter waits for one
        (on a loaded machine this test's own stream can arrive late, which the watchdog stops)."""
        values = values if self.armed() else [0.0] * 7
        self.pub.publish(Float64MultiArray(data=[float(v) for v in values]))

    def command(self, values, seconds: float, rate: float = 100.0) -> None:
        """Publish `values` at `rate` for `seconds` while spinning (as the controller would)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._send(values)
            self.spin_for(1.0 / rate)

    def command_until(self, values, cond, timeout: float = 5.0) -> bool:
        """Publish `values` at 100 Hz until `cond()` (on a loaded machine the graph lags: wait for the
        effect instead of a fixed time)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            self._send(values)
            self.spin_for(0.01)
        return cond()

    def moved_by(self, joint: int, rad: float):
        q = self.robot().position[joint]
        return lambda: abs(self.robot().position[joint] - q) > rad

    def robot(self):
        """The robot's latest state as the loop has it (robot time, q, dq)."""
        return self.backend.process.read()

    def at_rest(self, tol: float = 0.01) -> bool:
        return bool(self.states) and max(abs(v) for v in self.states[-1].velocity) < tol

    def interventions(self) -> int:
        """Both filters' interventions (a watchdog stop counts in one of them)."""
        return self.node.filter.interventions + self.backend.process.status().interventions

    def recover(self) -> Trigger.Response:
        return self.call(self.io.create_client(Trigger, "panda_bridge/recover"), Trigger.Request())

    def set_teaching(self, on: bool) -> SetBool.Response:
        client = self.io.create_client(SetBool, "panda_bridge/set_teaching")
        return self.call(client, SetBool.Request(data=on))

    def recover_if_needed(self) -> None:
        """Each test starts from a connected, armed arm at rest, whatever an earlier one left."""
        if self.backend.process.status().teaching:        # a teaching test that failed half-way
            assert self.set_teaching(False).success
        held = bool(self.status) and self.status[-1].code == SafetyStatus.REFLEX
        if self.backend.status.code != LoopStatus.OK or held:
            assert self.recover().success
        assert self.connected()
        assert self.spin_until(self.at_rest, 5.0)
        self.rearm()

    def rearm(self) -> None:
        """Zero commands until both filters (the node's and the loop's) are armed: after every stop
        the operator did not choose (here: the connection) motion needs a zero first."""
        assert self.command_until([0.0] * 7, self.armed, 10.0), (self.node.filter.arming.reason,
                                                                  self.backend.status)


@pytest.fixture(scope="module")
def bridge(sim):
    b = Bridge(sim)
    try:
        assert b.connected(), b.backend.status
        yield b
    finally:
        b.shutdown()


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def velocity(j: int, v: float) -> list[float]:
    out = [0.0] * 7
    out[j] = v
    return out


def test_it_connects_and_streams_the_servers_state(sim):
    bridge = Bridge(sim, control_rate=1000, state_rate=1000.0)    # first: franka-sim takes one client
    try:
        assert bridge.connected(), bridge.backend.status
        n = len(bridge.states)
        bridge.spin_for(1.0)
        window = bridge.states[n:]
        robot = bridge.robot()
        tau_ext = bridge.backend.external_torque()        # with the states, for the contact slowing
    finally:
        bridge.shutdown()
    stamps = np.array([_stamp(m) for m in window])
    assert np.all(np.diff(stamps) > 0)                    # every one a new robot state
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])   # in the robot's clock (its stamps)
    # It streams: 939 Hz measured at load 1.7; 100 Hz is a 9x margin for a loaded machine. The rate
    # itself is bench/bench_libfranka.py's to measure, not a test's.
    assert rate >= 100.0, f"joint_states at {rate:.0f} Hz"
    last = window[-1]
    assert list(last.name) == FR3_JOINTS and last.header.frame_id == ""
    np.testing.assert_allclose(last.position, SIM_Q0, atol=2e-3)    # the fresh server's pose
    np.testing.assert_allclose(last.velocity, 0.0, atol=1e-2)
    np.testing.assert_allclose(last.position, robot.position, atol=1e-3)
    # pylibfranka's RobotState.tau_ext_hat_filtered reached the node through the loop's state slot.
    # franka-sim 1.1.7 always sends zeros there (robot_state.py), so only its arrival is checked here;
    # that a measured torque slows motion into it is test_libfranka_backend's.
    assert tau_ext is not None and tau_ext.shape == (7,) and np.all(np.isfinite(tau_ext)), tau_ext


def test_a_constant_velocity_moves_the_joint_as_integrated(bridge):
    cuts = []
    for attempt in range(8):
        v = 0.2 if attempt % 2 == 0 else -0.2             # back and forth: every try stays in the limits
        bridge.recover_if_needed()
        assert bridge.command_until(velocity(3, v), lambda: abs(bridge.robot().velocity[3]) > 0.196, 10.0)
        bridge.command(velocity(3, v), 0.2)               # settled
        before = bridge.interventions()
        a = bridge.robot()
        bridge.command(velocity(3, v), 0.8)
        b = bridge.robot()
        if bridge.interventions() == before:
            break
        # A filter intervened: this test's own command stream (or the node in this process) stalled
        # past the watchdog's 0.1 s at load 30, and the arm was stopped, as it must be. Such a window
        # measures the stop, not the integration (test_the_watchdog_... is about the stop): again.
        cuts.append((bridge.node.filter.arming.reason, bridge.backend.process.status().filter_text))
        bridge.command([0.0] * 7, 0.3)
    else:
        pytest.fail(f"8 windows of 0.8 s in a row had a stop: {cuts}")
    bridge.command([0.0] * 7, 0.3)
    # joint_states between a and b by their stamps (the robot's): a starved node publishes late batches,
    # so the states that arrive in a wall-clock window are not the window's (at load 30 they began with
    # states from before the motion)
    t_a, t_b = a.stamp_ns * 1e-9, b.stamp_ns * 1e-9
    assert bridge.spin_until(lambda: _stamp(bridge.states[-1]) >= t_b, 30.0)
    steady = [m for m in bridge.states if t_a <= _stamp(m) <= t_b]
    # The joint runs at the commanded velocity (franka-sim's servo tracks it within about 0.5 %) ...
    speeds = np.array([m.velocity[3] for m in steady])
    assert np.median(speeds) == pytest.approx(v, rel=0.02), (
        np.percentile(speeds, [0, 10, 50, 90, 100]).round(3).tolist(), len(speeds), cuts,
        bridge.backend.process.status())
    # ... and its position is that velocity integrated over the time it ran: never more than v times
    # the wall time (+3 %, 1 mrad). franka-sim paces its physics to the wall clock but drops time when
    # it falls behind (0.64x real time seen with a load average of 4.8 on these 2 cores), so the lower
    # bound is half of it: a motion that did not happen, or at half speed, still fails.
    moved = (b.position[3] - a.position[3]) * np.sign(v)
    wall = abs(v) * (b.stamp_ns - a.stamp_ns) * 1e-9
    assert 0.5 * wall <= moved <= 1.03 * wall + 1e-3, (moved, wall)
    others = np.delete(b.position - a.position, 3)
    assert np.all(np.abs(others) < 2e-3)


def test_the_watchdog_brings_the_arm_to_rest_within_0_3_s(bridge):
    bridge.recover_if_needed()
    assert bridge.command_until(velocity(0, 0.2), lambda: bridge.robot().velocity[0] > 0.15, 10.0)
    bridge.spin_for(0.1)
    stopped_at = bridge.arrivals[-1]                      # the last command at the bridge (wall time,
    #                                                       as the joint_states stamps)
    # the states of the second after it (waited for by their stamps: a starved node publishes late)
    assert bridge.spin_until(lambda: _stamp(bridge.states[-1]) > stopped_at + 1.0, 30.0)
    after = [m for m in bridge.states if _stamp(m) > stopped_at]
    moving = [m for m in after if max(abs(x) for x in m.velocity) > 0.01]
    last_moving = _stamp(moving[-1]) if moving else stopped_at
    trace = [(round(_stamp(m) - stopped_at, 3), round(max(m.velocity, key=abs), 3)) for m in after[:150:5]]
    assert last_moving - stopped_at <= 0.3, (f"still moving {last_moving - stopped_at:.3f} s after", trace,
                                             bridge.arrivals[-5:], bridge.backend.process.status())
    assert any(s.code == SafetyStatus.COMMAND_TIMEOUT for s in bridge.status)


def test_malformed_commands_are_rejected_as_on_mujoco(bridge):
    bridge.recover_if_needed()
    q0 = np.array(bridge.states[-1].position)
    rejected = bridge.status[-1].commands_rejected if bridge.status else 0
    bridge.status.clear()
    # each bad command is sent until a status names its refusal (the status is periodic: a starved
    # node may publish none within a fixed window), with a wall bound only against a hang
    for bad, code in (([math.nan] * 7, SafetyStatus.NON_FINITE_COMMAND),
                      ([0.1] * 3, SafetyStatus.WRONG_LENGTH),
                      ([math.inf, 0, 0, 0, 0, 0, 0], SafetyStatus.NON_FINITE_COMMAND)):
        bridge.status.clear()
        assert bridge.command_until(bad, lambda c=code: any(s.code == c for s in bridge.status), 30.0), code
    assert bridge.spin_until(lambda: bridge.status and bridge.status[-1].commands_rejected >= rejected + 3)
    assert bridge.status[-1].commands_rejected >= rejected + 3
    np.testing.assert_allclose(bridge.states[-1].position, q0, atol=1e-3)    # nothing moved
    assert bridge.backend.status.code == LoopStatus.OK


def test_teaching_on_and_off_moves_the_hand_by_at_most_1_mm(bridge):
    bridge.recover_if_needed()
    fk = PandaKinematics().fk
    n, m = len(bridge.states), len(bridge.status)
    res = bridge.set_teaching(True)
    assert res.success and "teaching" in res.message, res.message
    assert bridge.backend.process.status().teaching
    # The status comes on its own topic: the service's answer can overtake it (load 15)
    assert bridge.spin_until(lambda: any(s.code == SafetyStatus.TEACHING for s in bridge.status[m:]), 10.0)
    k = len(bridge.states)                                # joint_states keep flowing while teaching
    assert bridge.spin_until(lambda: len(bridge.states) - k > 50, 10.0)   # (0.5 s at rest; load slows it)
    bridge.command(velocity(0, 0.3), 0.2)                 # ignored: the hand moves the arm, not commands
    res = bridge.set_teaching(False)
    assert res.success and "zero command" in res.message, res.message
    assert not bridge.backend.process.status().teaching
    bridge.spin_for(0.3)
    tcp = np.array([fk(np.array(m.position))[0] for m in bridge.states[n - 1:]])
    travel = np.linalg.norm(tcp - tcp[0], axis=1).max()
    assert travel <= 1e-3, f"the hand travelled {travel * 1e3:.2f} mm"
    bridge.command([0.0] * 7, 0.05)
    assert bridge.command_until(velocity(6, 0.2), bridge.moved_by(6, 0.02))     # velocity control again


def test_a_stalled_loop_gives_a_reflex_and_recover_resumes(bridge):
    bridge.recover_if_needed()
    assert bridge.command_until(velocity(1, 0.1), lambda: bridge.robot().velocity[1] > 0.08)
    pid = bridge.backend.process.pid
    os.kill(pid, signal.SIGSTOP)                          # > 20 lost cycles: communication_constraints
    time.sleep(0.08)
    os.kill(pid, signal.SIGCONT)
    reflex = bridge.spin_until(lambda: bridge.backend.status.code == LoopStatus.REFLEX, 5.0)
    assert reflex, bridge.backend.status
    st = bridge.backend.status
    assert "communication_constraints_violation" in st.text
    assert bridge.spin_until(lambda: bridge.status[-1].code == SafetyStatus.REFLEX, 2.0)
    assert "communication_constraints_violation" in bridge.status[-1].text
    n = len(bridge.states)
    q = bridge.robot().position
    bridge.command(velocity(1, 0.1), 0.3)                 # no motion until recovered ...
    # ... but the state keeps flowing (waited for: at load 30 this process took fewer in 0.3 s)
    assert bridge.command_until(velocity(1, 0.1), lambda: len(bridge.states) > n + 25, 10.0)
    np.testing.assert_allclose(bridge.robot().position, q, atol=2e-3)
    res = bridge.recover()
    assert res.success and "recovery done" in res.message, res.message
    assert bridge.backend.process.status().code == LoopStatus.OK
    bridge.command([0.0] * 7, 0.05)                       # the filter re-arms on a zero command
    assert bridge.command_until(velocity(1, 0.1), bridge.moved_by(1, 0.02))


def test_a_killed_server_is_reported_and_the_bridge_reconnects_when_it_returns(bridge, sim):
    bridge.recover_if_needed()
    assert bridge.command_until(velocity(2, 0.2), lambda: bridge.robot().velocity[2] > 0.15)
    sim.kill()
    killed_at = time.time()
    connects = bridge.backend.status.connects
    assert bridge.spin_until(lambda: bridge.backend.status.code == LoopStatus.DISCONNECTED, 5.0)
    st = bridge.backend.status
    assert "UDP receive: Timeout" in st.text or "closed connection" in st.text, st.text
    bridge.spin_for(0.5)                                  # silent: nothing new, the node alive
    assert all(_stamp(m) <= killed_at + 0.01 for m in bridge.states[-50:])
    status = bridge.status[-1]
    assert status.code == SafetyStatus.REFLEX and "UDP receive: Timeout" in status.text, status
    assert not bridge.recover().success                   # nothing to reconnect to yet
    sim.start()
    # the loop retries with back-off (up to reconnect_max) while franka-sim restarts: slow under load
    assert bridge.spin_until(lambda: bridge.backend.status.code == LoopStatus.OK, 30.0), bridge.backend.status
    assert bridge.backend.status.connects == connects + 1
    assert bridge.spin_until(lambda: _stamp(bridge.states[-1]) > killed_at + 0.5, 30.0)
    np.testing.assert_allclose(bridge.states[-1].position, SIM_Q0, atol=2e-3)   # a fresh server
    q = bridge.robot().position
    bridge.command(velocity(2, 0.2), 0.3)
    np.testing.assert_allclose(bridge.robot().position, q, atol=1e-3)         # held until ~/recover
    bridge.recover_if_needed()
    assert bridge.command_until(velocity(2, 0.2), bridge.moved_by(2, 0.03))


def test_shutdown_ends_the_motion_and_the_loop_process(bridge, sim):
    """Last: the module's bridge shuts down mid-motion (franka-sim takes one client at a time)."""
    bridge.recover_if_needed()
    assert bridge.command_until(velocity(0, 0.3), lambda: bridge.robot().velocity[0] > 0.2)
    proc = bridge.backend.process.child._proc
    t0 = time.monotonic()
    bridge.node.on_shutdown()
    assert time.monotonic() - t0 < 2.0                    # the rule's 2 s: 17x the 0.12 s measured (load 1.7)
    assert proc.poll() == 0                               # the loop ended the motion and exited
    log = sim.log()
    last = log[log.rindex("Motion started"):]
    assert "Motion finished" in last and "aborting" not in last     # motion_finished, no reflex


def test_sigint_stops_the_bridge_process_within_2_s_ending_the_motion(sim, tmp_path):
    """The installed node as `ros2 run` starts it; Ctrl-C (SIGINT to its process group) mid-motion,
    after the module's bridge let go of franka-sim's one client slot."""
    exe = find_executable("vla_panda_bridge", "panda_bridge")
    params = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
              "realtime_config": "ignore", "loop_prefix": " ".join(sim.netns.prefix()),
              "robot_model": "fr3", "loop_priority": RT_PRIORITY, "gripper": False, **FR3_SCALES}
    args = [a for k, v in params.items() for a in ("-p", f"{k}:={v}")]
    log = tmp_path / "bridge.log"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, exe, "--ros-args", *args], stdout=err, stderr=err,
                                start_new_session=True)
    h = RosHarness(other_processes=True)
    try:
        io = h.add(rclpy.create_node("franka_sim_sigint_io", context=h.context))
        states: list[JointState] = []
        io.create_subscription(JointState, "joint_states", states.append, 2000)
        pub = io.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        def ready() -> bool:
            return "libfranka OK" in log.read_text() and bool(states) and pub.get_subscription_count() > 0
        assert h.spin_until(ready, 30.0), log.read_text()
        loop_pid = int(re.search(r"1 kHz loop in process (\d+)", log.read_text()).group(1))
        end = time.monotonic() + 20.0                    # only against a hang: the effect is waited for
        while time.monotonic() < end and abs(states[-1].velocity[5]) < 0.2:
            pub.publish(Float64MultiArray(data=velocity(5, 0.3)))
            h.spin_for(0.01)
        assert abs(states[-1].velocity[5]) >= 0.2
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)               # Ctrl-C: the whole foreground process group
        code = proc.wait(10)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        h.shutdown()
    # The 2 s of the project's rule, 4.3x the 0.47 s measured at load 1.7 (2026-12-03)
    assert code == 0 and took < 2.0, (code, took, log.read_text()[-2000:])
    with pytest.raises(ProcessLookupError):
        os.kill(loop_pid, 0)                              # the loop process is gone too
    last = sim.log()[sim.log().rindex("Motion started"):]
    assert "Motion finished" in last and "aborting" not in last

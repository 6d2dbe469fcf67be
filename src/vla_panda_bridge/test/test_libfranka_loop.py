"""The libfranka loop's state machine against a fake robot (no libfranka, no process): motions start
and end at rest, the command stream the robot gets is continuous, errors stop the arm and never end
the loop, recover/teaching/e-stop/shutdown requests through the slots."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from vla_common.safety_status import SafetyCode
from vla_panda_bridge.libfranka_driver import CONNECTION, REFLEX, RobotError
from vla_panda_bridge.libfranka_loop import ControlLoop, LoopSettings
from vla_panda_bridge.libfranka_slots import CONTROL, Slots

from vla_panda_bridge import libfranka_loop as lf

Q0 = [0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785]
REFLEX_TEXT = ('ControlException: libfranka: Move command aborted: motion aborted by reflex! '
               '["joint_motion_generator_acceleration_discontinuity"]')


# ------------------------------------------------------------------------------------------- fakes
class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


class Duration:
    def __init__(self, s: float):
        self.s = s

    def to_sec(self) -> float:
        return self.s


@dataclass
class State:
    q: list
    dq: list
    tau_J: list  # noqa: N815 (libfranka's field names)
    tau_ext_hat_filtered: list
    O_T_EE: list
    robot_mode: int
    control_command_success_rate: float
    time: Duration


@dataclass
class FakeRobot:
    """The arm and its server, shared by every driver a test's loop opens."""

    clock: Clock
    q: list = field(default_factory=lambda: list(Q0))
    dq: list = field(default_factory=lambda: [0.0] * 7)
    t: float = 0.0
    mode: int = 1
    reachable: bool = True
    fatal: str = ""
    attempts: int = 0
    tau_ext: list = field(default_factory=lambda: [0.0] * 7)   # what pushes on the arm (Nm)

    def state(self) -> State:
        pose = [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.3, 0, 0.5, 1]
        return State(list(self.q), list(self.dq), [0.0] * 7, list(self.tau_ext), pose, self.mode, 1.0,
                     Duration(self.t))

    def tick(self, dq=None) -> None:
        self.t = round(self.t + 0.001, 9)
        self.clock.t += 0.001
        if dq is not None:
            self.dq = list(dq)
        self.q = [q + 0.001 * v for q, v in zip(self.q, self.dq)]


class FakeDriver:
    """The Driver interface over a FakeRobot; records every command. `fail_next` is raised by the
    next read_cycle."""

    name = "fake"

    def __init__(self, robot: FakeRobot):
        self.robot = robot
        self.velocities: list[tuple[list, bool]] = []
        self.torques: list[tuple[list, bool]] = []
        self.events: list[str] = []
        self.fail_next: RobotError | None = None
        self.in_motion: str | None = None
        self.extrapolated: tuple[list, list] | None = None

    def connect(self) -> None:
        r = self.robot
        r.attempts += 1
        if r.fatal:
            raise RobotError("fatal", r.fatal)
        if not r.reachable:
            raise RobotError(CONNECTION, "NetworkException: libfranka: Connection to FCI refused.")

    def read_idle(self):
        if not self.robot.reachable:
            raise RobotError(CONNECTION, "NetworkException: libfranka: UDP receive: Timeout")
        self.robot.tick()
        return self.robot.state()

    def start_velocity(self) -> None:
        assert self.in_motion is None
        self.in_motion = "velocity"
        self.events.append("start_velocity")

    def start_torque(self) -> None:
        assert self.in_motion is None
        self.in_motion = "torque"
        self.events.append("start_torque")

    def read_cycle(self):
        assert self.in_motion is not None, "read_cycle outside a motion"
        if self.fail_next is not None:
            exc, self.fail_next = self.fail_next, None
            self.in_motion = None
            if exc.kind == REFLEX:
                self.robot.mode, self.robot.dq = 4, [0.0] * 7
            raise exc
        if not self.robot.reachable:
            self.in_motion = None
            raise RobotError(CONNECTION, "NetworkException: libfranka: UDP receive: Timeout")
        last = self.velocities[-1][0] if self.in_motion == "velocity" and self.velocities else None
        self.robot.tick(last)
        return self.robot.state(), 0.001

    def gap_reference(self, v, a, cycles: int):
        """The fake robot holds the last velocity (as panda-py does); `extrapolated` overrides it."""
        if self.extrapolated is not None:
            return self.extrapolated
        return list(v), [0.0] * 7

    def write_velocity(self, dq, finished: bool) -> None:
        assert self.in_motion == "velocity"
        self.velocities.append((list(dq), finished))
        if finished:
            self.in_motion = None
            self.events.append("finish_velocity")

    def write_torque(self, tau, finished: bool) -> None:
        assert self.in_motion == "torque"
        self.torques.append((list(tau), finished))
        if finished:
            self.in_motion = None
            self.events.append("finish_torque")

    def recover(self) -> None:
        self.in_motion = None
        self.robot.mode = 1
        self.events.append("recover")

    def close(self) -> None:
        self.events.append("close")


class Rig:
    """A ControlLoop over fresh slots and a FakeRobot, with the ROS side's writes as helpers."""

    def __init__(self, settings: LoopSettings | None = None, parent_pid: int | None = None):
        self.clock = Clock()
        self.robot = FakeRobot(self.clock)
        self.slots = Slots.create()
        self.drivers: list[FakeDriver] = []
        self.loop = ControlLoop(self.slots, settings or LoopSettings(robot={"robot_ip": "192.0.2.1"}),
                                opener=self._open, clock=self.clock, wall=lambda: 1.7e9 + self.clock.t,
                                sleep=self.clock.sleep, parent_pid=parent_pid)

    def _open(self, name, settings):
        d = FakeDriver(self.robot)
        d.connect()
        self.drivers.append(d)
        return d

    @property
    def driver(self) -> FakeDriver:
        return self.drivers[-1]

    def command(self, values) -> None:
        self.slots.write_command(list(values), self.clock.t)

    def run(self, cycles: int, command=None) -> None:
        for _ in range(cycles):
            if command is not None:
                self.command(command)
            assert self.loop.step()

    def run_until(self, cond, limit: int = 5000, command=None) -> None:
        for _ in range(limit):
            if cond():
                return
            if command is not None:
                self.command(command)
            self.loop.step()
        assert cond(), "condition not reached"

    def state(self):
        return self.slots.read_state()

    def request(self, name: str, value: float | None = None) -> None:
        c = self.slots.control
        if name == "teaching":
            c[CONTROL["teaching"]] = float(value)
            c[CONTROL["teaching_req"]] += 1.0
        elif name == "recover":
            c[CONTROL["recover_req"]] += 1.0
        else:
            c[CONTROL[name]] = float(value)

    def close(self) -> None:
        self.slots.close()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


ZERO = [0.0] * 7


def velocity(j: int, v: float) -> list[float]:
    out = [0.0] * 7
    out[j] = v
    return out


def assert_continuous(loop: ControlLoop, commands: list[list[float]]) -> None:
    """Acceleration and jerk of a command stream (with the zero before it) within the filter's limits."""
    v = np.vstack([np.zeros((2, 7)), np.array(commands)])
    a = np.diff(v, axis=0) / lf.PERIOD
    j = np.diff(a, axis=0) / lf.PERIOD
    f = loop.filter
    assert np.all(np.abs(a) <= f.a_max * (1 + 1e-9) + 1e-9), np.abs(a).max(axis=0)
    assert np.all(np.abs(j) <= f.j_max * (1 + 1e-9) + 1e-6), np.abs(j).max(axis=0)


# ------------------------------------------------------------------------------------------- tests
def test_connects_and_publishes_idle_states(rig):
    rig.run(5)
    s = rig.state()
    assert s.status == lf.LoopStatus.OK and s.mode == lf.Mode.IDLE and s.connects == 1
    assert s.cycle == 5 and s.robot_time == pytest.approx(0.005)
    assert np.allclose(s.q, rig.robot.q)
    assert rig.slots.read_text("status") == "connected to 192.0.2.1 (fake)"
    assert rig.driver.velocities == []                     # nothing commanded: no motion


def test_the_robots_external_torque_estimate_reaches_the_state_slot(rig):
    rig.run(3)
    assert np.array_equal(rig.state().tau_ext_hat_filtered, np.zeros(7))
    rig.robot.tau_ext = [0.5, -12.0, 0.0, 3.0, 0.0, -1.0, 0.25]
    rig.run(1, command=ZERO)                                # idle: read_idle's state
    assert np.array_equal(rig.state().tau_ext_hat_filtered, rig.robot.tau_ext)
    rig.run_until(lambda: rig.loop.mode == lf.Mode.VELOCITY, command=velocity(0, 0.1))
    rig.robot.tau_ext = [1.0] * 7
    rig.run(1, command=velocity(0, 0.1))                    # in a motion: read_cycle's state
    assert np.array_equal(rig.state().tau_ext_hat_filtered, np.ones(7))


def test_a_command_starts_a_continuous_motion_that_ends_at_rest(rig):
    rig.run(3, command=ZERO)
    rig.run(400, command=velocity(3, 0.3))                 # the node writes every period
    d = rig.driver
    assert d.events == ["start_velocity"]
    sent = [v for v, _ in d.velocities]
    assert sent[0] == [0.0] * 7 and sent[1] == [0.0] * 7      # START_ZEROS open the motion
    assert sent[-1][3] == pytest.approx(0.3)
    rig.run(200, command=[0.0] * 7)                        # the node's filter output at rest: zeros
    assert d.events == ["start_velocity", "finish_velocity"]
    last, finished = d.velocities[-1]
    assert finished and last == [0.0] * 7
    assert not any(f for _, f in d.velocities[:-1])
    assert_continuous(rig.loop, [v for v, _ in d.velocities])
    assert rig.state().mode == lf.Mode.IDLE
    # q integrates the commands (the fake robot follows them exactly)
    assert rig.robot.q[3] - Q0[3] == pytest.approx(sum(v[3] for v, _ in d.velocities[:-1]) * 0.001, abs=1e-9)


def test_the_loop_watchdog_brakes_when_commands_stop(rig):
    rig.run(2, command=ZERO)
    rig.run(300, command=velocity(0, 0.2))
    n = len(rig.driver.velocities)
    timeout = rig.loop.filter.config.command_timeout
    rig.run_until(lambda: rig.state().mode == lf.Mode.IDLE)
    after = [v for v, _ in rig.driver.velocities[n:]]
    still = next(i for i, v in enumerate(after) if v[0] < 0.2 - 1e-9)   # first braking step
    assert still == pytest.approx(timeout / lf.PERIOD, abs=2)
    assert rig.driver.velocities[-1] == ([0.0] * 7, True)
    assert_continuous(rig.loop, [v for v, _ in rig.driver.velocities])


def test_at_rest_the_state_slot_reports_the_filters_hold_not_the_last_motions_code(rig):
    """A motion that ended on the watchdog left AWAITING_ZERO in the state slot after the zero command
    that re-armed the filter at rest: the franka-sim test waiting for it to arm waited for ever (load
    30). Between motions the slot says what the filter holds now."""
    rig.run(2, command=ZERO)
    rig.run(300, command=velocity(0, 0.2))
    rig.run_until(lambda: rig.state().mode == lf.Mode.IDLE)   # the watchdog braked it; motion over
    assert rig.state().filter_code == SafetyCode.AWAITING_ZERO
    rig.run(3, command=velocity(0, 0.2))                     # the stick still held: nothing moves
    assert rig.state().filter_code == SafetyCode.AWAITING_ZERO and rig.state().mode == lf.Mode.IDLE
    rig.run(1, command=ZERO)                                 # neutral: armed, and the slot says so
    assert rig.loop.filter.arming.armed and rig.state().filter_code == SafetyCode.OK
    assert rig.state().mode == lf.Mode.IDLE


@pytest.mark.parametrize("bad, code", [([math.nan, 0, 0, 0, 0, 0, 0], SafetyCode.NON_FINITE_COMMAND),
                                       ([0.1] * 6, SafetyCode.WRONG_LENGTH)])
def test_malformed_commands_are_treated_as_zero(rig, bad, code):
    rig.run(2, command=ZERO)
    rig.run(200, command=velocity(1, 0.2))
    rig.command(bad)
    rig.run(1)
    assert rig.state().filter_code == code
    rig.run_until(lambda: rig.state().mode == lf.Mode.IDLE)
    assert_continuous(rig.loop, [v for v, _ in rig.driver.velocities])
    assert all(math.isfinite(x) for v, _ in rig.driver.velocities for x in v)


def test_a_reflex_stops_the_arm_and_recover_resumes(rig):
    rig.run(2, command=ZERO)
    rig.run(100, command=velocity(3, 0.2))
    rig.driver.fail_next = RobotError(REFLEX, REFLEX_TEXT)
    rig.run(1, command=velocity(3, 0.2))
    s = rig.state()
    assert s.status == lf.LoopStatus.REFLEX and s.errors == 1
    assert REFLEX_TEXT in rig.slots.read_text("status")
    cycle = s.cycle
    rig.run(200, command=velocity(3, 0.2))                 # commands do not move it before ~/recover
    assert rig.driver.events == ["start_velocity"]
    assert rig.state().cycle == cycle + 200                # but its state keeps flowing
    rig.request("recover")
    rig.run(1)
    s = rig.state()
    assert rig.driver.events[-1] == "recover"
    assert s.status == lf.LoopStatus.OK and s.recover_ack == 1 and s.recover_ok == 1
    rig.run(50, command=velocity(3, 0.2))
    assert rig.driver.events[-1] == "recover"              # a held stick does not restart it ...
    rig.run(1, command=ZERO)
    rig.run(50, command=velocity(3, 0.2))
    assert rig.driver.events[-1] == "start_velocity"       # the same connection drives again
    assert len(rig.drivers) == 1


def test_a_lost_connection_is_retried_with_backoff_and_states_stop(rig):
    rig.run(2, command=ZERO)
    rig.run(100, command=velocity(3, 0.2))
    rig.robot.reachable = False
    rig.run(1, command=velocity(3, 0.2))
    s = rig.state()
    assert s.status == lf.LoopStatus.DISCONNECTED and "UDP receive: Timeout" in rig.slots.read_text("status")
    cycle, t0, attempts = s.cycle, rig.clock.t, rig.robot.attempts
    tried_at = []
    while rig.clock.t - t0 < 3.0:
        before = rig.robot.attempts
        rig.loop.step()
        if rig.robot.attempts > before:
            tried_at.append(rig.clock.t - t0)
    assert rig.state().cycle == cycle                      # nothing new while the robot is silent
    gaps = np.diff(tried_at)
    assert len(tried_at) >= 4 and np.all(np.diff(gaps) >= -0.03), tried_at   # back-off grows ...
    assert gaps.max() <= rig.loop.settings.reconnect_max + 0.05                  # ... up to its cap
    assert rig.robot.attempts - attempts == len(tried_at)
    rig.robot.reachable = True
    rig.run_until(lambda: rig.state().status == lf.LoopStatus.OK)
    s = rig.state()
    assert s.connects == 2 and s.cycle > cycle and len(rig.drivers) == 2
    rig.run(1, command=ZERO)
    rig.run(20, command=velocity(3, 0.1))
    assert rig.driver.events == ["start_velocity"]         # the new connection starts from rest
    assert rig.driver.velocities[0][0] == [0.0] * 7


def test_a_fatal_error_waits_for_recover(rig):
    rig.robot.fatal = "libfranka: Incompatible library version (server version: 7, library version: 10)."
    for _ in range(200):
        rig.loop.step()
    assert rig.robot.attempts == 1
    assert rig.state().status == lf.LoopStatus.FATAL and "server version: 7" in rig.slots.read_text("status")
    rig.robot.fatal = ""
    rig.request("recover")
    rig.run_until(lambda: rig.state().status == lf.LoopStatus.OK, limit=50)
    s = rig.state()
    assert rig.robot.attempts == 2 and s.recover_ack == 1 and s.recover_ok == 1


def test_teaching_brakes_switches_to_torque_and_back_holding_the_pose(rig):
    settings = LoopSettings(robot={"robot_ip": "192.0.2.1", "teaching_damping": [2.0] * 7})
    r = Rig(settings)
    try:
        r.run(2, command=ZERO)
        r.run(200, command=velocity(0, 0.3))
        r.request("teaching", 1)
        r.run_until(lambda: r.state().mode == lf.Mode.TORQUE, command=velocity(0, 0.3))
        d = r.driver
        assert d.events == ["start_velocity", "finish_velocity", "start_torque"]
        assert d.velocities[-1] == ([0.0] * 7, True)
        assert_continuous(r.loop, [v for v, _ in d.velocities])
        assert r.state().teaching_ack == 1
        r.robot.dq = velocity(2, 0.5)                     # the hand moves joint 3
        r.run(10, command=velocity(0, 0.3))                # commands do not move it while teaching
        assert d.torques[-1][0] == pytest.approx(velocity(2, -1.0))
        assert d.events[-1] == "start_torque"
        r.robot.dq = [0.0] * 7
        r.request("teaching", 0)
        r.run(1)
        assert d.torques[-1] == ([0.0] * 7, True)
        s = r.state()
        assert s.mode == lf.Mode.IDLE and s.teaching_ack == 2
        r.run(50, command=velocity(0, 0.3))                # still held from before: no motion
        assert d.events[-1] == "finish_torque"
        r.run(1, command=ZERO)
        r.run(50, command=velocity(0, 0.2))                # velocity control again, from rest
        assert d.events[-1] == "start_velocity" and d.velocities[-50][0] == [0.0] * 7
    finally:
        r.close()


def test_teaching_is_refused_during_a_reflex(rig):
    rig.run(2, command=ZERO)
    rig.run(20, command=velocity(0, 0.2))
    rig.driver.fail_next = RobotError(REFLEX, REFLEX_TEXT)
    rig.run(1)
    rig.request("teaching", 1)
    rig.run(5)
    s = rig.state()
    assert s.teaching_ack == 1 and s.mode == lf.Mode.IDLE and "start_torque" not in rig.driver.events


def test_estop_brakes_and_holds_until_released(rig):
    rig.run(2, command=ZERO)
    rig.run(200, command=velocity(4, 0.4))
    rig.request("estop", 1)
    rig.run_until(lambda: rig.state().mode == lf.Mode.IDLE, command=velocity(4, 0.4))
    assert rig.state().estop_active == 1
    rig.run(100, command=velocity(4, 0.4))
    assert rig.driver.events == ["start_velocity", "finish_velocity"]
    rig.request("estop", 0)
    rig.run(20, command=velocity(4, 0.4))
    assert rig.driver.events[-1] == "finish_velocity"      # released: a zero command first
    rig.run(1, command=ZERO)
    rig.run(20, command=velocity(4, 0.4))
    assert rig.driver.events[-1] == "start_velocity"
    assert_continuous(rig.loop, [v for v, _ in rig.driver.velocities[:-20]])


def test_shutdown_brakes_ends_the_motion_and_stops(rig):
    rig.run(2, command=ZERO)
    rig.run(300, command=velocity(5, 1.0))
    rig.request("shutdown", 1)
    for _ in range(2000):
        if not rig.loop.step():
            break
    assert rig.loop.stopped and rig.state().status == lf.LoopStatus.STOPPED
    d = rig.driver
    assert d.velocities[-1] == ([0.0] * 7, True) and d.events[-2:] == ["finish_velocity", "close"]
    assert_continuous(rig.loop, [v for v, _ in d.velocities])


def test_the_loop_stops_when_its_parent_is_gone():
    r = Rig(parent_pid=os.getpid())                        # not our parent: as if it had died
    try:
        assert not r.loop.step()
        assert r.state().status == lf.LoopStatus.STOPPED and r.loop.orphaned
    finally:
        r.close()


def test_after_lost_cycles_the_next_command_continues_from_the_robots_reference(rig):
    """The FCI extrapolates a velocity stream it did not hear from at frozen acceleration, and judges
    the next command's jerk against that (franka-sim aborted with an acceleration discontinuity when
    the loop stepped its own filter through the gap instead). The next command is one jerk-limited
    step from the robot's reference, whatever the loop itself last sent."""
    rig.run(2, command=ZERO)
    rig.run(4, command=velocity(3, 0.05))                  # ramping up: jerk-limited, not constant
    d = rig.driver
    h = 0.001
    sent, a_ref = d.velocities[-1][0][3], (d.velocities[-1][0][3] - d.velocities[-2][0][3]) / h
    v_ref = sent + 3 * h * a_ref                           # what the robot extrapolated over the gap
    orig = d.read_cycle
    f = rig.loop.filter
    a_lim, d_max = f.a_max[3], f.j_max[3] * h
    d.extrapolated = ([0, 0, 0, v_ref, 0, 0, 0], [0, 0, 0, a_ref, 0, 0, 0])

    def late():
        state, _ = orig()
        return state, 0.004                                # three robot cycles were missed
    d.read_cycle = late
    rig.run(1, command=velocity(3, 0.05))
    assert rig.state().missed == 3
    out = d.velocities[-1][0][3]
    a_next = (out - v_ref) / h
    assert abs(a_next - a_ref) <= d_max + 1e-9 and abs(a_next) <= a_lim + 1e-9, (out, v_ref)


def test_a_command_slot_caught_mid_write_keeps_the_previous_command(rig):
    """The ROS side can be preempted inside a write for milliseconds: the loop must not wait or fail."""
    rig.run(2, command=ZERO)
    rig.run(100, command=velocity(3, 0.2))
    rig.slots._cmd_seq[0] += 1.0                           # odd: a write in progress
    rig.run(50)                                            # the loop goes on with what it had
    assert rig.driver.velocities[-1][0][3] == pytest.approx(0.2)
    rig.slots._cmd_seq[0] += 1.0
    rig.run(5, command=velocity(3, 0.2))
    assert rig.state().mode == lf.Mode.VELOCITY


@pytest.mark.parametrize("model", ["fr3", "panda"])
def test_the_loop_filter_has_the_robot_models_limits_at_the_robot_rate(model):
    from vla_common.robot import robot_spec

    f = lf.make_filter(LoopSettings(robot_model=model, safety={"velocity_scale": 0.5}))
    assert f.robot is robot_spec(model) and f.config.dt == lf.PERIOD
    np.testing.assert_allclose(f.v_max, robot_spec(model).dq_max * 0.5)


@pytest.mark.parametrize("silence", [0.15, 0.5])
def test_a_silent_robot_stops_the_arm_until_a_zero_command(rig, silence):
    """Issue 20 item 2: the robot stops answering for 150 or 500 ms mid-motion while the node keeps
    writing the held stick's command; when it answers again the arm must not resume by itself: the
    filter is disarmed (AWAITING_ZERO) until a zero command, and only then moves again."""
    rig.run(3, command=ZERO)
    rig.run(300, command=velocity(3, 0.3))
    assert rig.driver.velocities[-1][0][3] == pytest.approx(0.3)
    rig.clock.t += silence                                 # no robot cycle for `silence` s (wall)
    rig.run(1500, command=velocity(3, 0.3))                # the stick is still held
    assert rig.loop.filter.awaiting_zero and "silent" in rig.loop.filter.arming.reason
    tail = [v[3] for v, _ in rig.driver.velocities[-500:]] if rig.driver.in_motion else [0.0]
    assert max(abs(v) for v in tail) < 1e-9                # braked, and nothing restarts it
    assert rig.state().filter_code == SafetyCode.AWAITING_ZERO
    rig.run(5, command=ZERO)                               # the operator back at neutral
    rig.run(400, command=velocity(3, 0.3))
    assert rig.driver.velocities[-1][0][3] == pytest.approx(0.3)


# ------------------------------------------------------------------------------- the state table
README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_shows_the_loops_state_table():
    text = README.read_text()
    start = text.index("\n", text.index("<!-- loop-table")) + 1
    assert text[start:text.index("<!-- /loop-table -->")] == lf.table_markdown()


def test_every_event_of_the_table_is_raised_by_the_loop_and_no_other():
    source = Path(lf.__file__).read_text()
    raised = set(re.findall(r'_go\("([^"]+)"', source))
    assert raised == {row.event for row in lf.TABLE}


def test_the_stops_the_operator_did_not_choose_disarm_in_every_state():
    """One row per stop; every state it can happen in disarms (issue 20 items 2, 3)."""
    stops = {"connected", "fatal error", "connection lost", "reflex", "teaching ends", "e-stop change",
             "robot silent"}
    disarming = {row.event for row in lf.TABLE if row.disarm}
    assert stops <= disarming and "recover request" in disarming


def test_an_event_the_table_does_not_list_raises(rig):
    rig.run(3, command=ZERO)
    assert rig.loop.state is lf.State.IDLE
    with pytest.raises(RuntimeError, match="no transition for 'at rest' in state IDLE"):
        rig.loop._go("at rest")

"""The libfranka backend's node side with a fake host and no loop process (its slots written by the
test as the loop would): control periods catch up by the wall clock, every robot state is
published once, faults reach host.on_fault once per change, a silent or faulted robot brakes, the
robot's external torque estimate slows motion into a contact before the collision reflex."""

from __future__ import annotations

import time

import numpy as np
import pytest
from vla_common.robot import FR3
from vla_common.safety_status import SafetyCode
from vla_panda_bridge.backend_libfranka import MAX_CATCH_UP, LibfrankaBackend
from vla_panda_bridge.backends import reflex_torque
from vla_panda_bridge.libfranka_driver import DriverSettings
from vla_panda_bridge.libfranka_loop import LoopStatus
from vla_panda_bridge.libfranka_slots import CMD_VALUES, STATE
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter


class Logger:
    def __init__(self):
        self.lines = []

    def info(self, m, **kw):
        self.lines.append(("info", m))

    warn = warning = error = info


class Host:
    def __init__(self, **params):
        self.params = {"control_rate": 1000, "state_rate": 1000.0, "state_timeout": 0.25,
                       "robot_ip": "192.0.2.1", "driver": "pylibfranka", "realtime_config": "ignore",
                       "lower_torque_thresholds": [20.0] * 7, "upper_torque_thresholds": [20.0] * 7,
                       "lower_force_thresholds": [20.0] * 6, "upper_force_thresholds": [20.0] * 6,
                       "joint_impedance": [3000.0] * 7, "teaching_damping": [1.0] * 7, "loop_prefix": "",
                       "loop_priority": 0, "gripper": False,
                       "velocity_scale": 1.0, "acceleration_scale": 1.0,
                       "jerk_scale": 1.0, "position_margin": 0.1, "command_timeout": 0.1,
                       "position_sync_tolerance": 0.05, "plausibility_factor": 2.0, **params}
        self.spec = FR3
        self.base_frame = "fr3_link0"
        self.steps = 0
        self.published = []
        self.faults = []
        self.logger = Logger()
        self.backend = None

    def control_step(self):
        self.steps += 1

    def publish_state(self):
        self.published.append(self.backend.latest().cycle)

    def on_fault(self, text):
        self.faults.append(text)

    def get_logger(self):
        return self.logger


@pytest.fixture
def rig():
    host = Host()
    backend = LibfrankaBackend(host)
    host.backend = backend
    yield host, backend
    backend.process.slots.close()


def loop_writes(backend, cycle: int, status: int = LoopStatus.OK, text: str = "connected", q=None,
                tau_ext=None, filter_code: int = SafetyCode.OK):
    """What the loop process would write for robot state `cycle`."""
    slots = backend.process.slots
    q = [0.1] * 7 if q is None else q
    slots.push_history(cycle, time.time(), q, [0.0] * 7, [0.0] * 7)
    b = slots.begin_state()
    b[STATE["cycle"]], b[STATE["pid"]], b[STATE["status"]] = cycle, 1, status
    b[STATE["q"]] = q
    b[STATE["tau_ext_hat_filtered"]] = [0.0] * 7 if tau_ext is None else tau_ext
    b[STATE["filter_code"]] = filter_code
    slots.end_state()
    slots.write_text("status", text)


def test_a_late_timer_catches_up_by_the_wall_clock(rig):
    host, backend = rig
    backend._t0 = time.monotonic() - 0.0105                # the timer fires 10 periods late
    backend._tick()
    assert host.steps == 10 and backend._ticks == 10
    backend._t0 -= 1.0                                      # a whole second late: bounded, then skipped
    backend._tick()
    assert host.steps == 10 + MAX_CATCH_UP and backend._ticks >= 1010
    steps = host.steps
    backend._tick()                                         # on time now: at most one period
    assert host.steps - steps <= 1


def test_every_robot_state_is_published_once_and_none_while_silent(rig):
    host, backend = rig
    for k in range(1, 6):
        loop_writes(backend, k)
    backend._t0 = time.monotonic() - 0.0015
    backend._tick()
    assert host.published == [1, 2, 3, 4, 5]
    backend._t0 -= 0.002
    backend._tick()                                         # the robot silent: nothing new
    assert host.published == [1, 2, 3, 4, 5]


def test_faults_reach_the_node_once_per_change_and_the_filter_brakes(rig):
    host, backend = rig
    loop_writes(backend, 1)
    backend._t0 = time.monotonic() - 0.0105
    backend._tick()
    np.testing.assert_allclose(backend.filter_position(), 0.1)
    loop_writes(backend, 2, LoopStatus.REFLEX, 'ControlException: ... reflex! ["joint_velocity_violation"]')
    for _ in range(3):
        backend._t0 -= 0.0105
        backend._tick()
    assert len(host.faults) == 1 and "joint_velocity_violation" in host.faults[0]
    assert np.isnan(backend.filter_position()).all()        # held: the node's filter brakes
    loop_writes(backend, 3, LoopStatus.DISCONNECTED, "NetworkException: libfranka: UDP receive: Timeout")
    backend._t0 -= 0.0105
    backend._tick()
    assert len(host.faults) == 2 and "UDP receive: Timeout" in host.faults[1]
    loop_writes(backend, 4, LoopStatus.OK, "connected to 192.0.2.1 (pylibfranka)")
    backend._t0 -= 0.0105
    backend._tick()
    assert len(host.faults) == 2 and not np.isnan(backend.filter_position()).any()


def test_a_stop_of_the_loops_filter_stops_the_nodes_filter_while_it_commands_motion(rig):
    """The loop's filter waits for a zero command (its watchdog fired while this process was late) and
    ignores the node's non-zero commands: the node's filter is told, once per watch, and only while it
    commands motion (its zeros re-arm the loop: no stop then)."""
    host, backend = rig
    stops = host.stops = []
    host.on_stop = stops.append
    loop_writes(backend, 1, filter_code=SafetyCode.AWAITING_ZERO)
    backend.write(np.zeros(7))                              # the node commands nothing: nothing to stop
    backend._t0 = time.monotonic() - 0.0105
    backend._tick()
    assert stops == []
    backend.write(np.full(7, 0.2))                          # the node drives; the loop refuses
    backend._t0 -= 0.0105
    backend._tick()
    assert len(stops) == 1 and "loop stopped" in stops[0]
    loop_writes(backend, 2)                                 # re-armed: the node's stop is its own now
    backend._t0 -= 0.0105
    backend._tick()
    assert len(stops) == 1


class NodeHost(Host):
    """A host whose control step is the bridge node's: its SafetyFilter, with the reflex table the node
    gives it (backends.reflex_torque), run against the backend's state and external torque."""

    def __init__(self, **params):
        super().__init__(backend="libfranka",
                         upper_torque_thresholds=list(DriverSettings.upper_torque_thresholds), **params)
        self.filter = SafetyFilter(SafetyConfig(dt=0.001), robot=FR3,
                                   reflex_torque=reflex_torque(self.params, FR3))
        self.code = None

    def control_step(self):
        b = self.backend
        dq, self.code, _ = self.filter.filter(None, b.filter_position(), b.now(), b.external_torque())
        b.write(dq)


def test_the_robots_external_torque_slows_motion_into_it_before_the_collision_reflex():
    """Issue 20 items 5/6: on a real arm the contact slowing works from libfranka's tau_ext_hat_filtered
    and acts below the collision thresholds the robot was configured with (upper_torque_thresholds:
    20 Nm on joint 2; tau_max is 87 Nm, so fractions of it would come after the reflex)."""
    host = NodeHost()
    clock = [1000.0]        # the backend's clock: one control period per robot state, however slow the test
    backend = host.backend = LibfrankaBackend(host, clock=lambda: clock[0])
    cycle = 0

    def drive(cmd, ticks, tau_ext=None):
        nonlocal cycle
        for _ in range(ticks):
            cycle += 1
            loop_writes(backend, cycle, tau_ext=tau_ext)
            host.filter.submit(cmd, backend.now())
            clock[0] += 0.001                               # one control period due
            backend._tick()
        return backend.process.slots.read_command()[CMD_VALUES:].copy()

    try:
        assert backend.external_torque() is None             # no robot state yet
        zero = [0.0] * 7
        into = [0.0, 0.5, 0, 0, 0, 0, 0]
        drive(zero, 20)                                      # the first state, armed by a zero command
        np.testing.assert_array_equal(backend.external_torque(), np.zeros(7))
        assert drive(into, 300)[1] == pytest.approx(0.5)     # free motion: full speed
        push = [0.0, -12.0, 0, 0, 0, 0, 0]                   # 0.6 x 20 Nm against the motion (0.14 x tau_max)
        assert drive(into, 300, push)[1] == pytest.approx(0.5 * 0.25)
        assert host.code == SafetyCode.CONTACT
        push[1] = -15.0                                      # 0.75 x 20 Nm: stopped, before the reflex at 20
        assert drive(into, 300, push)[1] == pytest.approx(0.0, abs=1e-12)
        assert drive([-x for x in into], 300, push)[1] == pytest.approx(-0.5)   # backing out: free
        loop_writes(backend, cycle + 1, LoopStatus.REFLEX, "reflex", tau_ext=push)
        backend._t0 -= 0.0105
        backend._tick()
        assert backend.external_torque() is None             # no valid state: none (the filter brakes)
    finally:
        backend.process.slots.close()


def test_the_node_scales_contact_slowing_to_the_reflex_of_the_robot_behind_its_backend():
    params = {"backend": "libfranka", "upper_torque_thresholds": [30.0, 25, 20, 20, 10, 10, 8]}
    assert reflex_torque(params, FR3) == [30.0, 25, 20, 20, 10, 10, 8]
    for backend in ("mujoco", "ros2_control"):              # the simulated arm's reflex: tau_max
        assert reflex_torque({**params, "backend": backend}, FR3) == [float(x) for x in FR3.tau_max]

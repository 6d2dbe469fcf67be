"""The libfranka backend's node side with a fake host and no loop process (its slots written by the
test as the loop would): control periods catch up by the wall clock, every robot state is
published once, faults reach host.on_fault once per change, a silent or faulted robot brakes."""

from __future__ import annotations

import time

import numpy as np
import pytest
from vla_common.robot import FR3
from vla_panda_bridge.backend_libfranka import MAX_CATCH_UP, LibfrankaBackend
from vla_panda_bridge.libfranka_loop import LoopStatus
from vla_panda_bridge.libfranka_slots import STATE


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


def loop_writes(backend, cycle: int, status: int = LoopStatus.OK, text: str = "connected", q=None):
    """What the loop process would write for robot state `cycle`."""
    slots = backend.process.slots
    q = [0.1] * 7 if q is None else q
    slots.push_history(cycle, time.time(), q, [0.0] * 7, [0.0] * 7)
    b = slots.begin_state()
    b[STATE["cycle"]], b[STATE["pid"]], b[STATE["status"]] = cycle, 1, status
    b[STATE["q"]] = q
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

"""The panda-py driver (Panda/FER) against panda-py's Python API with its network layer replaced by
a fake `Panda` object: the real `panda_py.controllers.IntegratedVelocity` and `panda_py.libfranka`
enums, a fake robot behind them. No protocol-5 simulator exists, so hardware is still to check."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest
from vla_panda_bridge.libfranka_driver import REFLEX, DriverSettings, RobotError
from vla_panda_bridge.libfranka_loop import ControlLoop, LoopSettings, Mode
from vla_panda_bridge.libfranka_slots import Slots

panda_py = pytest.importorskip("panda_py", reason="panda-python==1.1.1 is not installed")
from panda_py import controllers, libfranka  # noqa: E402

Q0 = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


class Duration:
    def __init__(self, s):
        self.s = s

    def to_sec(self):
        return self.s


@dataclass
class State:
    q: list
    dq: list = field(default_factory=lambda: [0.0] * 7)
    tau_J: list = field(default_factory=lambda: [0.0] * 7)  # noqa: N815 (libfranka's name)
    tau_ext_hat_filtered: list = field(default_factory=lambda: [0.0] * 7)
    O_T_EE: list = field(default_factory=lambda: [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.3, 0, 0.5, 1])
    robot_mode: object = libfranka.RobotMode.kIdle
    control_command_success_rate: float = 1.0
    time: Duration = field(default_factory=lambda: Duration(0.0))


class FakeClock:
    def __init__(self):
        self.t = 10.0
        self.slept = []

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.slept.append(s)
        self.t += s


class FakeRobot:
    """panda_py.libfranka.Robot's calls the driver makes."""

    def __init__(self, panda):
        self.panda = panda

    def set_collision_behavior(self, *thresholds):
        self.panda.calls.append(("set_collision_behavior", thresholds))

    def set_joint_impedance(self, k):
        self.panda.calls.append(("set_joint_impedance", k))

    def read_once(self):
        self.panda.advance()
        return self.panda.get_state()


class FakePanda:
    """panda_py.Panda with the network replaced: the controller thread is the fake's `advance()`."""

    def __init__(self, hostname, realtime_config=None, clock=None):
        self.calls = [("Panda", hostname, realtime_config)]
        self.clock = clock
        self.t = 0.0
        self.q = list(Q0)
        self.controller = None
        self.teaching = False
        self.error: str | None = None

    def get_robot(self):
        return FakeRobot(self)

    def advance(self):
        self.t = round(self.t + 0.001, 9)

    def get_state(self):
        return State(q=list(self.q), time=Duration(self.t))

    def start_controller(self, controller):
        assert isinstance(controller, controllers.IntegratedVelocity)
        self.calls.append(("start_controller",))
        self.controller = controller

    def stop_controller(self):
        self.calls.append(("stop_controller",))
        self.controller = None

    def raise_error(self):
        self.advance()
        if self.error:
            raise RuntimeError(self.error)

    def teaching_mode(self, active, damping=None):
        self.calls.append(("teaching_mode", active, None if damping is None else list(damping)))
        self.teaching = active

    def recover(self):
        self.calls.append(("recover",))
        self.error = None


@pytest.fixture
def rig():
    from vla_panda_bridge.libfranka_panda_py import PandaPyDriver

    clock = FakeClock()
    pandas = []

    def factory(hostname, realtime_config=None):
        pandas.append(FakePanda(hostname, realtime_config, clock))
        return pandas[-1]

    settings = DriverSettings(robot_ip="192.0.2.5", realtime="ignore", teaching_damping=(3.0,) * 7)
    driver = PandaPyDriver(settings, panda_factory=factory, clock=clock, sleep=clock.sleep)
    return driver, pandas, clock


def test_connect_configures_the_robot(rig):
    driver, pandas, _ = rig
    driver.connect()
    p = pandas[0]
    assert p.calls[0] == ("Panda", "192.0.2.5", libfranka.RealtimeConfig.kIgnore)
    assert p.calls[1][0] == "set_collision_behavior" and len(p.calls[1][1]) == 4
    assert p.calls[2] == ("set_joint_impedance", list(driver.settings.joint_impedance))


def test_a_velocity_motion_runs_the_integrated_velocity_controller_paced_at_1khz(rig):
    driver, pandas, clock = rig
    driver.connect()
    driver.start_velocity()
    p = pandas[0]
    assert p.controller is not None
    t0 = clock.t
    for k in range(5):
        state, dt = driver.read_cycle()
        assert dt == pytest.approx(0.001)
        driver.write_velocity([0.01 * k] * 7, finished=False)
    assert clock.t - t0 == pytest.approx(0.005)              # slept to each next millisecond
    driver.write_velocity([0.0] * 7, finished=True)
    assert p.calls[-1] == ("stop_controller",) and p.controller is None


def test_a_controller_thread_error_surfaces_as_a_reflex(rig):
    driver, pandas, _ = rig
    driver.connect()
    driver.start_velocity()
    pandas[0].error = "libfranka: Move command aborted: motion aborted by reflex! [\"cartesian_reflex\"]"
    with pytest.raises(RobotError) as info:
        driver.read_cycle()
    assert info.value.kind == REFLEX and "cartesian_reflex" in info.value.text
    assert pandas[0].controller is None                       # the controller thread was stopped
    driver.recover()
    assert pandas[0].calls[-1] == ("recover",)


def test_teaching_uses_panda_py_teaching_mode_with_the_damping(rig):
    driver, pandas, _ = rig
    driver.connect()
    driver.start_torque()
    driver.read_cycle()
    driver.write_torque([0.0] * 7, finished=False)
    driver.write_torque([0.0] * 7, finished=True)
    modes = [c for c in pandas[0].calls if c[0] == "teaching_mode"]
    assert modes == [("teaching_mode", True, [3.0] * 7), ("teaching_mode", False, None)]


def test_the_loop_drives_a_panda_through_panda_py(rig):
    driver, pandas, clock = rig
    slots = Slots.create()
    try:
        def opener(name, settings):
            driver.connect()
            return driver
        loop = ControlLoop(slots, LoopSettings(driver="panda_py", robot={"robot_ip": "192.0.2.5"}),
                           opener=opener, clock=clock, sleep=clock.sleep)
        for _ in range(3):
            slots.write_command([0.0] * 7, clock.t)           # the node's filter at rest: zeros
            loop.step()
        for _ in range(300):
            slots.write_command([0.0, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0], clock.t)
            loop.step()
        assert slots.read_state().mode == Mode.VELOCITY and pandas[0].controller is not None
        for _ in range(500):
            loop.step()                                       # no commands: the watchdog stops it
        assert slots.read_state().mode == Mode.IDLE
        names = [c[0] for c in pandas[0].calls]
        assert names.count("start_controller") == 1 and names[-1] == "stop_controller"
        assert np.isfinite(slots.read_state().q).all()
    finally:
        slots.close()

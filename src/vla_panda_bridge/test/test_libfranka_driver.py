"""libfranka's errors as the loop sees them, the driver choice (`driver: auto`) and the bridge's
libfranka parameters."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from vla_panda_bridge.backend import BackendError
from vla_panda_bridge.backend_libfranka import loop_settings
from vla_panda_bridge.libfranka_driver import CONNECTION, FATAL, REFLEX, DriverSettings, RobotError, classify

from vla_panda_bridge import libfranka_open as drv


def _exc(name: str, text: str) -> Exception:
    return type(name, (RuntimeError,), {})(text)


# The texts franka-sim and pylibfranka 0.21.3 produced (docs/history/libfranka-notes.md, section 3.5).
@pytest.mark.parametrize("exc, kind", [
    (_exc("ControlException", 'libfranka: Move command aborted: motion aborted by reflex! '
          '["communication_constraints_violation"]'), REFLEX),
    (_exc("ControlException", 'libfranka: Move command aborted: motion aborted by reflex! '
          '["joint_velocity_violation", "joint_motion_generator_velocity_limits_violation"]'), REFLEX),
    (_exc("NetworkException", "libfranka: UDP receive: Timeout"), CONNECTION),
    (_exc("NetworkException", "libfranka: server closed connection"), CONNECTION),
    (RuntimeError("Net Exception"), CONNECTION),
    (_exc("ControlException", "libfranka robot: Attempted to start multiple motions!"), CONNECTION),
    (_exc("NetworkException", "libfranka: Connection to FCI refused. Please install FCI feature or "
          "enable FCI mode in Desk."), CONNECTION),
    (_exc("RealtimeException", "libfranka: Running kernel does not have realtime capabilities."), FATAL),
    (RuntimeError("libfranka: Incompatible library version (server version: 5, library version: 10)."),
     FATAL),
    (ValueError("Commanding value is infinite or NaN."), FATAL),
    (_exc("IncompatibleVersionError", "The robot speaks protocol version 9, but this panda-py was built "
          "with a libfranka that speaks version 5."), FATAL),
])
def test_libfranka_errors_are_classified(exc, kind):
    err = classify(exc, during_motion=True)
    assert err.kind == kind
    assert str(exc) in err.text


def test_the_server_version_is_read_from_the_incompatible_version_text():
    assert drv.server_version("libfranka: Incompatible library version (server version: 5, "
                              "library version: 10).") == 5
    assert drv.server_version("IncompatibleVersionError: The robot speaks protocol version 9, but "
                              "this panda-py was built with a libfranka that speaks version 5.") == 9
    assert drv.server_version("libfranka: UDP receive: Timeout") is None


class _Fake:
    def __init__(self, name, error=None):
        self.name, self.error, self.connected = name, error, False

    def connect(self):
        if self.error:
            raise self.error
        self.connected = True


def _incompatible(version: int) -> RobotError:
    return RobotError(FATAL, f"libfranka: Incompatible library version (server version: {version}, "
                             "library version: 10).")


def test_auto_picks_panda_py_when_the_robot_speaks_the_pandas_protocol(monkeypatch):
    made = []
    monkeypatch.setattr(drv, "_pylibfranka", lambda s: made.append(_Fake("pylibfranka", _incompatible(5)))
                        or made[-1])
    monkeypatch.setattr(drv, "_panda_py", lambda s: made.append(_Fake("panda_py")) or made[-1])
    d = drv.open_driver("auto", DriverSettings(robot_ip="192.0.2.1"))
    assert d.name == "panda_py" and d.connected and [m.name for m in made] == ["pylibfranka", "panda_py"]


def test_auto_fails_naming_the_protocol_it_saw(monkeypatch):
    monkeypatch.setattr(drv, "_pylibfranka", lambda s: _Fake("pylibfranka", _incompatible(7)))
    monkeypatch.setattr(drv, "_panda_py", lambda s: pytest.fail("panda-py does not speak protocol 7"))
    with pytest.raises(RobotError) as info:
        drv.open_driver("auto", DriverSettings(robot_ip="192.0.2.1"))
    assert info.value.kind == FATAL
    text = info.value.text
    assert "protocol 7" in text and "pylibfranka" in text and "panda-py" in text


def test_auto_passes_other_errors_on(monkeypatch):
    refused = RobotError(CONNECTION, "NetworkException: libfranka: Connection to FCI refused.")
    monkeypatch.setattr(drv, "_pylibfranka", lambda s: _Fake("pylibfranka", refused))
    with pytest.raises(RobotError) as info:
        drv.open_driver("auto", DriverSettings(robot_ip="192.0.2.1"))
    assert info.value is refused


def test_an_unknown_driver_is_fatal():
    with pytest.raises(RobotError, match="is not one of"):
        drv.open_driver("franky", DriverSettings(robot_ip="192.0.2.1"))


class _Robot:
    def __init__(self, ip, rt):
        self.calls = [("Robot", ip, rt)]

    def set_collision_behavior(self, *a):
        self.calls.append(("collision", a))

    def set_joint_impedance(self, k):
        self.calls.append(("impedance", k))


def _module(robot_cls=_Robot):
    cmd = type("Cmd", (), {"__init__": lambda self, v: None})
    return SimpleNamespace(Robot=robot_cls, JointVelocities=cmd, Torques=cmd,
                           RealtimeConfig=SimpleNamespace(kEnforce="enforce", kIgnore="ignore"),
                           ControllerMode=SimpleNamespace(JointImpedance=0))


def test_pylibfranka_connects_with_the_settings():
    s = DriverSettings(robot_ip="192.0.2.1", realtime="ignore", joint_impedance=(1.0,) * 7)
    d = drv.PylibfrankaDriver(s, module=_module())
    d.connect()
    assert d.robot.calls[0] == ("Robot", "192.0.2.1", "ignore")
    thresholds = (s.lower_torque_thresholds, s.upper_torque_thresholds, s.lower_force_thresholds,
                  s.upper_force_thresholds)
    assert d.robot.calls[1] == ("collision", tuple(list(t) for t in thresholds))
    assert d.robot.calls[2] == ("impedance", [1.0] * 7)


def test_pylibfranka_connection_errors_come_out_classified():
    def refuse(ip, rt):
        raise _exc("RealtimeException", "libfranka: Running kernel does not have realtime capabilities.")
    settings = DriverSettings(robot_ip="192.0.2.1", realtime="enforce")
    d = drv.PylibfrankaDriver(settings, module=_module(refuse))
    with pytest.raises(RobotError) as info:
        d.connect()
    assert info.value.kind == FATAL and d.robot is None


PARAMS = {"robot_ip": "192.0.2.1", "driver": "auto", "realtime_config": "ignore", "loop_priority": 0,
          "lower_torque_thresholds": [20.0] * 7, "upper_torque_thresholds": [20.0] * 7,
          "lower_force_thresholds": [20.0] * 6, "upper_force_thresholds": [20.0] * 6,
          "joint_impedance": [3000.0] * 7, "teaching_damping": [1.0] * 7, "velocity_scale": 0.5,
          "acceleration_scale": 1.0, "jerk_scale": 1.0, "position_margin": 0.1, "command_timeout": 0.1,
          "position_sync_tolerance": 0.05, "plausibility_factor": 2.0}


def test_the_bridge_parameters_make_the_loop_settings():
    s = loop_settings(PARAMS, "fr3")
    assert s.robot_model == "fr3" and s.driver == "auto" and s.safety["velocity_scale"] == 0.5
    assert s.driver_settings().teaching_damping == [1.0] * 7


@pytest.mark.parametrize("name, value, match", [
    ("robot_ip", "", "robot_ip"),
    ("joint_impedance", [3000.0] * 6, "joint_impedance"),
    ("upper_force_thresholds", [20.0] * 5 + [float("nan")], "upper_force_thresholds"),
    ("teaching_damping", [-1.0] * 7, "teaching_damping"),
])
def test_bad_libfranka_parameters_are_refused(name, value, match):
    with pytest.raises(BackendError, match=match):
        loop_settings({**PARAMS, name: value}, "fr3")


def test_after_lost_cycles_each_driver_says_where_its_robot_went_on():
    """The FCI extrapolates a velocity stream at frozen acceleration; panda-py's thread holds it."""
    from vla_panda_bridge.libfranka_driver import PERIOD, DriverSettings, PylibfrankaDriver
    from vla_panda_bridge.libfranka_panda_py import PandaPyDriver

    v, a = [0.1] * 7, [2.0] + [0.0] * 6
    fci = PylibfrankaDriver(DriverSettings(robot_ip="x"), module=_module())
    v3, a3 = fci.gap_reference(v, a, 3)
    assert v3[0] == pytest.approx(0.1 + 3 * PERIOD * 2.0) and v3[1:] == v[1:] and list(a3) == a
    held = PandaPyDriver.gap_reference(None, v, a, 3)
    assert held == (v, [0.0] * 7)

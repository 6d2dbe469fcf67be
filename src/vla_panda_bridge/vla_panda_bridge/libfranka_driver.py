"""The robot behind the libfranka loop: one small driver interface, its error kinds, and the
pylibfranka driver (FR3, server protocol 10). The panda-py driver (Panda/FER) is in
libfranka_panda_py.py; `libfranka_open.open_driver` picks one, also from the robot's answer
(`driver: auto`). This module imports neither (import-linter contract "libfranka-no-cycle").

The loop calls, per motion: `start_velocity()`, then every cycle `read_cycle()` and one
`write_velocity(dq, finished)` (the last with finished=True); `start_torque()` / `write_torque()` the
same way for teaching; `read_idle()` between motions. Every failure comes out as a `RobotError` whose
`kind` tells the loop what to do: REFLEX (the robot stopped itself; wait for ~/recover), CONNECTION
(drop the connection and reconnect with back-off), FATAL (retrying cannot help: wrong protocol
version, no real-time kernel; wait for ~/recover or a fix).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

REFLEX = "reflex"
CONNECTION = "connection"
FATAL = "fatal"

DRIVERS = ("auto", "pylibfranka", "panda_py")
REALTIME = ("enforce", "ignore")
PERIOD = 0.001              # the robot's control cycle (s)
PYLIBFRANKA_PROTOCOL = 10   # pylibfranka 0.21.3 (libfranka 0.21): FR3 with system >= 5.9
PANDA_PY_PROTOCOL = 5       # panda-py 1.1.1 (libfranka 0.9.2): Panda (FER)

# Words of libfranka's messages for a connection that is gone (also "Attempted to start multiple
# motions!", the answer of a Robot whose connection died earlier).
_LOST = ("network", "udp", "tcp", "connection", "net exception", "host not found", "timeout",
         "multiple motions")
# libfranka: "Incompatible library version (server version: 5, library version: 10)"; panda-py's own
# IncompatibleVersionError: "The robot speaks protocol version 5, but this panda-py was built ...".
_SERVER_VERSION = re.compile(r"(?:server version:|robot speaks protocol version)\s*(\d+)")


class RobotError(RuntimeError):
    """A failure of the robot or its connection; `kind` is REFLEX, CONNECTION or FATAL."""

    def __init__(self, kind: str, text: str):
        super().__init__(text)
        self.kind = kind
        self.text = text


def server_version(text: str) -> int | None:
    """The robot's protocol version named in libfranka's IncompatibleVersion message, if any."""
    m = _SERVER_VERSION.search(text)
    return int(m.group(1)) if m else None


def classify(exc: BaseException, during_motion: bool) -> RobotError:
    """libfranka's exceptions -> a RobotError. Both bindings raise RuntimeError subclasses (or plain
    RuntimeError, e.g. "Net Exception"), so the message decides where the type does not."""
    if isinstance(exc, RobotError):
        return exc
    name = type(exc).__name__
    text = str(exc) if name == "RuntimeError" else f"{name}: {exc}"
    low = text.lower()
    lost = any(w in low for w in _LOST)
    if "incompatible" in name.lower() or "incompatible library version" in low or "realtime" in low \
            or "real-time" in low:
        return RobotError(FATAL, text)
    if not lost and (name == "ControlException" or "reflex" in low or "move command aborted" in low):
        return RobotError(REFLEX, text)
    if lost or name in ("NetworkException", "InvalidOperationException"):
        return RobotError(CONNECTION, text)
    if name == "CommandException":
        # The robot refused a command (e.g. a start in the wrong mode): a fresh connection resets it.
        return RobotError(REFLEX if during_motion else CONNECTION, text)
    if isinstance(exc, ValueError | TypeError):
        return RobotError(FATAL, f"the loop sent an invalid command (a bug): {text}")
    return RobotError(CONNECTION, text)


@dataclass(frozen=True)
class DriverSettings:
    """What a driver needs to connect and configure the robot (all from the bridge's parameters)."""

    robot_ip: str
    realtime: str = "ignore"                 # REALTIME
    lower_torque_thresholds: Sequence[float] = (20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0)
    upper_torque_thresholds: Sequence[float] = (20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0)
    lower_force_thresholds: Sequence[float] = (20.0, 20.0, 20.0, 25.0, 25.0, 25.0)
    upper_force_thresholds: Sequence[float] = (20.0, 20.0, 20.0, 25.0, 25.0, 25.0)
    joint_impedance: Sequence[float] = (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0)
    teaching_damping: Sequence[float] = (2.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0)
    extra: dict = field(default_factory=dict)


class Driver(Protocol):
    """See the module docstring. States have libfranka's RobotState attributes (q, dq, tau_J,
    tau_ext_hat_filtered, O_T_EE, robot_mode, control_command_success_rate, time, last_motion_errors)."""

    name: str

    def connect(self) -> None: ...
    def read_idle(self) -> Any: ...
    def start_velocity(self) -> None: ...
    def read_cycle(self) -> tuple[Any, float]: ...
    def write_velocity(self, dq: Sequence[float], finished: bool) -> None: ...
    def gap_reference(self, v: Sequence[float], a: Sequence[float],
                      cycles: int) -> tuple[Sequence[float], Sequence[float]]:
        """The joint velocity and acceleration the robot is at after `cycles` commands it did not get
        from us (the last we sent: v, a): what the next command must continue from."""
        ...
    def start_torque(self) -> None: ...
    def write_torque(self, tau: Sequence[float], finished: bool) -> None: ...
    def recover(self) -> None: ...
    def close(self) -> None: ...


class PylibfrankaDriver:
    """pylibfranka 0.21.3. Every call holds the GIL (so the loop runs in its own process); readOnce
    paces the loop; after a NetworkException the Robot is dead for good (the loop makes a new driver);
    never readOnce after a motion_finished command (it blocks forever), read_once instead."""

    name = "pylibfranka"

    def __init__(self, settings: DriverSettings, module: Any = None):
        if module is None:
            import pylibfranka as module  # optional dependency: only a real arm / franka-sim needs it
        self._f = module
        self.settings = settings
        self.robot = None
        self.ctl = None
        self._vel = module.JointVelocities([0.0] * 7)   # reused every cycle: no allocation on the path
        self._tau = module.Torques([0.0] * 7)

    def connect(self) -> None:
        f, s = self._f, self.settings
        rt = f.RealtimeConfig.kEnforce if s.realtime == "enforce" else f.RealtimeConfig.kIgnore
        try:
            robot = f.Robot(s.robot_ip, rt)
            robot.set_collision_behavior(list(s.lower_torque_thresholds), list(s.upper_torque_thresholds),
                                         list(s.lower_force_thresholds), list(s.upper_force_thresholds))
            robot.set_joint_impedance(list(s.joint_impedance))
            self.robot = robot
        except Exception as exc:
            self.robot = None
            raise classify(exc, during_motion=False) from exc

    def read_idle(self):
        try:
            return self.robot.read_once()
        except Exception as exc:
            raise classify(exc, during_motion=False) from exc

    def start_velocity(self) -> None:
        try:
            self.ctl = self.robot.start_joint_velocity_control(self._f.ControllerMode.JointImpedance)
        except Exception as exc:
            self.ctl = None
            raise classify(exc, during_motion=False) from exc

    def start_torque(self) -> None:
        try:
            self.ctl = self.robot.start_torque_control()
        except Exception as exc:
            self.ctl = None
            raise classify(exc, during_motion=False) from exc

    def read_cycle(self):
        try:
            state, duration = self.ctl.readOnce()
        except Exception as exc:
            self.ctl = None
            raise classify(exc, during_motion=True) from exc
        return state, duration.to_sec()

    def write_velocity(self, dq: Sequence[float], finished: bool) -> None:
        cmd = self._vel
        cmd.dq = dq
        cmd.motion_finished = finished
        self._write(cmd, finished)

    def gap_reference(self, v, a, cycles: int):
        """The FCI extrapolates a lost cycle's command "keeping the acceleration constant" (libfranka's
        docs; franka-sim does the same): the velocity went on at the frozen acceleration."""
        return [x + cycles * PERIOD * y for x, y in zip(v, a)], list(a)

    def write_torque(self, tau: Sequence[float], finished: bool) -> None:
        cmd = self._tau
        cmd.tau_J = tau
        cmd.motion_finished = finished
        self._write(cmd, finished)

    def _write(self, cmd, finished: bool) -> None:
        try:
            self.ctl.writeOnce(cmd)
        except Exception as exc:
            self.ctl = None
            raise classify(exc, during_motion=True) from exc
        if finished:
            self.ctl = None

    def recover(self) -> None:
        self.ctl = None
        try:
            self.robot.automatic_error_recovery()
        except Exception as exc:
            raise classify(exc, during_motion=False) from exc

    def close(self) -> None:
        """Drop the connection (an unfinished ActiveControl is cancelled by libfranka: StopMove)."""
        self.ctl = None
        self.robot = None

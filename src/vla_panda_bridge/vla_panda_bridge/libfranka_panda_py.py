"""The panda-py driver (panda-python 1.1.1, bundled libfranka 0.9.2): the Panda (FER), protocol 5.

panda-py runs its controllers in a C++ thread at 1 kHz; its velocity controller `IntegratedVelocity`
integrates the commanded velocity into a joint-impedance set point and takes new values through
`set_control`. So here the loop paces itself (sleep to the next millisecond), reads the copy of the
latest state (`get_state`), raises the controller thread's errors (`raise_error`), and hands the
filtered velocity to the controller. Teaching uses panda-py's own `teaching_mode` (zero torque plus
`teaching_damping`). Between motions `read_once` of the underlying libfranka Robot paces the loop.

Not checked on hardware yet: franka-sim speaks only protocol 10, so this adapter is tested against a
fake `Panda` object with panda-py's Python API (test_libfranka_panda_py.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from vla_panda_bridge.libfranka_driver import PERIOD, DriverSettings, classify


class PandaPyDriver:
    name = "panda_py"

    def __init__(self, settings: DriverSettings, panda_factory: Callable[..., Any] | None = None,
                 controllers: Any = None, libfranka: Any = None, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        if panda_factory is None or controllers is None or libfranka is None:
            import panda_py  # optional dependency: only a real Panda needs it
            from panda_py import controllers as _controllers
            from panda_py import libfranka as _libfranka
            panda_factory = panda_factory or panda_py.Panda
            controllers = controllers or _controllers
            libfranka = libfranka or _libfranka
        self._factory = panda_factory
        self._controllers = controllers
        self._lf = libfranka
        self._clock = clock
        self._sleep = sleep
        self.settings = settings
        self.panda = None
        self._ctrl = None
        self._teaching = False
        self._next = 0.0
        self._last_t: float | None = None
        self._dq = np.zeros(7)

    def connect(self) -> None:
        s, lf = self.settings, self._lf
        rt = lf.RealtimeConfig.kEnforce if s.realtime == "enforce" else lf.RealtimeConfig.kIgnore
        try:
            self.panda = self._factory(s.robot_ip, realtime_config=rt)
            robot = self.panda.get_robot()
            robot.set_collision_behavior(list(s.lower_torque_thresholds), list(s.upper_torque_thresholds),
                                         list(s.lower_force_thresholds), list(s.upper_force_thresholds))
            robot.set_joint_impedance(list(s.joint_impedance))
        except Exception as exc:
            self.panda = None
            raise classify(exc, during_motion=False) from exc

    def read_idle(self):
        try:
            return self.panda.get_robot().read_once()
        except Exception as exc:
            raise classify(exc, during_motion=False) from exc

    def start_velocity(self) -> None:
        try:
            self._ctrl = self._controllers.IntegratedVelocity()
            self.panda.start_controller(self._ctrl)
        except Exception as exc:
            self._ctrl = None
            raise classify(exc, during_motion=False) from exc
        self._start_pacing()

    def start_torque(self) -> None:
        try:
            self.panda.teaching_mode(True, damping=np.asarray(self.settings.teaching_damping, dtype=float))
        except Exception as exc:
            raise classify(exc, during_motion=False) from exc
        self._teaching = True
        self._start_pacing()

    def _start_pacing(self) -> None:
        self._next = self._clock()
        self._last_t = None

    def read_cycle(self):
        """Wait for the next millisecond, then the latest state and the robot time since the last one."""
        self._next += PERIOD
        delay = self._next - self._clock()
        if delay > 0.0:
            self._sleep(delay)
        else:
            self._next = self._clock()           # fell behind: do not try to catch up in a burst
        try:
            self.panda.raise_error()             # errors of panda-py's controller thread surface here
            state = self.panda.get_state()
        except Exception as exc:
            self._stop_quietly()
            raise classify(exc, during_motion=True) from exc
        t = state.time.to_sec()
        dt = PERIOD if self._last_t is None else max(0.0, t - self._last_t)
        self._last_t = t
        return state, dt

    def write_velocity(self, dq: Sequence[float], finished: bool) -> None:
        self._dq[:] = dq
        try:
            self._ctrl.set_control(self._dq)
            if finished:
                self.panda.stop_controller()
                self._ctrl = None
        except Exception as exc:
            self._stop_quietly()
            raise classify(exc, during_motion=True) from exc

    def gap_reference(self, v, a, cycles: int):
        """panda-py's controller thread holds the last velocity it was given."""
        return list(v), [0.0] * len(v)

    def write_torque(self, tau: Sequence[float], finished: bool) -> None:
        """panda-py's teaching mode applies zero torque plus its damping itself; `tau` is not sent."""
        if not finished:
            return
        try:
            self.panda.teaching_mode(False)
        except Exception as exc:
            raise classify(exc, during_motion=True) from exc
        finally:
            self._teaching = False

    def recover(self) -> None:
        self._stop_quietly()
        try:
            self.panda.recover()
        except Exception as exc:
            raise classify(exc, during_motion=False) from exc

    def close(self) -> None:
        self._stop_quietly()
        self.panda = None

    def _stop_quietly(self) -> None:
        """Stop panda-py's controller thread (or teaching) if one runs; errors here change nothing."""
        if self.panda is None:
            return
        try:
            if self._ctrl is not None:
                self.panda.stop_controller()
            if self._teaching:
                self.panda.teaching_mode(False)
        except Exception:  # the connection is already gone: nothing left to stop
            pass
        self._ctrl = None
        self._teaching = False

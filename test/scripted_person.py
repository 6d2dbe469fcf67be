"""Test support: a scripted person at the stick of a study's graph (no rclpy import of its own).

From the experimenter's confirmation the person pushes the stick at full, lets go while the graph says
"return to neutral" (the controller's AWAITING_NEUTRAL, the bridge's AWAITING_ZERO), as a person does,
until they have driven `drive_s` simulated seconds, counted while the controller is ACTIVE and the bridge
moves (not e-stopped, awaiting a zero, ...): the trial's start, the e-stop's release and the return to
neutral take a time that varies with the load (a trial of 0.43 s at load 35 when the clock started at
the confirmation). Then they let go and say done. The study tests' experimenters (a simulated scene,
the real-robot mode) subclass it for their own prompts.
"""
from __future__ import annotations

import threading


def _held() -> frozenset[int]:
    from vla_interfaces.msg import SafetyStatus as S

    return frozenset({S.ESTOP, S.AWAITING_ZERO, S.COMMAND_TIMEOUT, S.INVALID_STATE, S.REFLEX, S.TEACHING})


class ScriptedPerson:
    def __init__(self, drive_s: float) -> None:
        self.drive_s, self.backend = drive_s, None
        self._stop = threading.Event()
        self._driven = 0.0          # simulated s driven (the arm moving with the stick) since start_driving
        self._last: float | None = None

    def start_driving(self) -> None:
        self._driven, self._last = 0.0, None
        self._stop.clear()
        threading.Thread(target=self._person, daemon=True).start()

    def _person(self) -> None:
        from vla_interfaces.msg import ControllerStatus, SafetyStatus

        obs, held = self.backend.ev.obs, _held()   # the bridge's states in which the stick moves nothing
        while not self._stop.wait(0.02):        # a joystick's 50 Hz
            with obs.cond:
                ctrl, safety, now = obs.ctrl, obs.safety, obs.now()
                active = (ctrl is not None and ctrl.code == ControllerStatus.ACTIVE
                          and safety is not None and safety.code not in held)
                if active and self._last is not None:
                    self._driven += max(0.0, now - self._last)
                self._last = now if active else None
                obs.cond.notify_all()
            told = ((ctrl is not None and ctrl.code == ControllerStatus.AWAITING_NEUTRAL)
                    or (safety is not None and safety.code == SafetyStatus.AWAITING_ZERO))
            obs.publish_stick(0.0 if told else 1.0)

    def drive_until_done(self, ended, limit_s: float) -> bool:
        """True when the person said done (drove drive_s simulated s) before the trial `ended`."""
        obs = self.backend.ev.obs
        with obs.cond:
            said = obs.cond.wait_for(lambda: ended() or self._driven >= self.drive_s, limit_s)
        self._stop.set()
        obs.publish_stick(0.0)                   # the person lets go
        return bool(said) and not ended()

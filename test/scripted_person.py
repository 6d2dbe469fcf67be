"""Test support: a scripted person at the stick of a study's graph (no rclpy import of its own).

From the experimenter's confirmation the person pushes the stick at full, lets go while the graph says
"return to neutral" (the controller's AWAITING_NEUTRAL, the bridge's AWAITING_ZERO), as a person does,
until they have driven `drive_s` simulated seconds; then they let go and say done. The study tests'
experimenters (a simulated scene, the real-robot mode) subclass it for their own prompts.
"""
from __future__ import annotations

import threading


class ScriptedPerson:
    def __init__(self, drive_s: float) -> None:
        self.drive_s, self.backend = drive_s, None
        self._stop = threading.Event()
        self._t0 = None

    def start_driving(self) -> None:
        self._t0 = self.backend.ev.obs.now()
        self._stop.clear()
        threading.Thread(target=self._person, daemon=True).start()

    def _person(self) -> None:
        from vla_interfaces.msg import ControllerStatus, SafetyStatus

        obs = self.backend.ev.obs
        while not self._stop.wait(0.02):        # a joystick's 50 Hz
            with obs.cond:
                ctrl, safety = obs.ctrl, obs.safety
            told = ((ctrl is not None and ctrl.code == ControllerStatus.AWAITING_NEUTRAL)
                    or (safety is not None and safety.code == SafetyStatus.AWAITING_ZERO))
            obs.publish_stick(0.0 if told else 1.0)

    def drive_until_done(self, ended, limit_s: float) -> bool:
        """True when the person said done (drove drive_s simulated s) before the trial `ended`."""
        obs = self.backend.ev.obs
        with obs.cond:
            said = obs.cond.wait_for(lambda: ended() or obs.now() - self._t0 >= self.drive_s, limit_s)
        self._stop.set()
        obs.publish_stick(0.0)                   # the person lets go
        return bool(said) and not ended()

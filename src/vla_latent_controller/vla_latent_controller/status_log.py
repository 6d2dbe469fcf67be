"""At which level the controller logs a change of its status code (plain Python, no rclpy).

A routine code (the input stopped, the arm's states have not arrived yet, the enable button let go,
back to neutral to move again ...) is said once at INFO, the first time the controller enters it;
entering it again is DEBUG. Over 20 minutes of a person driving through the operator station, every
release of a key gave a JOY_TIMEOUT or AWAITING_NEUTRAL line and every lag of the simulation a
WAITING_FOR_JOINT_STATES line: 358 INFO lines in which the rare ones that matter were lost (and the 2 s
throttle of that one log call dropped whichever came second). A problem (bad input, a model error) is
said each time, at most every 2 s; moving (ACTIVE, ZERO_DEADBAND) not at all. The status topic still
carries every change.
"""
from __future__ import annotations

from vla_latent_controller.teleop import Code

ROUTINE = frozenset({Code.WAITING_FOR_JOY, Code.JOY_TIMEOUT, Code.WAITING_FOR_JOINT_STATES,
                     Code.WAITING_FOR_DETECTION, Code.DEADMAN_RELEASED, Code.AWAITING_NEUTRAL})
SILENT = frozenset({Code.ACTIVE, Code.ZERO_DEADBAND})


class StatusLog:
    """Remembers which routine codes were said; `level(code)` for each change of code."""

    def __init__(self) -> None:
        self._said: set[Code] = set()

    def level(self, code: Code) -> str | None:
        """"info" (said once), "problem" (INFO, throttled), "debug", or None (not logged) for
        entering `code`."""
        if code in SILENT:
            return None
        if code not in ROUTINE:
            return "problem"
        if code in self._said:
            return "debug"
        self._said.add(code)
        return "info"

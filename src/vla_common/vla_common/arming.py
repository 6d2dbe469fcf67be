"""The arming rule, written once: after a stop the operator did not choose, motion needs a neutral first.

A stop the operator did not choose is anything that zeroes motion without the operator's say: an
e-stop (latched or released), a watchdog (a command or input timeout), an invalid or silent robot
state, a reflex, a recovery, teaching mode, a lost connection. After any of them the arm must not
move again until the operator has returned to neutral, even if the input they hold never changed.

Two layers hold one `Arming` each, and together they make the rule hold end to end:
- the controller (which knows the operator's input) re-arms only on the operator's neutral: the
  stick inside its deadband or a released deadman. Every other zero it sends (input late, no joint
  states, no context, bad input) disarms it;
- the bridge (which knows the robot's stops) re-arms only on a zero command, and ignores non-zero
  commands until then.
So the bridge re-arms on a zero that is either the operator's neutral, or a controller stop, after
which the controller itself sends nothing but zero until the operator's neutral. A stick held through
any stop, with any gaps in its input, cannot move the arm.

Plain Python, no ROS: the bridge's safety filter, the 1 kHz libfranka loop (through that filter) and
the controller's core use it.
"""
from __future__ import annotations


class Arming:
    """Armed or waiting for a neutral input; `reason` says which stop disarmed it ("" when armed)."""

    def __init__(self, armed: bool = True, reason: str = "not yet at neutral"):
        self._reason = "" if armed else reason

    @property
    def armed(self) -> bool:
        return not self._reason

    @property
    def reason(self) -> str:
        """The stop that disarmed it, in words ("" when armed)."""
        return self._reason

    def disarm(self, why: str) -> None:
        """A stop the operator did not choose happened: motion waits for a neutral input. The first
        reason is kept while disarmed (it is what the operator must know: why it stopped)."""
        if not self._reason:
            self._reason = why or "stopped"

    def offer(self, neutral: bool) -> bool:
        """An input arrives; `neutral` says it is the re-arming kind (the operator's neutral at the
        controller, a zero command at the bridge). Returns whether motion may follow it."""
        if neutral:
            self._reason = ""
        return not self._reason

"""Status codes in words for the page (status in words, not only in colour). The codes are the
messages' constants (vla_interfaces ControllerStatus and SafetyStatus); no rclpy here."""
from __future__ import annotations

CONTROLLER = {
    0: "Moving with your input",
    1: "Ready: input at neutral",
    2: "Waiting for input",
    3: "Input stopped arriving: stopped",
    4: "Waiting for the arm's joint states",
    5: "Waiting to see the object",
    6: "Input not usable: stopped",
    7: "Enable button released: stopped",
    8: "Model problem: stopped",
    9: "Stopped: let go of the input (back to neutral) to move again",
}
SAFETY = {
    0: "Safety OK",
    1: "Bad command (not a number): stopped",
    2: "Bad command (wrong length): stopped",
    3: "Speed limited",
    4: "Acceleration limited",
    5: "Near a joint limit: slowed",
    6: "Commands stopped arriving: braking",
    7: "EMERGENCY STOP latched",
    8: "Arm state not valid: braking",
    9: "Implausible command: stopped",
    10: "The robot stopped itself (reflex): needs recovery",
    11: "Teaching mode: the arm can be moved by hand",
    12: "Waiting for a zero command before moving",
    13: "Contact: slowed",
}


def controller_words(code: int) -> str:
    return CONTROLLER.get(code, f"Controller code {code}")


def safety_words(code: int) -> str:
    return SAFETY.get(code, f"Safety code {code}")

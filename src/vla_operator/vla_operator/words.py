"""Status codes in words for the page (status in words, not only in colour). The codes are the
messages' constants (vla_interfaces ControllerStatus; SafetyStatus's are vla_common's SafetyCode); no
rclpy here."""
from __future__ import annotations

from vla_common.safety_status import SafetyCode

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
    SafetyCode.OK: "Safety OK",
    SafetyCode.NON_FINITE_COMMAND: "Bad command (not a number): stopped",
    SafetyCode.WRONG_LENGTH: "Bad command (wrong length): stopped",
    SafetyCode.VELOCITY_SCALED: "Speed limited",
    SafetyCode.ACCELERATION_LIMITED: "Acceleration limited",
    SafetyCode.POSITION_MARGIN: "Near a joint limit: slowed",
    SafetyCode.COMMAND_TIMEOUT: "Commands stopped arriving: braking",
    SafetyCode.ESTOP: "EMERGENCY STOP latched",
    SafetyCode.INVALID_STATE: "Arm state not valid: braking",
    SafetyCode.IMPLAUSIBLE_COMMAND: "Implausible command: stopped",
    SafetyCode.REFLEX: "The robot stopped itself (reflex): needs recovery",
    SafetyCode.TEACHING: "Teaching mode: the arm can be moved by hand",
    SafetyCode.AWAITING_ZERO: "Waiting for a zero command before moving",
    SafetyCode.CONTACT: "Contact: slowed",
    SafetyCode.WORKSPACE: "Near the table: lowering slowed",
}


def controller_words(code: int) -> str:
    return CONTROLLER.get(code, f"Controller code {code}")


def safety_words(code: int) -> str:
    return SAFETY.get(code, f"Safety code {code}")

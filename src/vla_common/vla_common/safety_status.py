"""The bridge's safety status codes, one home: the constants of vla_interfaces/msg/SafetyStatus as an
enum (plain Python, so the safety layer needs no ROS; a test checks that the two agree). The safety
filter (vla_panda_bridge.safety) and the bridge give them, the operator station says them in words
(vla_operator.words), the evaluation counts them by name."""
from __future__ import annotations

import enum


class SafetyCode(enum.IntEnum):
    """What the safety layer does to the commands now (see SafetyStatus.msg for each)."""

    OK = 0
    NON_FINITE_COMMAND = 1
    WRONG_LENGTH = 2
    VELOCITY_SCALED = 3
    ACCELERATION_LIMITED = 4
    POSITION_MARGIN = 5
    COMMAND_TIMEOUT = 6
    ESTOP = 7
    INVALID_STATE = 8
    IMPLAUSIBLE_COMMAND = 9
    REFLEX = 10
    TEACHING = 11
    AWAITING_ZERO = 12
    CONTACT = 13
    WORKSPACE = 14


def code_name(code: int) -> str:
    """The code's name ("ESTOP"), or the number for a code this version does not know."""
    try:
        return SafetyCode(int(code)).name
    except ValueError:
        return str(code)

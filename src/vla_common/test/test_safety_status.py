"""The safety status codes: one enum, the same constants as vla_interfaces/msg/SafetyStatus."""
from vla_common.safety_status import SafetyCode, code_name

from vla_interfaces.msg import SafetyStatus


def test_the_enum_and_the_message_have_the_same_constants():
    constants = {name: getattr(SafetyStatus, name) for name in dir(SafetyStatus)
                 if name.isupper() and isinstance(getattr(SafetyStatus, name), int)}
    assert constants == {c.name: c.value for c in SafetyCode}


def test_a_code_is_named_and_an_unknown_one_kept_as_a_number():
    assert code_name(7) == "ESTOP" and code_name(SafetyCode.WORKSPACE) == "WORKSPACE"
    assert code_name(200) == "200"

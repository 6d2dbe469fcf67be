"""Every safety status code has words for the page (WORKSPACE had none: "Safety code 14")."""
from vla_common.safety_status import SafetyCode
from vla_operator.words import safety_words


def test_every_safety_code_has_words():
    assert all(not safety_words(int(c)).startswith("Safety code") for c in SafetyCode)
    assert safety_words(14) == "Near the table: lowering slowed" and safety_words(99) == "Safety code 99"

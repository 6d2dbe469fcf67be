"""The /diagnostics helper: levels, key values as strings, the node's name, an immediate publish on a
level change and the periodic republish, received by a subscriber in another node."""
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from vla_common.ros.diagnostics import TOPIC, Diagnostics, level_of, status_message
from vla_common.ros.testing import RosHarness


def test_levels_by_name_and_number():
    assert level_of("ok") == DiagnosticStatus.OK and level_of("WARN") == DiagnosticStatus.WARN
    assert level_of(2) == DiagnosticStatus.ERROR
    assert level_of(DiagnosticStatus.STALE) == DiagnosticStatus.STALE
    for bad in ("fine", 4, -1):
        with pytest.raises(ValueError):
            level_of(bad)


def test_values_are_strings():
    s = status_message("ns/node", "panda", "warn", "late", {"age_s": 0.1234567, "code": 3, "mode": "latent"})
    assert (s.name, s.hardware_id, s.level, s.message) == ("ns/node", "panda", DiagnosticStatus.WARN, "late")
    assert {kv.key: kv.value for kv in s.values} == {"age_s": "0.123457", "code": "3", "mode": "latent"}


def test_published_on_diagnostics_from_a_namespaced_node():
    h = RosHarness()
    try:
        node = h.add(Node("talker", namespace="/robot1", context=h.context))
        diag = Diagnostics(node, hardware_id="sim", period=0.2)
        got: list[DiagnosticArray] = []
        listener = h.add(Node("listener", context=h.context))
        listener.create_subscription(DiagnosticArray, TOPIC, got.append, 10)
        assert h.spin_until(lambda: node.count_subscribers(TOPIC) == 1)
        assert h.spin_until(lambda: got), "the periodic publish never came"
        assert got[-1].status[0].name == "robot1/talker" and got[-1].status[0].message == "starting"
        n = len(got)
        diag.update("error", "arm stopped", reflex="cartesian_reflex")
        assert h.spin_until(lambda: any(a.status[0].level == DiagnosticStatus.ERROR for a in got[n:]))
        last = got[-1].status[0]
        assert last.message == "arm stopped" and last.hardware_id == "sim"
        assert [(kv.key, kv.value) for kv in last.values] == [("reflex", "cartesian_reflex")]
        assert got[-1].header.stamp.sec > 0
    finally:
        h.shutdown()

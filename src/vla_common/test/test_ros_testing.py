"""RosHarness: its shutdown may be called twice (a test that ends its node early, then its fixture)."""
from __future__ import annotations

import pytest
from vla_common.ros.testing import RosHarness

pytestmark = pytest.mark.ros


def test_shutdown_twice_is_harmless():
    import rclpy

    h = RosHarness()
    node = h.add(rclpy.create_node("harness_probe", context=h.context))
    assert node.context.ok()
    h.shutdown()
    assert not h.context.ok()
    h.shutdown()          # before: rclpy.shutdown raised on the context already shut down

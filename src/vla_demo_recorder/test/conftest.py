"""Fixtures of the recorder tests: a private rclpy context, hand-made bag helpers on sys.path."""
import sys
from pathlib import Path

import pytest
from vla_common.ros.testing import RosHarness

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def ros():
    harness = RosHarness()
    yield harness
    harness.shutdown()

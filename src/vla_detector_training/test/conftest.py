"""Fixtures of the detector-training tests: the drawn datasets on sys.path, a private rclpy context."""

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

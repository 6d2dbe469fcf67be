"""Fixtures of the recorder tests: a private rclpy context (`ros`: its own nodes only;
`ros_processes`: also the recorder processes a test starts), hand-made bag helpers on sys.path."""
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


@pytest.fixture
def ros_processes():
    harness = RosHarness(other_processes=True)
    yield harness
    harness.shutdown()

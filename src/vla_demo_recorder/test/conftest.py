"""Fixtures of the recorder tests: a private rclpy context, hand-made bag helpers on sys.path."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from recorder_testing import RosHarness  # noqa: E402


@pytest.fixture
def ros():
    harness = RosHarness()
    yield harness
    harness.shutdown()

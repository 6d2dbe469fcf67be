"""Test-run isolation: every pytest run gets its own ROS domain and localhost-only discovery.

Set before any rclpy context exists, and inherited by every node process a test starts, so two
concurrent runs on one machine never see each other's topics.
"""
import os
import sys
from pathlib import Path

# test/ holds helpers the top-level tests import (package_deps, ...).
sys.path.insert(0, str(Path(__file__).parent / "test"))

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_configure(config):
    from vla_common.ros.domain import isolate

    os.environ.pop("ROS_DOMAIN_ID", None)  # a run of its own, not the shell's graph
    fixed = os.environ.get("VLA_TEST_DOMAIN_ID")
    isolate(domain=int(fixed) if fixed else None)
    os.environ["RCUTILS_COLORIZED_OUTPUT"] = "0"

"""Test-run isolation: every pytest run gets its own ROS domain and localhost-only discovery.

Set before any rclpy context exists, and inherited by every node process a test starts, so two
concurrent runs on one machine never see each other's topics.
"""
import os
import random
import sys
from pathlib import Path

# test/ holds helpers the top-level tests import (package_deps, ...).
sys.path.insert(0, str(Path(__file__).parent / "test"))

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_configure(config):
    if "VLA_TEST_DOMAIN_ID" in os.environ:
        domain = int(os.environ["VLA_TEST_DOMAIN_ID"])
    else:
        # Fast DDS allows 0..232; keep clear of 0 (the default) and of the well-known low ids.
        domain = random.SystemRandom().randint(30, 200)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ["RCUTILS_COLORIZED_OUTPUT"] = "0"

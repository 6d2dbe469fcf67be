"""Test-run isolation: every pytest run gets its own ROS domain and localhost-only discovery.

Set before any rclpy context exists, and inherited by every node process a test starts, so two
concurrent runs on one machine never see each other's topics.
"""
import faulthandler
import os
import sys
from pathlib import Path

import pytest

# test/ holds helpers the top-level tests import (package_deps, ...).
sys.path.insert(0, str(Path(__file__).parent / "test"))

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_configure(config):
    from vla_common.ros.domain import isolate

    os.environ.pop("ROS_DOMAIN_ID", None)  # a run of its own, not the shell's graph
    fixed = os.environ.get("VLA_TEST_DOMAIN_ID")
    isolate(domain=int(fixed) if fixed else None)
    os.environ["RCUTILS_COLORIZED_OUTPUT"] = "0"


# pytest-timeout's SIGALRM cannot interrupt a thread blocked in C (a Fast DDS deadlock in CI sat
# there until the job's own limit, with no word of where): past a test's timeout and this margin,
# print every thread's stack and end the run (a red run with the stacks, not a silent one).
HANG_MARGIN_S = float(os.environ.get("VLA_TEST_HANG_MARGIN_S", "120"))
_HANG_FILE = None


def _test_timeout(item) -> float:
    marker = item.get_closest_marker("timeout")
    if marker is not None and marker.args:
        return float(marker.args[0])
    return float(item.config.getoption("timeout", default=0) or 0)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    global _HANG_FILE
    timeout = _test_timeout(item)
    if timeout <= 0:
        yield
        return
    if _HANG_FILE is None:  # the terminal's stderr, not the captured one; kept for the run
        _HANG_FILE = os.fdopen(os.dup(2), "w")
    faulthandler.dump_traceback_later(timeout + HANG_MARGIN_S, exit=True, file=_HANG_FILE)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()

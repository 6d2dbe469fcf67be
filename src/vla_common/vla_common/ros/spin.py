"""Spinning until a condition holds, in one place: the test harness, the command-line tools and the
discovery check wait on what they expect instead of sleeping. `spin_once(seconds)` is an executor's
or rclpy's own, so the same loop serves both."""
from __future__ import annotations

import time
from collections.abc import Callable

SLICE_S = 0.02   # s: each spin waits at most this long for work, so the condition is seen soon after


def spin_until(spin_once: Callable[[float], object], condition: Callable[[], bool], timeout: float,
               slice_s: float = SLICE_S) -> bool:
    """Spin in slices until `condition()` is true (True) or `timeout` s have passed (False)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() >= deadline:
            return False
        spin_once(slice_s)
    return True

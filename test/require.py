"""Skip here, fail in CI: one rule for a test that cannot run on this machine.

A developer's machine may lack what a test needs (a network namespace, franka-sim, an installed
workspace); the test then skips, saying what is missing. A machine that promises it (CI: `.ci/run`
sets `VLA_REQUIRE_<WHAT>=1`) fails instead, so a missing install step can never pass as a skip.
"""
from __future__ import annotations

import os
from typing import NoReturn

import pytest

KINDS = ("SETUP", "NETNS", "FRANKA_SIM", "TMPFS", "RENDER", "BROWSER")


def required(what: str) -> bool:
    """Whether this machine promises `what` (one of KINDS)."""
    if what not in KINDS:
        raise ValueError(f"unknown requirement {what!r}; one of {KINDS}")
    return os.environ.get(f"VLA_REQUIRE_{what}") == "1"


def missing(what: str, reason: str) -> NoReturn:
    """Skip with `reason`, or fail where VLA_REQUIRE_<what>=1."""
    if required(what):
        pytest.fail(f"{reason} (VLA_REQUIRE_{what}=1: this machine must run it)")
    pytest.skip(reason)

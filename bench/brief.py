"""The benchmarks' brief mode: `VLA_BENCH_BRIEF=1` (`make bench BENCH_BRIEF=1`; CI runs every benchmark
so) gives each one a few samples, so that a benchmark that no longer runs is seen at once (issue 32:
three of them failed as shipped and nobody saw). A brief run checks that the benchmark runs; its
figures are not figures to report.

Every `bench/bench_*.py` parses its arguments with :func:`parse` (test/test_benchmarks.py checks it).
"""
from __future__ import annotations

import argparse
import os
import sys

ENV = "VLA_BENCH_BRIEF"


def brief() -> bool:
    """Whether this run is a brief one."""
    return os.environ.get(ENV, "0") not in ("", "0")


def parse(ap: argparse.ArgumentParser, argv: list[str] | None = None, **short) -> argparse.Namespace:
    """`ap.parse_args(argv)`; in brief mode `short` (argument dests) are the defaults: arguments given
    on the command line still win."""
    if brief():
        ap.set_defaults(**short)
        said = ", ".join(f"{k}={v}" for k, v in short.items())
        # on stderr: a benchmark's child processes (bench_detector's roles) answer on stdout
        print(f"[{ENV}=1] a brief run ({said}): it checks that the benchmark runs; the figures are not "
              "ones to report", file=sys.stderr, flush=True)
    return ap.parse_args(argv)


def skipped(what: str, reason: str) -> int:
    """A benchmark that cannot run on this machine: say why; the exit status is 1 where the machine
    promises `what` (`VLA_REQUIRE_<what>=1`, as CI sets it for the tests: test/require.py), else 0."""
    required = os.environ.get(f"VLA_REQUIRE_{what}") == "1"
    print(f"skipped: {reason}" + (f" (VLA_REQUIRE_{what}=1: this machine must run it)" if required else ""))
    return 1 if required else 0

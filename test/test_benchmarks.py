"""Every benchmark has a brief mode (issue 32: three benchmarks failed as shipped and nothing saw it).
CI runs each one briefly (`.ci/run`: `make bench BENCH_BRIEF=1`); this checks, fast, that none was
added without it: each parses its arguments with bench/brief.py's `parse`, which honours
VLA_BENCH_BRIEF=1."""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_every_benchmark_parses_its_arguments_with_the_brief_mode():
    missing = []
    for f in sorted(BENCH.glob("bench_*.py")):
        calls = [n for n in ast.walk(ast.parse(f.read_text())) if isinstance(n, ast.Call)]
        parses = [c for c in calls if isinstance(c.func, ast.Name) and c.func.id == "parse"]
        own = [c for c in calls if isinstance(c.func, ast.Attribute) and c.func.attr == "parse_args"]
        if not parses or own:
            missing.append(f.name)
    assert missing == [], f"benchmarks without the brief mode (bench/brief.py parse): {missing}"


def test_the_brief_mode_gives_the_brief_defaults_and_arguments_still_win(tmp_path):
    script = tmp_path / "b.py"
    script.write_text("import argparse, sys\nsys.path.insert(0, sys.argv[1])\nfrom brief import parse\n"
                      "ap = argparse.ArgumentParser(); ap.add_argument('--n', type=int, default=100)\n"
                      "print(parse(ap, sys.argv[2:], n=3).n)\n")
    run = lambda env, *args: subprocess.run(  # noqa: E731
        [sys.executable, str(script), str(BENCH), *args], capture_output=True, text=True, check=True,
        env={**os.environ, "VLA_BENCH_BRIEF": env}).stdout.splitlines()[-1]
    assert run("0") == "100" and run("1") == "3" and run("1", "--n", "7") == "7"

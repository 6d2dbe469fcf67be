"""A program with subcommands, each a module: the shape of the CLIs whose subcommands are many and
heavy (vla_evaluation, vla_latent_training); the small CLIs are a single argparse module.

A subcommand module exposes `add_arguments(parser)` and `run(args) -> int`. Every module is imported
when the parser is built (for its arguments); modules keep heavy optional dependencies (torch,
MuJoCo) inside `run`, so `--help` stays light.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

Subcommand = tuple[str, str, str]  # (name, module, one-line help)


def build_parser(prog: str, description: str, subcommands: Sequence[Subcommand]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module, text in subcommands:
        p = sub.add_parser(name, help=text, description=text)
        mod = importlib.import_module(module)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def run_cli(prog: str, description: str, subcommands: Sequence[Subcommand],
            argv: list[str] | None = None) -> int:
    """Parse `argv` and run the chosen subcommand; 130 on Ctrl-C (no traceback)."""
    args = build_parser(prog, description, subcommands).parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130

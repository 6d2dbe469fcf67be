"""`vla_latent_controller` command line: one subcommand per module.

Each subcommand module exposes `add_arguments(parser)` and `run(args) -> int` and is imported only when
its subcommand runs (so `--help` and light commands never import torch).
"""

from __future__ import annotations

import argparse
import importlib
import sys

# (name, module, one-line help). Add a subcommand by adding a row.
SUBCOMMANDS: list[tuple[str, str, str]] = [
    ("train", "vla_latent_controller.train_cli", "train a latent-action model from demonstration bags"),
    (
        "evaluate",
        "vla_latent_controller.evaluation.cli",
        "closed-loop evaluation with the simulated teleoperator (kinematic or full graph)",
    ),
    (
        "experiments",
        "vla_latent_controller.experiments",
        "the paper's simulation experiments (Figure 2a and 2c) into docs/results/",
    ),
    (
        "demo",
        "vla_latent_controller.demo",
        "the main job: the graph on the simulated Panda with the shipped models, table + video",
    ),
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vla_latent_controller", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module, text in SUBCOMMANDS:
        p = sub.add_parser(name, help=text, description=text)
        mod = importlib.import_module(module)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

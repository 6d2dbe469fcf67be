"""`vla_evaluation` command line: demonstrations, closed-loop evaluation, the experiments, the demo."""

from __future__ import annotations

import argparse
import sys

from vla_common.cli import Subcommand, run_cli
from vla_common.cli import build_parser as _build_parser

SUBCOMMANDS: list[Subcommand] = [
    ("generate", "vla_evaluation.generate",
     "scripted kinesthetic demonstrations through the ROS graph, recorded to bags"),
    ("evaluate", "vla_evaluation.evaluate_cli",
     "closed-loop evaluation with the simulated teleoperator (kinematic, physics or the full graph)"),
    ("experiments", "vla_evaluation.experiments",
     "the paper's simulation experiments (Figure 2a and 2c) into docs/results/"),
    ("demo", "vla_evaluation.demo",
     "the main job: the graph on the simulated Panda with the shipped models, table + video"),
    ("new-object", "vla_evaluation.new_object",
     "teach the robot a new object end to end in simulation (detector, demos, model) and measure it"),
]


def build_parser() -> argparse.ArgumentParser:
    return _build_parser("vla_evaluation", __doc__.splitlines()[0], SUBCOMMANDS)


def main(argv: list[str] | None = None) -> int:
    return run_cli("vla_evaluation", __doc__.splitlines()[0], SUBCOMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())

"""`vla_latent_training` command line: train a latent-action model, inspect the pairs bags give."""

from __future__ import annotations

import sys

from vla_common.cli import Subcommand, run_cli

SUBCOMMANDS: list[Subcommand] = [
    ("train", "vla_latent_training.train_cli", "train a latent-action model from demonstration bags"),
    ("pairs", "vla_latent_training.pairs_cli", "load demonstration bags and report the training pairs"),
    ("calibrate", "vla_latent_training.calibrate_cli",
     "re-calibrate a trained model's latent (what full stick means) without refitting it"),
]


def main(argv: list[str] | None = None) -> int:
    return run_cli("vla_latent_training", __doc__.splitlines()[0], SUBCOMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())

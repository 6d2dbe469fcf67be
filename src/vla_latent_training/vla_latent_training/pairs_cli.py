"""`vla_latent_training pairs`: what training pairs a set of bags gives, and which bags are skipped."""

from __future__ import annotations

import argparse

import numpy as np
from vla_demo_recorder.dataset import load_demos

from vla_latent_training.pairs import make_pairs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", help="bag folders or folders of bags")
    p.add_argument("--require", choices=("image", "detection"), default=None)
    p.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    demos, skipped = load_demos(args.paths, require=args.require)
    for path, reason in skipped:
        print(f"skipped {path}: {reason}")
    rng = np.random.default_rng(args.seed)
    total = 0
    for demo in demos:
        q_noisy, _ = make_pairs(demo, rng)
        total += len(q_noisy)
        print(f"{demo.bag_path}: {demo.task}, {len(demo.t)} samples at 10 Hz, {len(q_noisy)} pairs, "
              f"image {'yes' if demo.first_image is not None else 'no'}, "
              f"detection {demo.detection['class_id'] if demo.detection else 'no'}")
    print(f"{len(demos)} demos, {len(skipped)} skipped, {total} pairs")
    return 0 if demos else 1

"""`vla_latent_training pairs`: what training pairs a set of bags gives, and which bags are skipped."""

from __future__ import annotations

import argparse
import sys

import numpy as np
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_demo_recorder.dataset import load_demos

from vla_latent_training.pairs import make_pairs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", help="bag folders or folders of bags")
    p.add_argument("--require", choices=("image", "detection"), default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--task", default=None, help="the task of bags without episode metadata (ros2 bag record)")
    p.add_argument("--catalogue", default=None, help="where --task is defined (default: vla_common's)")
    p.add_argument("--include-incomplete", action="store_true",
                   help="also recovered and interrupted episodes (as `train --include-incomplete`)")


def run(args: argparse.Namespace) -> int:
    try:
        task = load_catalogue(args.catalogue).task(args.task).name if args.task else None
    except (CatalogueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    demos, skipped = load_demos(args.paths, require=args.require, task=task,
                                include_incomplete=args.include_incomplete)
    for path, reason in skipped:
        print(f"skipped {path}: {reason}")
    rng = np.random.default_rng(args.seed)
    total = 0
    for demo in demos:
        q_noisy, _ = make_pairs(demo, rng)
        total += len(q_noisy)
        print(f"{demo.bag_path}: {demo.task}, {len(demo.t)} samples at 10 Hz, {len(q_noisy)} pairs, "
              f"image {'yes' if demo.first_image is not None else 'no'}, "
              f"detection {demo.detection.class_id if demo.detection else 'no'}")
    print(f"{len(demos)} demos, {len(skipped)} skipped, {total} pairs")
    if not demos and not skipped:
        print(f"no bags in {' '.join(args.paths)} (a folder is searched one level deep for bag folders)")
    return 0 if demos else 1

"""`vla_latent_training calibrate`: re-calibrate a trained model's latent (what full stick means) from
demonstration bags, without refitting its networks.

Example:
    vla_latent_training calibrate --model src/vla_latent_controller/models/default \\
        --bags out/data/demos/* --out out/model_recalibrated
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vla_demo_recorder.dataset import load_demos
from vla_latent_controller.artifacts import ModelError

from vla_latent_training.config import TrainConfig
from vla_latent_training.train_cli import _detector

_DEFAULT = TrainConfig()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, type=Path, help="trained model directory (detector encoder)")
    p.add_argument("--bags", nargs="+", required=True,
                   help="the model's demonstration bags (bag folders, .mcap files, or folders of bags)")
    p.add_argument("--out", required=True, type=Path, help="output model directory (may be --model)")
    p.add_argument("--gain-percentile", type=float, default=_DEFAULT.gain_percentile,
                   help="full stick = this percentile of the demonstrated pairs' |z|, per class "
                        f"(default: {_DEFAULT.gain_percentile:g})")
    p.add_argument("--detector-model", default=None,
                   help="ONNX detector run on a demo's first image when the bag has no recorded detection")


def run(args: argparse.Namespace) -> int:
    from vla_latent_training.recalibrate import recalibrate_model  # torch: only when it runs

    demos, skipped = load_demos(args.bags)
    for path, reason in skipped:
        print(f"skipped {path}: {reason}", file=sys.stderr)
    if not demos:
        print(f"error: no usable demonstrations in {' '.join(args.bags)}", file=sys.stderr)
        return 1
    try:
        detector = _detector(args.detector_model, any(d.detection is None for d in demos))
        out = recalibrate_model(args.model, demos, args.out, args.gain_percentile, detector=detector)
    except (ValueError, ModelError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"saved {out}/")
    return 0


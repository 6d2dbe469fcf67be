"""`vla_latent_training train`: learn a latent-action model from recorded demonstration bags.

Example:
    vla_latent_training train --bags demos/ --encoder detector --out model/
    vla_latent_training train --bags demos/ --encoder detector --paper-exact --seed 3 --out model_paper/
    vla_latent_training train --bags recorded/ --task bread/push_east --out model/   # `ros2 bag record` bags
    vla_latent_training train --bags base/ new/ --default-task cereal_box/push_south --out model/  # transfer
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from vla_common.catalogue import Catalogue, CatalogueError, load_catalogue
from vla_demo_recorder.dataset import INCOMPLETE_OUTCOMES, load_demos
from vla_detector.inference import Detector, default_model_path
from vla_latent_controller.context import ENCODERS

from vla_latent_training.config import TrainConfig, check_position_scale

# The recipe's defaults, declared once in TrainConfig; the options below only show them.
_DEFAULT, _PAPER = TrainConfig(), TrainConfig.paper()


def position_scale_arg(text: str) -> float | None:
    """--position-scale: 'demos' (None: the demos' spread) or a positive number."""
    if text == "demos":
        return None
    try:
        v = float(text)
        check_position_scale(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'demos' or a positive number, got {text!r}") from None
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bags", nargs="+", required=True, help="bag folders, .mcap files, or folders of bags")
    p.add_argument("--encoder", choices=ENCODERS, default=_DEFAULT.encoder, help="context encoder")
    p.add_argument(
        "--detector-model",
        default=None,
        help="ONNX detector run on a demo's first image when the bag has no recorded detection "
        "(default: the shipped model, if installed)",
    )
    p.add_argument("--out", required=True, type=Path, help="output model directory")
    p.add_argument("--seed", type=int, default=_DEFAULT.seed, help=f"default: {_DEFAULT.seed}")
    p.add_argument("--epochs", type=int, default=_DEFAULT.epochs,
                   help=f"default: {_DEFAULT.epochs}; the paper: {_PAPER.epochs}")
    p.add_argument("--batch-size", type=int, default=_DEFAULT.batch_size,
                   help=f"default: {_DEFAULT.batch_size}; the paper: {_PAPER.batch_size} (near full batch)")
    p.add_argument("--lr", type=float, default=_DEFAULT.lr,
                   help=f"Adam learning rate; default: {_DEFAULT.lr}; the paper: {_PAPER.lr}")
    p.add_argument("--hidden", type=int, default=None,
                   help=f"units per hidden layer (default: {_DEFAULT.hidden}; the paper and --paper-exact: "
                        f"{_PAPER.hidden})")
    default_scale = "demos" if _DEFAULT.position_scale is None else str(_DEFAULT.position_scale)
    p.add_argument("--position-scale", type=position_scale_arg, default=default_scale,
                   help=f"what the detector context's (x, y) are divided by (default: {default_scale}): "
                        "'demos' (their "
                        "spread over the demos) or a number (0.2887 = sqrt(1/12), a coordinate's spread "
                        "over the image; quieter position, for 1-2 demos per object)")
    p.add_argument("--rest-samples", type=int, default=_DEFAULT.rest_samples,
                   help="hold each demonstration at its last state for N more samples (10 Hz), so that a "
                        "held stick stops where the task ends (default: %(default)s)")
    p.add_argument("--corrective-copies", type=int, default=_DEFAULT.corrective_copies,
                   help="K copies of every pair from a perturbed state, leading back to the same point "
                        "(DART-like corrections; default: %(default)s)")
    p.add_argument("--corrective-sigma", type=float, default=_DEFAULT.corrective_sigma,
                   help="their perturbation per joint (rad; default: %(default)s)")
    p.add_argument(
        "--paper-exact",
        action="store_true",
        help="reproduce the paper's code: no z=0 term, unbounded latent, raw units, no reversed pairs",
    )
    p.add_argument("--task", action="append", default=None,
                   help="only demos of this task (repeatable); a single --task is also the task of bags "
                        "without episode metadata (`ros2 bag record` output)")
    p.add_argument("--default-task", default=None,
                   help="the task of bags without episode metadata when they are mixed with recorded "
                        "episodes of other tasks (the paper's transfer: --bags base/ new/)")
    p.add_argument("--catalogue", default=None,
                   help="object classes and tasks (a catalogue YAML; default: vla_common's)")
    p.add_argument("--max-per-task", type=int, default=0, help="keep at most N demos per task (0: all)")
    p.add_argument("--include-incomplete", action="store_true",
                   help="also train on episodes whose outcome is recovered (a file cut short, made "
                        "readable by `vla_demo_recorder recover`) or interrupted; left out by default, "
                        "since they may end before the task did")
    p.add_argument(
        "--threads", type=int, default=1, help="torch threads (1 is fastest on a busy 2-core machine)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _detector(path: str | None, needed: bool) -> Detector | None:
    """A vla_detector Detector from `path`, the shipped model when needed and available, else None."""
    if path is None:
        if not needed:
            return None
        p = default_model_path()
        if not p.is_file():
            return None
        path = str(p)
    return Detector(path)


def select_demos(demos: list, tasks: list[str] | None, max_per_task: int) -> list:
    """The demos of `tasks` (task names; all when None), at most `max_per_task` of each (0: all)."""
    if tasks:
        demos = [d for d in demos if d.task in set(tasks)]
    if max_per_task <= 0:
        return demos
    kept, seen = [], Counter()
    for d in sorted(demos, key=lambda d: (d.task, d.bag_path)):
        if seen[d.task] < max_per_task:
            kept.append(d)
            seen[d.task] += 1
    return kept


def report_incomplete(demos: list, skipped: list[tuple[str, str]], included: bool) -> None:
    """Say what happens to recovered and interrupted episodes (they may end before the task did)."""
    if included:
        n = sum(d.outcome in INCOMPLETE_OUTCOMES for d in demos)
        if n:
            print(f"training on {n} incomplete demos (outcome recovered or interrupted), as "
                  "--include-incomplete asks", file=sys.stderr)
        return
    n = sum(any(f"outcome is {o!r}" in reason for o in INCOMPLETE_OUTCOMES) for _, reason in skipped)
    if n:
        print(f"left out {n} incomplete episodes (outcome recovered or interrupted: they may end before "
              "the task did); --include-incomplete trains on them", file=sys.stderr)


def resolve_tasks(args: argparse.Namespace, catalogue: Catalogue) -> tuple[list[str], str | None]:
    """(the --task names, the task of bags without episode metadata), parsed by the catalogue."""
    tasks = [catalogue.task(t).name for t in args.task or []]
    if args.default_task:
        return tasks, catalogue.task(args.default_task).name
    return tasks, tasks[0] if len(tasks) == 1 else None


def train_config(args: argparse.Namespace) -> TrainConfig:
    overrides = dict(encoder=args.encoder, seed=args.seed, epochs=args.epochs, batch_size=args.batch_size,
                     lr=args.lr, position_scale=args.position_scale, rest_samples=args.rest_samples,
                     corrective_copies=args.corrective_copies, corrective_sigma=args.corrective_sigma)
    if args.hidden is not None:
        overrides["hidden"] = args.hidden
    return TrainConfig.paper(**overrides) if args.paper_exact else TrainConfig(**overrides)


def run(args: argparse.Namespace) -> int:
    from vla_latent_training.train import train_model  # torch: only when training runs

    try:
        catalogue = load_catalogue(args.catalogue)
        tasks, untagged_task = resolve_tasks(args, catalogue)
    except (CatalogueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    demos, skipped = load_demos(args.bags, require="image" if args.encoder != "detector" else None,
                                task=untagged_task, include_incomplete=args.include_incomplete)
    demos = select_demos(demos, tasks, args.max_per_task)
    for path, reason in skipped:
        print(f"skipped {path}: {reason}", file=sys.stderr)
    report_incomplete(demos, skipped, args.include_incomplete)
    if any("no task was given" in reason for _, reason in skipped):
        print("hint: bags without episode metadata need their task: one --task, or --default-task",
              file=sys.stderr)
    if not demos:
        print(f"error: no usable demonstrations in {' '.join(args.bags)}"
              + ("" if skipped else " (no bags: a folder is searched one level deep for bag folders)"),
              file=sys.stderr)
        return 1
    print(f"loaded {len(demos)} demos from {' '.join(args.bags)} ({len(skipped)} bags skipped)")
    try:
        needs_detection = args.encoder == "detector" and any(d.detection is None for d in demos)
        detector = _detector(args.detector_model, needs_detection)
        if detector is not None:
            catalogue.check_classes(detector.classes, f"detector {args.detector_model or 'shipped'}")
    except Exception as e:  # a bad --detector-model is the user's error, not a crash
        print(f"error: detector: {e}", file=sys.stderr)
        return 2
    classes = list(detector.classes) if detector is not None else list(catalogue.classes)
    try:
        res = train_model(demos, train_config(args), classes=classes, detector=detector,
                          progress=not args.quiet, threads=args.threads)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    out = res.save(args.out)
    print(f"saved {out}/ (config.json, model.safetensors{', context_cnn.onnx' if res.cnn_onnx else ''})")
    return 0

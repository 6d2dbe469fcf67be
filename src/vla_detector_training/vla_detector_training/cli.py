"""`vla_detector_training` command line: synth, capture, import-coco, check, train, evaluate, export.

Heavy optional imports (torch, MuJoCo) happen inside the subcommands that need them, so `--help`,
`check` and `evaluate` stay light.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

from rclpy.parameter import Parameter
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.ros.node_main import run_node
from vla_detector.inference import default_model_path

from vla_detector_training.capture_node import CaptureNode
from vla_detector_training.coco import import_coco, parse_mapping
from vla_detector_training.dataset import DatasetError, load_data_config, load_split
from vla_detector_training.evaluate import evaluate_model

SCRATCH_LR = 3e-3
FINE_TUNE_LR = 1e-3  # warm-started at 3e-3 the shipped model lost 0.28 mAP@0.5:0.95 in an epoch (history)


def _cmd_synth(a: argparse.Namespace) -> int:
    from vla_detector_training.synth import synthesize  # MuJoCo

    t = time.perf_counter()
    counts = synthesize(a.out, a.count, a.seed, a.split, a.val_fraction, a.width, a.height, not a.quiet,
                        load_catalogue(a.catalogue) if a.catalogue else None, a.include)
    print(
        f"wrote {sum(counts.values())} images to {a.out} "
        f"({', '.join(f'{k}: {v}' for k, v in counts.items())}) "
        f"in {time.perf_counter() - t:.1f} s"
    )
    return 0


def _cmd_capture(a: argparse.Namespace) -> int:
    params = [Parameter("out", value=a.out), Parameter("count", value=a.count),
              Parameter("every", value=float(a.every)), Parameter("split", value=a.split),
              Parameter("catalogue", value=a.catalogue or ""),
              Parameter("image_reliability", value=a.image_reliability)]
    ros_args = ["vla_detector_training", "--ros-args", *a.ros_args] if a.ros_args else None
    return run_node(lambda: CaptureNode(parameter_overrides=params), "vla_detector_training capture",
                    ros_args)


def _cmd_import_coco(a: argparse.Namespace) -> int:
    classes = load_catalogue(a.catalogue).classes
    report = import_coco(a.annotations, a.images, a.out, classes, parse_mapping(a.map or []), a.split)
    for line in report.lines():
        print(line)
    print(f"dataset: {a.out} (split {a.split}; classes {list(classes)})")
    return 0


def learning_rate(a: argparse.Namespace) -> float:
    """--lr, else the default for training from scratch or for fine-tuning (--init)."""
    return a.lr if a.lr is not None else (FINE_TUNE_LR if a.init else SCRATCH_LR)


def _cmd_train(a: argparse.Namespace) -> int:
    from vla_detector_training.train import TrainConfig, parse_imgsz, train  # torch

    if a.drop_old_classes and not a.init:
        raise ValueError("--drop-old-classes needs --init (the classes to drop are the initial model's)")
    w, h = parse_imgsz(a.imgsz)
    cfg = TrainConfig(
        data=a.data,
        out=a.out,
        epochs=a.epochs,
        batch=a.batch,
        lr=learning_rate(a),
        input_width=w,
        input_height=h,
        width=a.width,
        seed=a.seed,
        threads=a.threads,
        max_images=a.max_images,
        augment=not a.no_augment,
        progress=not a.quiet,
        init=str(default_model_path()) if a.init == "shipped" else a.init,
        drop_old_classes=a.drop_old_classes,
        mix_synth=a.mix_synth,
        catalogue=a.catalogue,
    )
    s = train(cfg)
    print(f"model: {s['onnx']}")
    return 0


def _cmd_evaluate(a: argparse.Namespace) -> int:
    model = a.model or str(default_model_path())
    t = time.perf_counter()
    m, n, split = evaluate_model(model, a.data, a.split, a.score_threshold, a.iou_threshold, not a.quiet)
    print(f"model: {model}")
    print(f"data: {a.data} (split {split}, {n} images)")
    for line in m.lines():
        print(line)
    for name, ap in m.per_class_ap50.items():
        print(f"  AP@0.5 {name}: {ap:.4f}")
    print(f"time: {time.perf_counter() - t:.1f} s")
    if a.json is not None:  # for programs (vla_evaluation new-object): the same figures, typed
        figures = {"model": str(model), "data": str(a.data), "split": split, "images": n, **asdict(m)}
        Path(a.json).write_text(json.dumps(_no_nan(figures), indent=2) + "\n")
    return 0


def _no_nan(value):
    """NaN (a centre error with nothing matched) as null: standard JSON."""
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    return None if isinstance(value, float) and math.isnan(value) else value


def _cmd_check(a: argparse.Namespace) -> int:
    cfg = load_data_config(a.data)
    for s in cfg.splits:
        samples = load_split(cfg, s)
        n = sum(len(x.boxes) for x in samples)
        print(f"{s}: {len(samples)} images, {n} boxes")
    print(f"classes: {cfg.names}")
    return 0


def _cmd_export(a: argparse.Namespace) -> int:
    from vla_detector_training.export import export_onnx, load_checkpoint  # torch

    net, classes, extra = load_checkpoint(a.checkpoint)
    print(f"exported {export_onnx(net, classes, a.out, {'trained': extra})}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vla_detector_training", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("synth", help="render annotated images from the MuJoCo scene (YOLO format)")
    s.add_argument("--count", type=int, required=True)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True)
    s.add_argument(
        "--split",
        default="auto",
        choices=["auto", "train", "val", "test"],
        help="auto: the last --val-fraction of the images go to val, the rest to train",
    )
    s.add_argument("--val-fraction", type=float, default=0.1)
    s.add_argument("--width", type=int, default=320)
    s.add_argument("--height", type=int, default=240)
    s.add_argument("--catalogue", default=None, help="the objects on the table (default: vla_common's)")
    s.add_argument("--include", default=None, metavar="CLASS", help="every scene has this object")
    s.add_argument("--quiet", action="store_true")
    s.set_defaults(func=_cmd_synth)

    cap = sub.add_parser("capture", help="save camera/image_raw frames as a YOLO dataset skeleton to label")
    cap.add_argument("--out", required=True, help="dataset folder (created; one with frames is added to)")
    cap.add_argument("--count", type=int, default=20, help="frames to save")
    cap.add_argument("--every", type=float, default=1.0, help="seconds between saved frames (0: every frame)")
    cap.add_argument("--split", default="train", choices=["train", "val", "test"])
    cap.add_argument("--catalogue", default=None, help="the classes of data.yaml (default: vla_common's)")
    cap.add_argument("--image-reliability", default="reliable", choices=["reliable", "best_effort"])
    cap.add_argument("--ros-args", nargs=argparse.REMAINDER, default=None, dest="ros_args",
                   help="ROS arguments, e.g. --ros-args -r camera/image_raw:=/webcam/image_raw")
    cap.set_defaults(func=_cmd_capture)

    i = sub.add_parser("import-coco", help="COCO JSON (CVAT, Label Studio, Roboflow) -> a YOLO dataset")
    i.add_argument("annotations", help="the COCO annotation file (.json)")
    i.add_argument("--images", required=True, help="folder holding the images the file names")
    i.add_argument("--out", required=True, help="YOLO dataset folder (created, or added to)")
    i.add_argument("--map", nargs="+", action="extend", default=[], metavar="COCO=OURS",
                   help="category name -> our class name (identical names map themselves); COCO= leaves a "
                        "category out")
    i.add_argument("--split", default="train", choices=["train", "val", "test"])
    i.add_argument("--catalogue", default=None, help="our classes (catalogue YAML; default: vla_common's)")
    i.set_defaults(func=_cmd_import_coco)

    t = sub.add_parser("train", help="train (from scratch or --init), validate each epoch, export the best")
    t.add_argument("--data", required=True, help="dataset folder with data.yaml")
    t.add_argument("--out", required=True)
    t.add_argument("--epochs", type=int, default=40)
    t.add_argument("--batch", type=int, default=16)
    t.add_argument("--lr", type=float, default=None,
                   help=f"peak learning rate (default {SCRATCH_LR:g}; with --init {FINE_TUNE_LR:g})")
    t.add_argument("--imgsz", default="320", help="input size: W (4:3) or WxH, multiples of 16")
    t.add_argument("--width", type=int, default=24, help="network width (channels at stride 4)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--max-images", type=int, default=0, help="use only the first N training images")
    t.add_argument("--no-augment", action="store_true")
    t.add_argument("--init", default=None, metavar="MODEL",
                   help="warm-start from a detector: .safetensors, .onnx, a run folder, or 'shipped' (the "
                        "backbone is kept, the class head resized; the old classes stay unless dropped)")
    t.add_argument("--drop-old-classes", action="store_true",
                   help="with --init: the model's classes are the data's only")
    t.add_argument("--mix-synth", type=int, default=0, metavar="N",
                   help="mix N synthetic renders of the scene into training (10 %% into validation): they "
                        "keep the old classes alive when the new data lacks them")
    t.add_argument("--catalogue", default=None, help="the objects of the --mix-synth renders")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=_cmd_train)

    e = sub.add_parser("evaluate", help="mAP@0.5, mAP@0.5:0.95, mean centre error of an ONNX model")
    e.add_argument("--model", default=None, help="ONNX file (default: the shipped model)")
    e.add_argument("--data", required=True)
    e.add_argument("--split", default=None, help="default: test, else val")
    e.add_argument("--score-threshold", type=float, default=0.3, help="for centre error, precision, recall")
    e.add_argument("--iou-threshold", type=float, default=0.25, help="NMS IoU")
    e.add_argument("--json", type=Path, default=None,
                   help="also write the figures to this JSON file (model, data, split, images, map50, "
                        "map50_95, centre_error_px, precision, recall, per_class_ap50)")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=_cmd_evaluate)

    c = sub.add_parser("check", help="validate a YOLO dataset (errors name file and line)")
    c.add_argument("--data", required=True)
    c.set_defaults(func=_cmd_check)

    x = sub.add_parser("export", help="export a .safetensors checkpoint to ONNX + JSON sidecar")
    x.add_argument("--checkpoint", required=True)
    x.add_argument("--out", required=True)
    x.set_defaults(func=_cmd_export)

    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (DatasetError, CatalogueError, ValueError, FileNotFoundError) as e:
        print(f"vla_detector_training {args.cmd}: error: {e}", file=sys.stderr)
        return 2
    except RuntimeError as e:  # ModelError and friends
        print(f"vla_detector_training {args.cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

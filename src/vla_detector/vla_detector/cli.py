"""`vla_detector detect`: run an ONNX detector on image files and print one JSON line per image."""

from __future__ import annotations

import argparse
import json
import sys

from vla_common.image_convert import UnsupportedImageError, read_image

from vla_detector.inference import Detector, ModelError, default_model_path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vla_detector", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("detect", help="run a model on image files, print JSON lines")
    d.add_argument("images", nargs="+")
    d.add_argument("--model", default=None, help="ONNX file (default: the shipped model)")
    d.add_argument("--score-threshold", type=float, default=0.3)
    d.add_argument("--iou-threshold", type=float, default=0.25)
    return p


def detect(a: argparse.Namespace) -> int:
    det = Detector(a.model or default_model_path(), a.score_threshold, a.iou_threshold)
    for path in a.images:
        dets = det.detect(read_image(path))
        print(json.dumps({"image": path, "detections": [d.as_dict() for d in dets]}))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return detect(args)
    except (UnsupportedImageError, ModelError, ValueError, FileNotFoundError) as e:
        print(f"vla_detector {args.cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

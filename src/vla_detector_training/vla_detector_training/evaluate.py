"""Evaluate an ONNX detector (ours or an Ultralytics export) on a YOLO-format split, through the same
`Detector` the node uses, so the figures are those of the deployed model."""

from __future__ import annotations

import os

import numpy as np
from tqdm import tqdm
from vla_detector.inference import Detector

from vla_detector_training.dataset import DatasetError, load_data_config, load_split, read_image
from vla_detector_training.metrics import ImageResult, Metrics, evaluate

EVAL_SCORE_FLOOR = 0.001


def pick_split(data: str | os.PathLike, split: str | None) -> str:
    """The requested split, else test, else val."""
    cfg = load_data_config(data)
    if split:
        cfg.split_dir(split)
        return split
    for s in ("test", "val"):
        if s in cfg.splits:
            return s
    raise DatasetError(f"{cfg.root / 'data.yaml'}: no 'test' or 'val' split to evaluate on")


def evaluate_model(
    model: str | os.PathLike,
    data: str | os.PathLike,
    split: str | None = None,
    score_threshold: float = 0.3,
    iou_threshold: float = 0.25,
    progress: bool = False,
) -> tuple[Metrics, int, str]:
    """(metrics, number of images, split). Class names of data and model must agree."""
    cfg = load_data_config(data)
    split = pick_split(data, split)
    det = Detector(model, score_threshold=EVAL_SCORE_FLOOR, iou_threshold=iou_threshold, max_detections=100)
    if list(det.classes) != list(cfg.names):
        raise DatasetError(f"class names differ: model {det.classes} vs {cfg.root / 'data.yaml'} {cfg.names}")
    samples = load_split(cfg, split)
    results = []
    for s in tqdm(samples, desc=f"evaluating {split}", dynamic_ncols=True, disable=not progress):
        dets = det.detect(read_image(s.image_path))
        gt = np.array([[b.cx, b.cy, b.w, b.h] for b in s.boxes], dtype=np.float64).reshape(-1, 4)
        results.append(
            ImageResult(
                gt,
                np.array([b.class_index for b in s.boxes], dtype=np.int64),
                np.array([[d.cx, d.cy, d.width, d.height] for d in dets], dtype=np.float64).reshape(-1, 4),
                np.array([d.score for d in dets], dtype=np.float64),
                np.array([d.class_index for d in dets], dtype=np.int64),
            )
        )
    return evaluate(results, cfg.names, score_threshold), len(samples), split

"""Training on a YOLO-format dataset, from scratch or warm-started from an existing detector (the
backbone kept, the class head resized to the new class list; see warmstart.py), optionally with
synthetic renders mixed in; validated every epoch, the best checkpoint kept.

Images are held in memory (1000 images at 320x240 are 230 MB), letterboxed to the input size the
way the run-time Detector does it, and augmented on the fly (flip, scale/shift, colour gain). The
best epoch by 0.1 * mAP@0.5 + 0.9 * mAP@0.5:0.95 (Ultralytics' fitness) is saved as safetensors and
exported to ONNX with its JSON sidecar.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm
from vla_common.catalogue import load_catalogue
from vla_detector.decode import letterbox, postprocess

from vla_detector_training.dataset import (
    DataConfig,
    DatasetError,
    list_images,
    load_data_config,
    read_image,
    read_split_labels,
)
from vla_detector_training.export import export_onnx, load_checkpoint, save_checkpoint
from vla_detector_training.metrics import ImageResult, Metrics, evaluate
from vla_detector_training.model import STRIDE, DetectorNet, ModelConfig, count_parameters, raw_to_output
from vla_detector_training.targets import build_targets, detection_loss
from vla_detector_training.warmstart import Source, load_source, model_classes, recalibrate_batchnorm, resized

EVAL_SCORE_FLOOR = 0.001  # predictions kept for mAP (standard practice)
BN_CALIBRATION_IMAGES = 64  # training images the BatchNorm statistics of an ONNX source come from


@dataclass
class TrainConfig:
    data: str
    out: str
    epochs: int = 40
    batch: int = 16
    lr: float = 3e-3
    weight_decay: float = 5e-4
    input_width: int = 320
    input_height: int = 240
    width: int = 24
    seed: int = 0
    threads: int = 2
    score_threshold: float = 0.3
    iou_threshold: float = 0.25
    max_images: int = 0  # 0: all
    augment: bool = True
    progress: bool = True
    init: str | None = None  # warm start from this detector (.safetensors, .onnx or a run folder)
    drop_old_classes: bool = False  # with init: the model's classes are the data's only
    mix_synth: int = 0  # synthetic renders of the scene mixed in (10 % of them into validation)
    catalogue: str | None = None  # the objects of those renders (None: vla_common's default)


@dataclass
class ArrayData:
    images: np.ndarray  # (N, H, W, 3) uint8, letterboxed to the input size
    boxes: list[np.ndarray]  # per image (K, 4) cx, cy, w, h in input pixels
    classes: list[np.ndarray]  # per image (K,)


def parse_imgsz(text: str) -> tuple[int, int]:
    """'320' -> (320, 240) (4:3, the camera's aspect); '320x240' -> (320, 240). Multiples of 16."""
    t = str(text).lower().replace("*", "x")
    try:
        if "x" in t:
            w, h = (int(v) for v in t.split("x"))
        else:
            w = int(t)
            h = int(round(w * 3 / 4 / 16) * 16)
    except ValueError:
        raise ValueError(f"--imgsz {text!r}: expected W or WxH") from None
    if w <= 0 or h <= 0 or w % 16 or h % 16:
        raise ValueError(f"--imgsz {w}x{h}: width and height must be positive multiples of 16")
    return w, h


def load_arrays(cfg: DataConfig, split: str, width: int, height: int, max_images: int = 0) -> ArrayData:
    """Every image of a split letterboxed to width x height, boxes mapped alike (validated first)."""
    images = list_images(cfg.split_dir(split))
    if not images:
        raise DatasetError(f"{cfg.split_dir(split)}: no images")
    labels = read_split_labels(images, len(cfg.names))  # all errors before work
    if max_images:
        images, labels = images[:max_images], labels[:max_images]
    imgs, boxes, classes = [], [], []
    for path, lab in zip(images, labels):
        rgb = read_image(path)
        h, w = rgb.shape[:2]
        img, lb = letterbox(rgb, width, height)
        b = np.array(
            [[cx * w, cy * h, bw * w, bh * h] for _, cx, cy, bw, bh in lab], dtype=np.float64
        ).reshape(-1, 4)
        b[:, 0] = b[:, 0] * lb.scale + lb.pad_x
        b[:, 1] = b[:, 1] * lb.scale + lb.pad_y
        b[:, 2:] *= lb.scale
        imgs.append(img)
        boxes.append(b.astype(np.float32))
        classes.append(np.array([c for c, *_ in lab], dtype=np.int64))
    return ArrayData(np.stack(imgs), boxes, classes)


def augment(img: np.ndarray, boxes: np.ndarray, classes: np.ndarray, rng: np.random.Generator):
    """Flip, random scale/shift (boxes clipped, mostly-cut boxes dropped), colour gain."""
    h, w = img.shape[:2]
    b = boxes.astype(np.float64).copy()
    if rng.random() < 0.5:
        img = img[:, ::-1]
        b[:, 0] = w - b[:, 0]
    if rng.random() < 0.5:
        s = rng.uniform(0.8, 1.25)
        tx, ty = rng.uniform(-0.1, 0.1) * w, rng.uniform(-0.1, 0.1) * h
        m = np.array([[s, 0, tx + (1 - s) * w / 2], [0, s, ty + (1 - s) * h / 2]])
        img = cv2.warpAffine(
            np.ascontiguousarray(img), m, (w, h), flags=cv2.INTER_LINEAR, borderValue=(114, 114, 114)
        )
        x1, y1 = b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2
        x2, y2 = b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2
        x1, x2 = x1 * s + m[0, 2], x2 * s + m[0, 2]
        y1, y2 = y1 * s + m[1, 2], y2 * s + m[1, 2]
        area0 = (x2 - x1) * (y2 - y1)
        x1, x2 = np.clip(x1, 0, w), np.clip(x2, 0, w)
        y1, y2 = np.clip(y1, 0, h), np.clip(y2, 0, h)
        keep = ((x2 - x1) > 2) & ((y2 - y1) > 2) & ((x2 - x1) * (y2 - y1) > 0.4 * area0)
        b = np.stack([(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1], 1)[keep]
        classes = classes[keep]
    if rng.random() < 0.8:
        gain = rng.uniform(0.75, 1.25) * rng.normal(1.0, 0.04, size=3)
        img = np.clip(img.astype(np.float32) * gain, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img), b.astype(np.float32), classes


def to_tensor(imgs: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(imgs)).permute(0, 3, 1, 2).float().div_(255.0)


@torch.no_grad()
def predict_arrays(
    net: DetectorNet, data: ArrayData, iou_threshold: float, batch: int = 16
) -> list[ImageResult]:
    """Run the torch model over a dataset and decode exactly as the ONNX Detector does."""
    net.eval()
    results = []
    for i in range(0, len(data.images), batch):
        out = raw_to_output(*net(to_tensor(data.images[i : i + batch]))).numpy()
        for j in range(out.shape[0]):
            k = i + j
            boxes, scores, cls = postprocess(out[j : j + 1], "yolov8", EVAL_SCORE_FLOOR, iou_threshold, 100)
            results.append(ImageResult(data.boxes[k].astype(np.float64), data.classes[k], boxes, scores, cls))
    return results


def fitness(m: Metrics) -> float:
    v = 0.1 * m.map50 + 0.9 * m.map50_95
    return v if math.isfinite(v) else -1.0


def _log(msg: str, progress: bool) -> None:
    if progress:
        tqdm.write(msg)
    else:
        print(msg, flush=True)


def subset(data: ArrayData, idx: np.ndarray) -> ArrayData:
    return ArrayData(data.images[idx], [data.boxes[i] for i in idx], [data.classes[i] for i in idx])


def concat(a: ArrayData, b: ArrayData) -> ArrayData:
    return ArrayData(np.concatenate([a.images, b.images]), a.boxes + b.boxes, a.classes + b.classes)


def relabel(data: ArrayData, names: Sequence[str], classes: Sequence[str]) -> ArrayData:
    """The same images with class indices into `classes`; boxes of names it lacks are dropped."""
    lut = np.array([list(classes).index(n) if n in classes else -1 for n in names], np.int64)
    boxes, cls = [], []
    for b, c in zip(data.boxes, data.classes):
        new = lut[c] if len(c) else c
        keep = new >= 0
        boxes.append(b[keep])
        cls.append(new[keep])
    return ArrayData(data.images, boxes, cls)


def synthetic_mix(cfg: TrainConfig, out: Path) -> tuple[list[str], ArrayData, ArrayData | None]:
    """(class names, training part, validation part or None) of cfg.mix_synth renders at the input size,
    rendered once into the run folder and reused."""
    from vla_detector_training.synth import synthesize  # MuJoCo: only when renders are mixed in

    root = out / f"mix_synth_s{cfg.seed}_n{cfg.mix_synth}"
    if not (root / "data.yaml").is_file():
        _log(f"rendering {cfg.mix_synth} synthetic images into {root}", cfg.progress)
        synthesize(root, cfg.mix_synth, cfg.seed, "auto", 0.1, cfg.input_width, cfg.input_height,
                   cfg.progress, load_catalogue(cfg.catalogue) if cfg.catalogue else None)
    dcfg = load_data_config(root)
    train_part = load_arrays(dcfg, "train", cfg.input_width, cfg.input_height)
    val_part = load_arrays(dcfg, "val", cfg.input_width, cfg.input_height) if "val" in dcfg.splits else None
    return dcfg.names, train_part, val_part


def training_data(cfg: TrainConfig, rng: np.random.Generator, out: Path,
                  old_classes: Sequence[str] | None) -> tuple[list[str], ArrayData, ArrayData]:
    """(the model's classes, training images, validation images), labels in the model's indices: the
    old classes (unless dropped), then the data's new ones, then the renders' (when mixed in)."""
    names, train_data, val_data = load_datasets(cfg, rng)
    classes = model_classes(old_classes, names, cfg.drop_old_classes)
    train_data, val_data = relabel(train_data, names, classes), relabel(val_data, names, classes)
    if cfg.mix_synth:
        synth_names, synth_train, synth_val = synthetic_mix(cfg, out)
        if not cfg.drop_old_classes:
            classes = model_classes(classes, synth_names, False)
        train_data = concat(train_data, relabel(synth_train, synth_names, classes))
        if synth_val is not None:
            val_data = concat(val_data, relabel(synth_val, synth_names, classes))
    return classes, train_data, val_data


def initial_network(cfg: TrainConfig, classes: list[str], source: Source | None,
                    train_data: ArrayData) -> DetectorNet:
    """A fresh network, or the source's resized to `classes` (BatchNorms recalibrated on the training
    images when the source was an ONNX model, which does not store their statistics)."""
    if source is None:
        return DetectorNet(ModelConfig(len(classes), cfg.width, cfg.input_width, cfg.input_height))
    width = source.net.cfg.width
    net = resized(source.net, source.classes, classes,
                  ModelConfig(len(classes), width, cfg.input_width, cfg.input_height))
    if source.from_onnx:
        recalibrate_batchnorm(net, to_tensor(train_data.images[:BN_CALIBRATION_IMAGES]))
    kept = [c for c in source.classes if c in classes]
    new = [c for c in classes if c not in kept]
    dropped = [c for c in source.classes if c not in classes]
    _log(f"warm start from {source.path} (width {width}): the class head of {kept} kept, new {new}"
         + (f", dropped {dropped}" if dropped else ""), cfg.progress)
    return net


def load_datasets(cfg: TrainConfig, rng: np.random.Generator) -> tuple[list[str], ArrayData, ArrayData]:
    """(class names, training images, validation images): the `val` split, else 10 % of `train`
    held out deterministically."""
    dcfg = load_data_config(cfg.data)
    if "train" not in dcfg.splits:
        raise DatasetError(f"{dcfg.root / 'data.yaml'}: no 'train' split")
    train_data = load_arrays(dcfg, "train", cfg.input_width, cfg.input_height, cfg.max_images)
    if "val" in dcfg.splits:
        return dcfg.names, train_data, load_arrays(dcfg, "val", cfg.input_width, cfg.input_height)
    n = len(train_data.images)
    idx = rng.permutation(n)
    nv = max(1, n // 10)
    return dcfg.names, subset(train_data, np.sort(idx[nv:])), subset(train_data, np.sort(idx[:nv]))


def lr_schedule(cfg: TrainConfig, steps_per_epoch: int) -> Callable[[int], float]:
    """Learning rate at each optimiser step: linear warm-up (at most an epoch), then cosine to 2 %."""
    total = steps_per_epoch * cfg.epochs
    warmup = min(steps_per_epoch, total // 5 + 1)

    def lr_at(step: int) -> float:
        if step < warmup:
            return cfg.lr * (step + 1) / warmup
        p = (step - warmup) / max(1, total - warmup)
        return cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * p)))

    return lr_at


def make_batch(data: ArrayData, idx: np.ndarray, augmented: bool, rng: np.random.Generator):
    """(images (B, H, W, 3), boxes per image, classes per image) of the images at `idx`."""
    imgs, bxs, cls = [], [], []
    for i in idx:
        if augmented:
            im, b, c = augment(data.images[i], data.boxes[i], data.classes[i], rng)
        else:
            im, b, c = data.images[i], data.boxes[i], data.classes[i]
        imgs.append(im)
        bxs.append(b)
        cls.append(c)
    return np.stack(imgs), bxs, cls


@dataclass
class _Optimiser:
    """AdamW, its per-step learning rate and the step count so far."""

    opt: torch.optim.Optimizer
    lr_at: Callable[[int], float]
    step: int = 0

    def update(self, net: DetectorNet, loss: torch.Tensor) -> None:
        for g in self.opt.param_groups:
            g["lr"] = self.lr_at(self.step)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
        self.opt.step()
        self.step += 1


def train_epoch(net: DetectorNet, data: ArrayData, num_classes: int, cfg: TrainConfig, optimiser: _Optimiser,
                rng: np.random.Generator, desc: str) -> float:
    """One pass over the training images in a fresh order; the running (smoothed) loss at its end."""
    net.train()
    n = len(data.images)
    order = rng.permutation(n)
    gh, gw = cfg.input_height // STRIDE, cfg.input_width // STRIDE
    steps = max(1, math.ceil(n / cfg.batch))
    bar = tqdm(range(steps), desc=desc, disable=not cfg.progress, leave=False, dynamic_ncols=True)
    run_loss = 0.0
    for s in bar:
        imgs, bxs, cls = make_batch(data, order[s * cfg.batch : (s + 1) * cfg.batch], cfg.augment, rng)
        heat, reg, wt = build_targets(bxs, cls, num_classes, gh, gw)
        cl, bo = net(to_tensor(imgs))
        loss, parts = detection_loss(cl, bo, heat, reg, wt)
        optimiser.update(net, loss)
        lv = float(loss.detach())
        run_loss = 0.9 * run_loss + 0.1 * lv if s else lv
        bar.set_postfix(loss=f"{run_loss:.3f}", cls=f"{parts['cls']:.3f}", giou=f"{parts['giou']:.3f}")
    bar.close()
    return run_loss


def epoch_row(epoch: int, loss: float, m: Metrics, elapsed_s: float) -> dict:
    """One line of results.csv."""
    return {
        "epoch": epoch,
        "loss": round(loss, 5),
        "map50": m.map50,
        "map50_95": m.map50_95,
        "centre_error_px": m.centre_error_px,
        "precision": m.precision,
        "recall": m.recall,
        "elapsed_s": round(elapsed_s, 1),
    }


@dataclass
class FitResult:
    history: list[dict]  # results.csv rows
    best_epoch: int  # 1-based
    best_metrics: Metrics


def fit(net: DetectorNet, train_data: ArrayData, val_data: ArrayData, names: list[str], cfg: TrainConfig,
        rng: np.random.Generator, ckpt: Path, t_start: float) -> FitResult:
    """Train for cfg.epochs, validating after each; the best epoch (by `fitness`) is saved to `ckpt`."""
    steps_per_epoch = max(1, math.ceil(len(train_data.images) / cfg.batch))
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    optimiser = _Optimiser(opt, lr_schedule(cfg, steps_per_epoch))
    best, best_epoch, best_metrics = -2.0, -1, None
    history = []
    for epoch in range(1, cfg.epochs + 1):
        loss = train_epoch(net, train_data, len(names), cfg, optimiser, rng, f"epoch {epoch}/{cfg.epochs}")
        m = evaluate(predict_arrays(net, val_data, cfg.iou_threshold), names, cfg.score_threshold)
        row = epoch_row(epoch, loss, m, time.perf_counter() - t_start)
        history.append(row)
        mark = ""
        if fitness(m) > best:
            best, best_epoch, best_metrics = fitness(m), epoch, m
            save_checkpoint(ckpt, net, names, {"epoch": epoch, "metrics": row})
            mark = "  (best)"
        _log(
            f"epoch {epoch}/{cfg.epochs}: loss {loss:.4f}  mAP@0.5 {m.map50:.4f}  "
            f"mAP@0.5:0.95 {m.map50_95:.4f}  centre error {m.centre_error_px:.2f} px  "
            f"P {m.precision:.3f} R {m.recall:.3f}  [{row['elapsed_s']:.0f} s]{mark}",
            cfg.progress,
        )
    return FitResult(history, best_epoch, best_metrics)


def write_history(path: Path, history: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(history[0]))
        w.writeheader()
        w.writerows(history)


def export_best(ckpt: Path, names: list[str], out: Path, cfg: TrainConfig, result: FitResult, n_train: int,
                wall: float) -> Path:
    """The best checkpoint as detector.onnx + detector.json, with what it was trained on."""
    best_net, _, _ = load_checkpoint(ckpt)
    m = result.best_metrics
    trained = {
        "epochs": cfg.epochs,
        "best_epoch": result.best_epoch,
        "train_images": n_train,
        "seed": cfg.seed,
        "wall_time_s": round(wall, 1),
        "init": cfg.init,
        "mix_synth": cfg.mix_synth,
        "val": {"map50": m.map50, "map50_95": m.map50_95, "centre_error_px": m.centre_error_px,
                "ap50_per_class": m.per_class_ap50},
    }
    return export_onnx(best_net, names, out / "detector.onnx", extra={"trained": trained})


def per_class_lines(m: Metrics, classes: Sequence[str]) -> list[str]:
    """AP@0.5 of each class on the validation images (classes without validation boxes say so)."""
    return [f"  AP@0.5 {c}: {m.per_class_ap50[c]:.4f}" if c in m.per_class_ap50 else
            f"  AP@0.5 {c}: no validation boxes" for c in classes]


def train(cfg: TrainConfig) -> dict:
    """Train, validate each epoch, keep the best checkpoint, export it. Returns a summary dict."""
    t_start = time.perf_counter()
    torch.set_num_threads(max(1, cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    source = load_source(cfg.init) if cfg.init else None
    classes, train_data, val_data = training_data(cfg, rng, out, source.classes if source else None)
    net = initial_network(cfg, classes, source, train_data)
    n_train = len(train_data.images)
    _log(
        f"training on {n_train} images, validating on {len(val_data.images)}; classes {classes}; "
        f"input {cfg.input_width}x{cfg.input_height}; {count_parameters(net)} parameters",
        cfg.progress,
    )
    ckpt = out / "best.safetensors"
    result = fit(net, train_data, val_data, classes, cfg, rng, ckpt, t_start)
    write_history(out / "results.csv", result.history)
    wall = time.perf_counter() - t_start
    onnx_path = export_best(ckpt, classes, out, cfg, result, n_train, wall)
    m = result.best_metrics
    summary = {
        "best_epoch": result.best_epoch,
        "wall_time_s": round(wall, 1),
        "onnx": str(onnx_path),
        "checkpoint": str(ckpt),
        "classes": classes,
        "val": dict(result.history[result.best_epoch - 1], ap50_per_class=m.per_class_ap50),
        "train_images": n_train,
        "config": dict(vars(cfg)),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    _log(
        f"best epoch {result.best_epoch}: mAP@0.5 {m.map50:.4f}  mAP@0.5:0.95 {m.map50_95:.4f}  "
        f"centre error {m.centre_error_px:.2f} px; wall time {wall:.0f} s; exported {onnx_path}",
        cfg.progress,
    )
    for line in per_class_lines(m, classes):
        _log(line, cfg.progress)
    return summary


def default_threads() -> int:
    return min(2, os.cpu_count() or 1)

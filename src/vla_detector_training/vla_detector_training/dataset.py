"""YOLO-format datasets: what labelImg, CVAT and Roboflow export, so real labelled photos work as-is.

Layout (Ultralytics convention)::

    DIR/data.yaml               names: [bread, soda_can, ...]   train: images/train   val: images/val
    DIR/images/<split>/x.png    any image OpenCV reads
    DIR/labels/<split>/x.txt    one line per object: `class cx cy w h`, normalised to [0, 1]

An empty label file is an image without objects (a background image). A missing label file is read
the same way but warned about, once per split with the images it concerns: a background image should
be a deliberate choice, not a label lost on the way. Every problem is reported as a `DatasetError`
naming the file and line, never a traceback from deep inside training.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from vla_common.image_convert import UnsupportedImageError

from vla_common import image_convert

log = logging.getLogger("vla_detector_training")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
SPLITS = ("train", "val", "test")
_TOL = 1e-6  # rounding slack for coordinates written with limited precision


class DatasetError(ValueError):
    """A dataset problem, with the file (and line) at fault in the message."""


@dataclass
class Box:
    """One labelled object, in pixels of its image."""

    class_index: int
    cx: float
    cy: float
    w: float
    h: float

    def xyxy(self) -> tuple[float, float, float, float]:
        return (self.cx - self.w / 2, self.cy - self.h / 2, self.cx + self.w / 2, self.cy + self.h / 2)


@dataclass
class Sample:
    image_path: Path
    label_path: Path
    boxes: list[Box] = field(default_factory=list)
    width: int = 0
    height: int = 0


@dataclass
class DataConfig:
    """Contents of data.yaml: class names in index order and the image folder of each split."""

    root: Path
    names: list[str]
    splits: dict[str, Path]

    def split_dir(self, split: str) -> Path:
        if split not in self.splits:
            raise DatasetError(f"{self.root / 'data.yaml'}: no '{split}' split (have: {sorted(self.splits)})")
        return self.splits[split]


def label_path_for(image_path: Path) -> Path:
    """images/<split>/x.png -> labels/<split>/x.txt (the last `images` path component is replaced)."""
    parts = list(image_path.parts)
    for i in range(len(parts) - 2, -1, -1):
        if parts[i] == "images":
            parts[i] = "labels"
            return Path(*parts).with_suffix(".txt")
    return image_path.with_suffix(".txt")


def parse_label_line(
    line: str, path: Path, lineno: int, num_classes: int
) -> tuple[int, float, float, float, float]:
    """One `class cx cy w h` line -> values; DatasetError naming path:line on any problem."""
    where = f"{path}:{lineno}"
    fields = line.split()
    if len(fields) != 5:
        raise DatasetError(
            f"{where}: expected 5 fields 'class cx cy w h', got {len(fields)}: {line.strip()!r}"
        )
    try:
        cls_f = float(fields[0])
    except ValueError:
        raise DatasetError(f"{where}: class id {fields[0]!r} is not an integer") from None
    if not cls_f.is_integer():
        raise DatasetError(f"{where}: class id {fields[0]!r} is not an integer")
    cls = int(cls_f)
    if not 0 <= cls < num_classes:
        raise DatasetError(
            f"{where}: unknown class id {cls} (data.yaml names {num_classes} classes: 0..{num_classes - 1})"
        )
    try:
        cx, cy, w, h = (float(v) for v in fields[1:])
    except ValueError:
        raise DatasetError(f"{where}: box values must be numbers: {line.strip()!r}") from None
    for name, v in (("cx", cx), ("cy", cy), ("w", w), ("h", h)):
        if not math.isfinite(v) or v < -_TOL or v > 1 + _TOL:
            raise DatasetError(f"{where}: {name}={v} out of range [0, 1] (coordinates must be normalised)")
    if w <= 0 or h <= 0:
        raise DatasetError(f"{where}: box has zero or negative size (w={w}, h={h})")
    if cx - w / 2 < -1e-3 or cx + w / 2 > 1 + 1e-3 or cy - h / 2 < -1e-3 or cy + h / 2 > 1 + 1e-3:
        raise DatasetError(f"{where}: box extends outside the image (cx={cx}, cy={cy}, w={w}, h={h})")
    return cls, cx, cy, w, h


def read_labels(path: Path, num_classes: int) -> list[tuple[int, float, float, float, float]]:
    """All labels of one file (normalised); a missing file is an image without objects (see
    read_split_labels for the warning)."""
    if not path.exists():
        return []
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read label file: {e}") from None
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            out.append(parse_label_line(line, path, lineno, num_classes))
    return out


def read_split_labels(
    images: Sequence[Path], num_classes: int
) -> list[list[tuple[int, float, float, float, float]]]:
    """The labels of every image, all validated before any work; one warning naming the images that
    have no label file (they count as images without objects)."""
    missing = [p for p in images if not label_path_for(p).exists()]
    if missing:
        folder = label_path_for(missing[0]).parent
        names = ", ".join(p.name for p in missing[:3]) + (", ..." if len(missing) > 3 else "")
        log.warning(
            "warning: %d of %d images have no label file in %s (%s); they are read as images without "
            "objects. A background image should be deliberate: give it an empty label file.",
            len(missing), len(images), folder, names,
        )
    return [read_labels(label_path_for(p), num_classes) for p in images]


def read_image(path: Path) -> np.ndarray:
    """Image file -> (H, W, 3) uint8 RGB; DatasetError if it cannot be decoded."""
    try:
        return image_convert.read_image(path)
    except UnsupportedImageError as err:
        raise DatasetError(str(err)) from None


def image_size(path: Path) -> tuple[int, int]:
    img = read_image(path)
    return img.shape[1], img.shape[0]


def load_data_config(root: str | os.PathLike) -> DataConfig:
    """Read DIR/data.yaml (or a path to a yaml file) with `names` and split folders."""
    p = Path(root)
    yaml_path = p if p.suffix in (".yaml", ".yml") else p / "data.yaml"
    if not yaml_path.is_file():
        raise DatasetError(f"{yaml_path}: data.yaml not found (a YOLO dataset needs one naming the classes)")
    try:
        doc = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    except yaml.YAMLError as e:
        raise DatasetError(f"{yaml_path}: invalid YAML: {e}") from None
    if not isinstance(doc, dict) or "names" not in doc:
        raise DatasetError(f"{yaml_path}: must be a mapping with a 'names' entry")
    names = doc["names"]
    if isinstance(names, dict):  # Ultralytics also writes {0: name, 1: name}
        try:
            keys = sorted(int(k) for k in names)
        except (TypeError, ValueError):
            raise DatasetError(f"{yaml_path}: 'names' keys must be class indices") from None
        if keys != list(range(len(keys))):
            raise DatasetError(f"{yaml_path}: 'names' indices must be 0..{len(keys) - 1} without gaps")
        names = [names[k] if k in names else names[str(k)] for k in keys]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise DatasetError(f"{yaml_path}: 'names' must be a non-empty list of class names")
    base = yaml_path.parent
    if doc.get("path"):
        base = (
            (base / str(doc["path"])).resolve()
            if not Path(str(doc["path"])).is_absolute()
            else Path(doc["path"])
        )
    splits = {}
    for s in SPLITS:
        if doc.get(s):
            d = Path(str(doc[s]))
            splits[s] = d if d.is_absolute() else base / d
    return DataConfig(root=yaml_path.parent, names=list(names), splits=splits)


def write_data_config(root: Path, names: Sequence[str], splits: Sequence[str]) -> Path:
    """Write DIR/data.yaml naming the classes in index order and the given splits."""
    doc = {"path": ".", "names": list(names)}
    for s in SPLITS:
        if s in splits:
            doc[s] = f"images/{s}"
    path = root / "data.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


def list_images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise DatasetError(f"{folder}: image folder not found")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def load_split(cfg: DataConfig, split: str, check_images: bool = True) -> list[Sample]:
    """All samples of a split with boxes in pixels; validates every label (and image if asked)."""
    images = list_images(cfg.split_dir(split))
    if not images:
        raise DatasetError(f"{cfg.split_dir(split)}: no images")
    samples = []
    for img, labels in zip(images, read_split_labels(images, len(cfg.names))):
        w, h = image_size(img) if check_images else (0, 0)
        boxes = [Box(c, cx * w, cy * h, bw * w, bh * h) for c, cx, cy, bw, bh in labels]
        samples.append(Sample(img, label_path_for(img), boxes, w, h))
    return samples


def format_label_line(
    class_index: int, cx: float, cy: float, w: float, h: float, width: int, height: int
) -> str:
    """Pixel box -> normalised `class cx cy w h` line."""
    return f"{class_index} {cx / width:.6f} {cy / height:.6f} {w / width:.6f} {h / height:.6f}"


def write_sample(root: Path, split: str, stem: str, rgb: np.ndarray, boxes: Sequence[Box]) -> Path:
    """Write one image (PNG) and its label file into DIR/images/<split>, DIR/labels/<split>."""
    img_dir = root / "images" / split
    lbl_dir = root / "labels" / split
    img_dir.mkdir(parents=True, exist_ok=True)
    lbl_dir.mkdir(parents=True, exist_ok=True)
    h, w = rgb.shape[:2]
    path = img_dir / f"{stem}.png"
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise DatasetError(f"{path}: could not write image")
    lines = [format_label_line(b.class_index, b.cx, b.cy, b.w, b.h, w, h) for b in boxes]
    (lbl_dir / f"{stem}.txt").write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return path

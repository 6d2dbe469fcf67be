"""COCO JSON annotations (CVAT, Label Studio, Roboflow exports) converted to a YOLO dataset.

COCO boxes are [x, y, w, h] in pixels from the image's top-left corner; YOLO lines are
`class cx cy w h` normalised by the image size. Category names are mapped to our class names
(identical names map themselves; `--map coco_name=our_name` for others, `coco_name=` leaves a
category out). The dataset's `data.yaml` names the catalogue's classes, so class indices are those of
the detector everywhere. Images are copied (never moved); an image the file lists without annotations
gets an empty label file (a deliberate background image). Crowd regions (`iscrowd: 1`, which CVAT
exports for a region of many objects) are not boxes of one object: they are skipped and counted.
An image is only ever read from inside the images folder: a file name that climbs out of it (`..`)
or a symbolic link that points out of it is refused (an absolute name is looked up inside it). Ids
are integers or strings. Every problem is a DatasetError naming the file and the annotation, image
or category id.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vla_detector_training.dataset import (
    SPLITS,
    DatasetError,
    format_label_line,
    image_size,
    load_data_config,
    write_data_config,
)

EDGE_SLACK_PX = 2.0  # boxes may overshoot the image by this much (tools round), then are clipped


@dataclass
class CocoImport:
    """What an import wrote."""

    images: int = 0
    boxes: int = 0
    backgrounds: int = 0  # images listed without annotations: empty label files
    per_class: Counter = field(default_factory=Counter)
    left_out: Counter = field(default_factory=Counter)  # annotations of categories mapped to nothing
    crowd: Counter = field(default_factory=Counter)  # iscrowd regions skipped, by category name

    def lines(self) -> list[str]:
        out = [f"imported {self.images} images, {self.boxes} boxes ({self.backgrounds} images without "
               "objects: empty label files)"]
        out += [f"  {name}: {n} boxes" for name, n in sorted(self.per_class.items())]
        out += [f"  left out (--map {name}=): {n} boxes" for name, n in sorted(self.left_out.items())]
        out += [f"  skipped (iscrowd, a region of many objects, not a box): {n} {name} regions"
                for name, n in sorted(self.crowd.items())]
        return out


def parse_mapping(items: Sequence[str]) -> dict[str, str | None]:
    """['Bread=bread', 'person='] -> {'Bread': 'bread', 'person': None}."""
    out: dict[str, str | None] = {}
    for item in items:
        name, sep, ours = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--map {item!r}: expected coco_name=our_name (or coco_name= to leave it out)")
        out[name.strip()] = ours.strip() or None
    return out


def _load(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read: {e}") from None
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path}:{e.lineno}: invalid JSON: {e.msg}") from None
    if not isinstance(doc, dict) or not all(isinstance(doc.get(k), list) for k in ("images", "categories")):
        raise DatasetError(f"{path}: not a COCO file: expected lists 'images', 'annotations', 'categories'")
    if not isinstance(doc.get("annotations", []), list):
        raise DatasetError(f"{path}: 'annotations' must be a list")
    return doc


def _is_id(value) -> bool:
    """COCO ids are integers (strings from some tools); a list or a mapping is no id (nor hashable)."""
    return isinstance(value, (int, str)) and not isinstance(value, bool)


def _entries_by_id(path: Path, entries: list, what: str) -> dict:
    out = {}
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or "id" not in e:
            raise DatasetError(f"{path}: {what} #{k} has no id")
        if not _is_id(e["id"]):
            raise DatasetError(f"{path}: {what} #{k}: id must be an integer or a string, got a "
                               f"{type(e['id']).__name__}")
        if e["id"] in out:
            raise DatasetError(f"{path}: {what} {e['id']}: id used twice")
        out[e["id"]] = e
    return out


def _annotation_name(k: int, ann: dict) -> str:
    return f"annotation {ann['id']}" if _is_id(ann.get("id")) else f"annotation #{k}"


def is_crowd(ann: dict) -> bool:
    """A crowd region (`iscrowd: 1`): many objects under one outline, not one object's box."""
    return ann.get("iscrowd") in (1, True)


def category_classes(path: Path, categories: dict, used: set, mapping: Mapping[str, str | None],
                     classes: Sequence[str]) -> dict:
    """{category id: our class name or None (left out)} for the categories annotations use."""
    unknown_maps = [n for n in mapping if n not in {str(c.get("name")) for c in categories.values()}]
    if unknown_maps:
        names = sorted(str(c.get("name")) for c in categories.values())
        raise DatasetError(f"{path}: --map names categories {unknown_maps} the file does not have ({names})")
    out = {}
    for cid in sorted(used, key=str):
        name = str(categories[cid].get("name", ""))
        if name in mapping:
            ours = mapping[name]
        elif name in classes:
            ours = name
        else:
            raise DatasetError(
                f"{path}: category {cid} {name!r} maps to none of our classes {list(classes)}; "
                f"give --map '{name}=<class>' (or --map '{name}=' to leave it out)"
            )
        if ours is not None and ours not in classes:
            raise DatasetError(f"{path}: --map {name}={ours}: {ours!r} is not one of our classes "
                               f"{list(classes)}")
        out[cid] = ours
    return out


def find_image(path: Path, images_dir: Path, image: dict) -> Path:
    """The image file: images_dir/file_name, else images_dir/<its base name> (Label Studio and CVAT
    prefix folders such as `images/` or `/data/upload/3/`); never a file outside images_dir."""
    name = image.get("file_name")
    if not isinstance(name, str) or not name:
        raise DatasetError(f"{path}: image {image['id']}: no file_name")
    if ".." in Path(name).parts:
        raise DatasetError(f"{path}: image {image['id']} ({name!r}): the file name climbs out of "
                           f"{images_dir} (images are read only from the images folder)")
    root = images_dir.resolve()
    for candidate in (images_dir / name.lstrip("/"), images_dir / Path(name).name):
        if candidate.is_file():
            if not candidate.resolve().is_relative_to(root):
                raise DatasetError(f"{path}: image {image['id']} ({name!r}): {candidate} is a link to a file "
                                   f"outside {images_dir} (images are read only from the images folder)")
            return candidate
    raise DatasetError(f"{path}: image {image['id']} ({name!r}): not found in {images_dir}")


def yolo_box(path: Path, ann: dict, width: int, height: int) -> tuple[float, float, float, float]:
    """COCO [x, y, w, h] (pixels, top-left) -> (cx, cy, w, h) in pixels, clipped to the image."""
    where = f"{path}: annotation {ann.get('id')}"
    bbox = ann.get("bbox")
    if not isinstance(bbox, list) or len(bbox) != 4 or not all(isinstance(v, (int, float)) for v in bbox):
        raise DatasetError(f"{where}: bbox must be [x, y, width, height] in pixels, got {bbox!r}")
    x, y, w, h = (float(v) for v in bbox)
    if not all(math.isfinite(v) for v in (x, y, w, h)) or w <= 0 or h <= 0:
        raise DatasetError(f"{where}: bbox {bbox} has a non-finite value or no area")
    s = EDGE_SLACK_PX
    if x < -s or y < -s or x + w > width + s or y + h > height + s:
        raise DatasetError(f"{where}: bbox {bbox} extends outside its {width}x{height} image")
    x1, y1, x2, y2 = max(x, 0.0), max(y, 0.0), min(x + w, float(width)), min(y + h, float(height))
    if x2 - x1 <= 0 or y2 - y1 <= 0:
        raise DatasetError(f"{where}: bbox {bbox} has no area inside its {width}x{height} image")
    return (x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1


def _image_size(path: Path, image: dict, file: Path) -> tuple[int, int]:
    """(width, height) from the COCO entry, checked against the file."""
    actual = image_size(file)
    listed = (image.get("width"), image.get("height"))
    if all(isinstance(v, int) and v > 0 for v in listed) and tuple(listed) != actual:
        raise DatasetError(f"{path}: image {image['id']} ({file.name}): listed as {listed[0]}x{listed[1]}, "
                           f"the file is {actual[0]}x{actual[1]}")
    return actual


def _copy(src: Path, dst: Path) -> None:
    """Copy, refusing to replace a different file that is already there."""
    if dst.exists():
        if dst.read_bytes() != src.read_bytes():
            raise DatasetError(f"{dst}: exists with other contents (import into another --out or --split)")
        return
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src, dst)


def _write_label(path: Path, lines: list[str]) -> None:
    text = "".join(line + "\n" for line in lines)
    if path.exists() and path.read_text(encoding="utf-8") != text:
        raise DatasetError(f"{path}: exists with other labels (import into another --out or --split)")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def _check_out(out: Path, classes: Sequence[str]) -> list[str]:
    """The splits an existing dataset at `out` already has (its classes must be ours)."""
    if not (out / "data.yaml").is_file():
        return []
    existing = load_data_config(out)
    if existing.names != list(classes):
        raise DatasetError(f"{out / 'data.yaml'}: names {existing.names}, the import's classes are "
                           f"{list(classes)}")
    return list(existing.splits)


def import_coco(annotations: str | os.PathLike, images_dir: str | os.PathLike, out: str | os.PathLike,
                classes: Sequence[str], mapping: Mapping[str, str | None] | None = None,
                split: str = "train") -> CocoImport:
    """Convert a COCO annotation file and its images into the YOLO dataset at `out` (split `split`)."""
    path, images_dir, out = Path(annotations), Path(images_dir), Path(out)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if not images_dir.is_dir():
        raise DatasetError(f"{images_dir}: image folder not found")
    doc = _load(path)
    images = _entries_by_id(path, doc["images"], "image")
    categories = _entries_by_id(path, doc["categories"], "category")
    anns = doc.get("annotations", [])
    by_image: dict = {i: [] for i in images}
    report = CocoImport()
    for k, ann in enumerate(anns):
        if not isinstance(ann, dict):
            raise DatasetError(f"{path}: annotation #{k} is not an object")
        where = f"{path}: {_annotation_name(k, ann)}"
        for key in ("image_id", "category_id"):
            if not _is_id(ann.get(key)):
                raise DatasetError(f"{where}: {key} must be an integer or a string, got "
                                   f"{type(ann.get(key)).__name__}")
        if ann["image_id"] not in images:
            raise DatasetError(f"{where}: image_id {ann['image_id']!r} is not in 'images'")
        if ann["category_id"] not in categories:
            raise DatasetError(f"{where}: category_id {ann['category_id']!r} is not in 'categories'")
        if is_crowd(ann):
            report.crowd[str(categories[ann["category_id"]].get("name"))] += 1
            continue
        by_image[ann["image_id"]].append(ann)
    used = {a["category_id"] for boxes in by_image.values() for a in boxes}
    ours = category_classes(path, categories, used, mapping or {}, classes)
    present = _check_out(out, classes)
    stems: dict[str, object] = {}
    for image_id, image in images.items():  # everything is checked before anything is written
        file = find_image(path, images_dir, image)
        if file.stem in stems:
            raise DatasetError(f"{path}: images {stems[file.stem]} and {image_id} are both named "
                               f"{file.stem!r}")
        stems[file.stem] = image_id
        image["_file"], image["_size"] = file, _image_size(path, image, file)
        image["_boxes"] = [(ours[a["category_id"]], yolo_box(path, a, *image["_size"]), a)
                           for a in by_image[image_id]]
    for image in images.values():
        w, h = image["_size"]
        lines = []
        for name, (cx, cy, bw, bh), ann in image["_boxes"]:
            if name is None:
                report.left_out[str(categories[ann["category_id"]].get("name"))] += 1
                continue
            lines.append(format_label_line(classes.index(name), cx, cy, bw, bh, w, h))
            report.per_class[name] += 1
        file = image["_file"]
        _copy(file, out / "images" / split / file.name)
        _write_label(out / "labels" / split / f"{file.stem}.txt", lines)
        report.images += 1
        report.boxes += len(lines)
        report.backgrounds += not lines
    write_data_config(out, classes, sorted(set(present) | {split}, key=SPLITS.index))
    return report

"""Frames from a camera saved as the skeleton of a YOLO dataset, for labelling (no rclpy; the node is
`capture_node.py`).

DIR/images/<split>/frame_NNNNNN.png for every saved frame, an empty DIR/labels/<split>/ for the
labelling tool's output, DIR/data.yaml naming the catalogue's classes, and DIR/contact_sheet.png with
every frame of the session as a thumbnail. A folder that already holds frames is added to: numbering
continues after the last one, nothing is overwritten.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from vla_detector_training.dataset import SPLITS, DatasetError, load_data_config, write_data_config

THUMB_WIDTH = 160
SHEET_COLUMNS = 6
_FRAME = re.compile(r"frame_(\d+)\.png$")


class CaptureSession:
    """Saves at most `count` frames, at least `every_s` seconds apart, into the dataset at `out`."""

    def __init__(self, out: str | os.PathLike, count: int, every_s: float, classes: Sequence[str],
                 split: str = "train"):
        if count < 1 or not (math.isfinite(every_s) and every_s >= 0):
            raise ValueError(f"count must be >= 1 and every >= 0 s, got {count} and {every_s}")
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        self.out, self.count, self.every_s, self.split = Path(out), count, every_s, split
        self.images = self.out / "images" / split
        self.saved: list[Path] = []
        self._last_t: float | None = None
        self._next = self._prepare(list(classes))

    def _prepare(self, classes: list[str]) -> int:
        """Create the skeleton; the index of the first new frame."""
        if (self.out / "data.yaml").is_file():
            existing = load_data_config(self.out)
            if existing.names != classes:
                raise DatasetError(f"{self.out / 'data.yaml'}: names {existing.names}, the catalogue's "
                                   f"classes are {classes}")
            splits = set(existing.splits) | {self.split}
        else:
            splits = {self.split}
        self.images.mkdir(parents=True, exist_ok=True)
        (self.out / "labels" / self.split).mkdir(parents=True, exist_ok=True)
        write_data_config(self.out, classes, [s for s in SPLITS if s in splits])
        taken = [int(m.group(1)) for p in self.images.iterdir() if (m := _FRAME.match(p.name))]
        return max(taken, default=-1) + 1

    @property
    def done(self) -> bool:
        return len(self.saved) >= self.count

    def offer(self, rgb: np.ndarray, t_s: float) -> Path | None:
        """Save `rgb` (H, W, 3 uint8) when the session wants a frame at time `t_s`; its path, or None."""
        if self.done or (self._last_t is not None and t_s - self._last_t < self.every_s):
            return None
        path = self.images / f"frame_{self._next:06d}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
            raise DatasetError(f"{path}: could not write the frame")
        self._next += 1
        self._last_t = t_s
        self.saved.append(path)
        return path

    def write_contact_sheet(self) -> Path | None:
        """DIR/contact_sheet.png: this session's frames as numbered thumbnails (None when none)."""
        if not self.saved:
            return None
        path = self.out / "contact_sheet.png"
        cv2.imwrite(str(path), contact_sheet([cv2.imread(str(p)) for p in self.saved],
                                             [p.stem for p in self.saved]))
        return path


def contact_sheet(images_bgr: Sequence[np.ndarray], labels: Sequence[str], thumb_width: int = THUMB_WIDTH,
                  columns: int = SHEET_COLUMNS) -> np.ndarray:
    """Thumbnails in rows of `columns`, each with its label in the corner (BGR, for cv2.imwrite)."""
    h0, w0 = images_bgr[0].shape[:2]
    tw, th = thumb_width, max(1, round(thumb_width * h0 / w0))
    cols = min(columns, len(images_bgr))
    rows = math.ceil(len(images_bgr) / cols)
    sheet = np.full((rows * th, cols * tw, 3), 255, np.uint8)
    for i, (img, label) in enumerate(zip(images_bgr, labels)):
        r, c = divmod(i, cols)
        thumb = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
        cv2.putText(thumb, label.removeprefix("frame_"), (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 2)
        cv2.putText(thumb, label.removeprefix("frame_"), (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (255, 255, 255), 1)
        sheet[r * th : (r + 1) * th, c * tw : (c + 1) * tw] = thumb
    return sheet

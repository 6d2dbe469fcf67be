"""Turn raw detector outputs into boxes: letterboxing, output layouts, score filter, NMS.

Pure NumPy + OpenCV (no torch), shared by the run-time Detector and the evaluation. Layouts:

- ``yolov8``: ``[1, 4 + nc, N]`` — cx, cy, w, h in input pixels, then per-class scores in [0, 1].
  Ultralytics YOLOv8/11 exports and our own models (model.ExportWrapper) use it.
- ``yolov5``: ``[1, N, 5 + nc]`` — cx, cy, w, h, objectness, per-class probabilities (score =
  objectness x class probability), as Ultralytics YOLOv5 exports it.

NMS is OpenCV's (`cv2.dnn.NMSBoxesBatched`, per class), not a hand-written loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

LAYOUTS = ("yolov8", "yolov5")
PAD_VALUE = 114  # Ultralytics' letterbox grey
MAX_NMS_CANDIDATES = 3000


class DecodeError(ValueError):
    """The model output does not have a shape any supported layout explains."""


@dataclass
class Letterbox:
    """How an image was fitted into the model input: input = image * scale + (pad_x, pad_y)."""

    scale: float
    pad_x: float
    pad_y: float

    def to_image(self, boxes_cxcywh: np.ndarray) -> np.ndarray:
        """Boxes (N, 4) cx, cy, w, h in model-input pixels -> pixels of the original image."""
        out = boxes_cxcywh.astype(np.float64, copy=True)
        out[:, 0] = (out[:, 0] - self.pad_x) / self.scale
        out[:, 1] = (out[:, 1] - self.pad_y) / self.scale
        out[:, 2:4] /= self.scale
        return out


def letterbox(rgb: np.ndarray, width: int, height: int) -> tuple[np.ndarray, Letterbox]:
    """Resize keeping the aspect ratio and pad (centred) to width x height. Identity if sizes match."""
    h, w = rgb.shape[:2]
    if (w, h) == (width, height):
        return rgb, Letterbox(1.0, 0.0, 0.0)
    scale = min(width / w, height / h)
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(rgb, (nw, nh), interpolation=interp)
    if (nw, nh) == (width, height):
        return resized, Letterbox(scale, 0.0, 0.0)
    left, top = (width - nw) // 2, (height - nh) // 2
    out = np.full((height, width, 3), PAD_VALUE, dtype=np.uint8)
    out[top : top + nh, left : left + nw] = resized
    return out, Letterbox(scale, float(left), float(top))


def to_input_tensor(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (1, 3, H, W) float32 in [0, 1], the input every YOLO export expects."""
    x = np.ascontiguousarray(rgb.transpose(2, 0, 1), dtype=np.float32)
    x *= 1.0 / 255.0
    return x[None]


def infer_layout(shape: tuple[int, ...], num_classes: int | None = None) -> tuple[str, int]:
    """Guess (layout, num_classes) from an output shape [1, a, b]; class count disambiguates."""
    if len(shape) != 3 or shape[0] != 1:
        raise DecodeError(f"model output shape {tuple(shape)} is not [1, a, b] (a YOLOv5 or YOLOv8 export)")
    _, a, b = (int(s) for s in shape)
    if num_classes is not None:
        v8, v5 = a == 4 + num_classes, b == 5 + num_classes
        if v8 and not v5:
            return "yolov8", num_classes
        if v5 and not v8:
            return "yolov5", num_classes
        if not v8 and not v5:
            raise DecodeError(
                f"model output shape {tuple(shape)} fits neither [1, 4+nc, N] (YOLOv8) nor [1, N, 5+nc] "
                f"(YOLOv5) with nc={num_classes} class names"
            )
    # Ambiguous or unknown nc: the anchor/cell count N is far larger than the channel count.
    if a < b:
        if a < 5:
            raise DecodeError(f"model output shape {tuple(shape)}: too few channels for a YOLOv8 layout")
        return "yolov8", a - 4
    if b < 6:
        raise DecodeError(f"model output shape {tuple(shape)}: too few channels for a YOLOv5 layout")
    return "yolov5", b - 5


def candidates(output: np.ndarray, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw output -> (boxes (N, 4) cx, cy, w, h, class scores (N, nc))."""
    out = np.asarray(output, dtype=np.float32)
    if out.ndim == 3:
        out = out[0]
    if layout == "yolov8":
        out = out.T
        return out[:, :4], out[:, 4:]
    if layout == "yolov5":
        return out[:, :4], out[:, 5:] * out[:, 4:5]
    raise DecodeError(f"unknown output layout {layout!r} (known: {', '.join(LAYOUTS)})")


def nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    class_ids: np.ndarray,
    iou_threshold: float,
    max_detections: int,
    agnostic: bool = False,
) -> np.ndarray:
    """Indices kept by OpenCV's NMS (per class unless agnostic), best first, at most max_detections."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    xywh = np.empty((len(boxes), 4), dtype=np.float64)
    xywh[:, 0] = boxes[:, 0] - boxes[:, 2] / 2
    xywh[:, 1] = boxes[:, 1] - boxes[:, 3] / 2
    xywh[:, 2:] = boxes[:, 2:4]
    sc = scores.astype(np.float32)
    if agnostic:
        keep = cv2.dnn.NMSBoxes(xywh, sc, 0.0, float(iou_threshold))
    else:
        keep = cv2.dnn.NMSBoxesBatched(xywh, sc, class_ids.astype(np.int32), 0.0, float(iou_threshold))
    keep = np.asarray(keep, dtype=np.int64).reshape(-1)
    keep = keep[np.argsort(-sc[keep], kind="stable")]
    return keep[: max(0, int(max_detections))]


def postprocess(
    output: np.ndarray,
    layout: str,
    score_threshold: float = 0.3,
    iou_threshold: float = 0.25,
    max_detections: int = 100,
    class_filter: set[int] | None = None,
    agnostic: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw output -> (boxes (K, 4) cx, cy, w, h in input pixels, scores (K,), class indices (K,)).

    Each candidate takes its best class; candidates under score_threshold or outside class_filter
    are dropped before NMS.
    """
    boxes, cls_scores = candidates(output, layout)
    if cls_scores.shape[1] == 0:
        raise DecodeError("model output has no class channels")
    if class_filter is not None:
        mask = np.full(cls_scores.shape[1], -1.0, dtype=np.float32)
        for c in class_filter:
            if 0 <= c < cls_scores.shape[1]:
                mask[c] = 0.0
        cls_scores = np.where(mask >= 0, cls_scores, -1.0)
    cls = cls_scores.argmax(axis=1)
    score = cls_scores[np.arange(len(cls)), cls]
    ok = (score >= score_threshold) & np.isfinite(score) & np.isfinite(boxes).all(axis=1)
    ok &= (boxes[:, 2] > 0) & (boxes[:, 3] > 0)
    idx = np.nonzero(ok)[0]
    if len(idx) > MAX_NMS_CANDIDATES:
        idx = idx[np.argsort(-score[idx])[:MAX_NMS_CANDIDATES]]
    keep = idx[nms(boxes[idx], score[idx], cls[idx], iou_threshold, max_detections, agnostic)]
    return boxes[keep].astype(np.float64), score[keep].astype(np.float64), cls[keep].astype(np.int64)

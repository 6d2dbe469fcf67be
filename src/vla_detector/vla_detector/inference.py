"""Run-time detection with ONNX Runtime. Never imports torch (.importlinter: no torch at run time).

`Detector(model_path)` loads an ONNX detector — ours (with its JSON sidecar) or an Ultralytics
YOLOv5 / YOLOv8 export (class names and input size from the ONNX metadata Ultralytics writes, or a
sidecar) — and `detect(rgb)` returns boxes in pixels of the given image.
"""

from __future__ import annotations

import ast
import json
import os
from pathlib import Path

import numpy as np
import onnxruntime as ort
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from vla_common.detection import Detection

from vla_detector.decode import LAYOUTS, DecodeError, infer_layout, letterbox, postprocess, to_input_tensor

DEFAULT_INPUT_SIZE = (640, 640)  # Ultralytics' default when the model has dynamic input dims


class ModelError(RuntimeError):
    """The model file is missing, unreadable, or not a detector this package can run."""


def sidecar_path(model_path: str | os.PathLike) -> Path:
    return Path(model_path).with_suffix(".json")


def _names_from_metadata(meta: dict[str, str]) -> list[str] | None:
    """Ultralytics writes names as the repr of a dict {0: 'person', ...}; parse it safely."""
    raw = meta.get("names") or meta.get("classes")
    if not raw:
        return None
    try:
        val = json.loads(raw)
    except ValueError:
        try:
            val = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            return None
    if isinstance(val, dict):
        try:
            return [str(val[k]) for k in sorted(val, key=int)]
        except (TypeError, ValueError):
            return None
    if isinstance(val, list):
        return [str(v) for v in val]
    return None


def _size_from_metadata(meta: dict[str, str]) -> tuple[int, int] | None:
    raw = meta.get("imgsz")
    if not raw:
        return None
    try:
        val = ast.literal_eval(raw)
        h, w = (int(val), int(val)) if isinstance(val, int) else (int(val[0]), int(val[1]))
    except (ValueError, SyntaxError, TypeError, IndexError):
        return None
    return w, h


class Detector:
    """ONNX Runtime detector: .classes, .input_size (w, h), .layout, detect(rgb) -> [Detection]."""

    def __init__(
        self,
        model_path: str | os.PathLike,
        score_threshold: float = 0.3,
        iou_threshold: float = 0.25,
        max_detections: int = 100,
        classes: list[str] | None = None,
        num_threads: int = 2,
    ) -> None:
        path = Path(model_path)
        if not path.is_file():
            raise ModelError(f"detector model not found: {path}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = max(1, int(num_threads))
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3
        # Threads sleep instead of spinning between runs: on a shared 2-core CPU spinning doubles the
        # CPU time per frame and makes latency worse, not better.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # ORT raises several exception types for bad files
            raise ModelError(f"cannot load detector model {path}: not a valid ONNX model ({e})") from None
        self.model_path = path
        inputs = self.session.get_inputs()
        outputs = self.session.get_outputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise ModelError(
                f"{path}: expected one image input [1, 3, H, W], got {[i.shape for i in inputs]}"
            )
        self.input_name = inputs[0].name
        meta = dict(self.session.get_modelmeta().custom_metadata_map)
        side = self._read_sidecar(path)

        names = side.get("classes") or _names_from_metadata(meta)
        size = None
        if "input_width" in side and "input_height" in side:
            size = (int(side["input_width"]), int(side["input_height"]))
        _, _, ih, iw = inputs[0].shape
        if size is None and isinstance(iw, int) and isinstance(ih, int) and iw > 0 and ih > 0:
            size = (iw, ih)
        self.input_size: tuple[int, int] = size or _size_from_metadata(meta) or DEFAULT_INPUT_SIZE

        out_shape = outputs[0].shape
        layout = side.get("layout")
        if layout is not None and layout not in LAYOUTS:
            raise ModelError(f"{sidecar_path(path)}: unknown layout {layout!r} (known: {', '.join(LAYOUTS)})")
        if layout is None or any(not isinstance(s, int) for s in out_shape):
            out_shape = self._probe_output_shape()
        try:
            guessed, nc = infer_layout(tuple(out_shape), len(names) if names else None)
        except DecodeError as e:
            raise ModelError(f"{path}: {e}") from None
        self.layout: str = layout or guessed
        if not names:
            names = [f"class{i}" for i in range(nc)]
        if len(names) != nc:
            raise ModelError(f"{path}: model outputs {nc} classes but {len(names)} class names are given")
        self.classes: list[str] = list(names)
        self.score_threshold = float(score_threshold)
        self.iou_threshold = float(iou_threshold)
        self.max_detections = int(max_detections)
        self.class_filter: set[int] | None = None
        self.set_class_filter(classes)

    @staticmethod
    def _read_sidecar(path: Path) -> dict:
        sp = sidecar_path(path)
        if not sp.is_file():
            return {}
        try:
            doc = json.loads(sp.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            raise ModelError(f"{sp}: unreadable model sidecar: {e}") from None
        if not isinstance(doc, dict):
            raise ModelError(f"{sp}: model sidecar must be a JSON object")
        classes = doc.get("classes")
        if classes is not None and (
            not isinstance(classes, list) or not all(isinstance(c, str) for c in classes)
        ):
            raise ModelError(f"{sp}: 'classes' must be a list of names")
        return doc

    def _probe_output_shape(self) -> tuple[int, ...]:
        w, h = getattr(self, "input_size", DEFAULT_INPUT_SIZE)
        x = np.zeros((1, 3, h, w), dtype=np.float32)
        try:
            return tuple(self.session.run(None, {self.input_name: x})[0].shape)
        except Exception as e:
            raise ModelError(f"{self.model_path}: model fails on a {w}x{h} input: {e}") from None

    def set_class_filter(self, classes: list[str] | None) -> None:
        """Keep only these class names (None or empty: all). Unknown names raise ValueError."""
        if not classes:
            self.class_filter = None
            return
        unknown = [c for c in classes if c not in self.classes]
        if unknown:
            raise ValueError(f"unknown class names {unknown}; the model knows {self.classes}")
        self.class_filter = {self.classes.index(c) for c in classes}

    def run_raw(self, rgb: np.ndarray) -> tuple[np.ndarray, object]:
        """Letterbox + run the network: (raw output, Letterbox)."""
        img, lb = letterbox(rgb, *self.input_size)
        out = self.session.run(None, {self.input_name: to_input_tensor(img)})[0]
        return out, lb

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """(H, W, 3) uint8 RGB -> detections, best first, boxes in pixels of this image."""
        if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(
                f"detect() needs an (H, W, 3) uint8 RGB image, got {getattr(rgb, 'shape', type(rgb))}"
            )
        out, lb = self.run_raw(rgb)
        boxes, scores, cls = postprocess(
            out, self.layout, self.score_threshold, self.iou_threshold, self.max_detections, self.class_filter
        )
        boxes = lb.to_image(boxes)
        return [
            Detection(class_id=self.classes[c], score=float(s), cx=float(b[0]), cy=float(b[1]),
                      width=float(b[2]), height=float(b[3]), class_index=int(c))
            for b, s, c in zip(boxes, scores, cls)
        ]


def default_model_path() -> Path:
    """The shipped model: share/vla_detector/models/detector.onnx, else the source tree's copy."""
    try:
        p = Path(get_package_share_directory("vla_detector")) / "models" / "detector.onnx"
        if p.is_file():
            return p
    except PackageNotFoundError:
        pass
    return Path(__file__).resolve().parent.parent / "models" / "detector.onnx"

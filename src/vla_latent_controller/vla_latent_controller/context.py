"""Context encoders' inputs: what the decoder is conditioned on besides the joint state.

Three strategies from the paper (Sec. 4.1):
- ``detector``: a frozen detector's class one-hot ⊕ (x, y) of the box centre normalised by image size.
- ``localization``: a CNN feature of the image ⊕ the oracle class one-hot.
- ``end_to_end``: a CNN feature of the image alone, trained jointly with the autoencoder.

This module is NumPy + OpenCV only (no torch): the runtime controller and the trainer share it, so the
image a CNN sees at run time is prepared exactly as in training.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from vla_common.detection import Detection

ENCODERS = ("detector", "localization", "end_to_end")
CNN_ENCODERS = ("localization", "end_to_end")
CNN_INPUT_SIZE = (64, 48)  # (width, height) of the downscaled image the CNN sees
CNN_FEATURE_DIM = 16

GOAL_SELECTIONS = ("highest_score", "nearest_to_ee")


class ContextError(ValueError):
    """The context cannot be built from the given inputs (unknown class, bad image, ...)."""


def context_dim(encoder: str, num_classes: int, feature_dim: int = CNN_FEATURE_DIM) -> int:
    """Length of the context vector fed to the decoder for ``encoder``."""
    if encoder == "detector":
        return num_classes + 2
    if encoder == "localization":
        return feature_dim + num_classes
    if encoder == "end_to_end":
        return feature_dim
    raise ContextError(f"unknown encoder {encoder!r}; expected one of {ENCODERS}")


def one_hot(class_id: str, classes: Sequence[str]) -> np.ndarray:
    """One-hot of ``class_id`` over ``classes``, resolved by name (never by the detector's index)."""
    try:
        i = list(classes).index(class_id)
    except ValueError:
        raise ContextError(f"class {class_id!r} is not one of the model's classes {list(classes)}") from None
    v = np.zeros(len(classes))
    v[i] = 1.0
    return v


def detector_context(det: Detection, image_size: tuple[int, int], classes: Sequence[str]) -> np.ndarray:
    """one-hot(class) ⊕ (cx / w, cy / h): the paper's structured context."""
    w, h = image_size
    if not (w > 0 and h > 0):
        raise ContextError(f"image size must be positive, got {image_size}")
    x, y = det.cx / w, det.cy / h
    if not (np.isfinite(x) and np.isfinite(y)):
        raise ContextError(f"detection centre is not finite: ({det.cx}, {det.cy})")
    return np.concatenate([one_hot(det.class_id, classes), [x, y]])


def preprocess_image(rgb: np.ndarray, size: tuple[int, int] = CNN_INPUT_SIZE) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (3, h, w) float32 in [0, 1], downscaled with area averaging."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 2 or a.shape[1] < 2:
        raise ContextError(f"expected an (H, W, 3) RGB image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float64)), 0, 255).astype(np.uint8)
    small = cv2.resize(np.ascontiguousarray(a), size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(small.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)


def select_detection(
    dets: Sequence[Detection],
    policy: str,
    classes: Sequence[str] | None = None,
    ee_pixel: tuple[float, float] | None = None,
) -> Detection | None:
    """Pick the goal object among ``dets``.

    ``policy``: ``highest_score``; ``nearest_to_ee`` (box centre closest to the end effector's pixel,
    falls back to the highest score when ``ee_pixel`` is unknown); or a class name (the best-scoring
    detection of that class). When ``classes`` is given only those classes are candidates.
    """
    cands = [d for d in dets if np.isfinite(d.score) and np.isfinite(d.cx) and np.isfinite(d.cy)]
    if classes is not None:
        cands = [d for d in cands if d.class_id in classes]
    if policy not in GOAL_SELECTIONS:
        cands = [d for d in cands if d.class_id == policy]
    if not cands:
        return None
    if policy == "nearest_to_ee" and ee_pixel is not None:
        ex, ey = ee_pixel
        return min(cands, key=lambda d: (d.cx - ex) ** 2 + (d.cy - ey) ** 2)
    return max(cands, key=lambda d: d.score)

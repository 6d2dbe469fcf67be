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
IMAGE_MARGIN = 0.02  # a box centre may lie this share of the image size outside it (rounding at a border)
MAX_IMAGE_SIDE = 16384  # px


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


def detection_problem(det: Detection, image_size: tuple[int, int]) -> str | None:
    """Why `det` cannot be a context in an image of `image_size` (w, h) pixels, or None: a size that is
    no camera's, a value that is not finite, or a box centre outside the image by more than
    IMAGE_MARGIN of its size (a detector's box lies in its image; (1e6, -1e6) px from a peer would
    otherwise be latched and drive the arm)."""
    w, h = image_size
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
        return f"image size must be 1..{MAX_IMAGE_SIDE} px a side, got {w}x{h}"
    if not det.is_finite():
        return f"a {det.class_id} detection is not finite (centre {det.cx}, {det.cy}; score {det.score})"
    mx, my = IMAGE_MARGIN * w, IMAGE_MARGIN * h
    if not (-mx <= det.cx <= w + mx and -my <= det.cy <= h + my):
        return f"a {det.class_id} detection at ({det.cx:.6g}, {det.cy:.6g}) px is outside the {w}x{h} image"
    return None


def detector_context(det: Detection, image_size: tuple[int, int], classes: Sequence[str]) -> np.ndarray:
    """one-hot(class) ⊕ (cx / w, cy / h): the paper's structured context."""
    problem = detection_problem(det, image_size)
    if problem:
        raise ContextError(problem)
    w, h = image_size
    return np.concatenate([one_hot(det.class_id, classes), [det.cx / w, det.cy / h]])


def preprocess_image(rgb: np.ndarray, size: tuple[int, int] = CNN_INPUT_SIZE) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (3, h, w) float32 in [0, 1], downscaled with area averaging."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 2 or a.shape[1] < 2:
        raise ContextError(f"expected an (H, W, 3) RGB image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float64)), 0, 255).astype(np.uint8)
    small = cv2.resize(np.ascontiguousarray(a), size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(small.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)


def candidates(dets: Sequence[Detection], policy: str,
               classes: Sequence[str] | None = None) -> list[Detection]:
    """The detections that may be the goal under ``policy`` (of ``classes`` when given), valid or not."""
    cands = [d for d in dets if classes is None or d.class_id in classes]
    return cands if policy in GOAL_SELECTIONS else [d for d in cands if d.class_id == policy]


def select_detection(
    dets: Sequence[Detection],
    policy: str,
    classes: Sequence[str] | None = None,
    ee_pixel: tuple[float, float] | None = None,
    image_size: tuple[int, int] | None = None,
) -> Detection | None:
    """Pick the goal object among ``dets``.

    ``policy``: ``highest_score``; ``nearest_to_ee`` (box centre closest to the end effector's pixel,
    falls back to the highest score when ``ee_pixel`` is unknown); or a class name (the best-scoring
    detection of that class). When ``classes`` is given only those classes are candidates. A detection
    that is not finite, or (``image_size`` given) not in the image, is never picked.
    """
    cands = [d for d in candidates(dets, policy, classes)
             if (d.is_finite() if image_size is None else detection_problem(d, image_size) is None)]
    if not cands:
        return None
    if policy == "nearest_to_ee" and ee_pixel is not None:
        ex, ey = ee_pixel
        return min(cands, key=lambda d: (d.cx - ex) ** 2 + (d.cy - ey) ** 2)
    return max(cands, key=lambda d: d.score)

"""Demonstrations made ready for training: each gives its context parts (a detection and image size,
or a preprocessed first image) and its joint trajectory; those that cannot are skipped with a reason.
No torch."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.detection import Detection, best
from vla_latent_controller.context import CNN_INPUT_SIZE, ContextError, preprocess_image


@dataclass
class DemoInput:
    """One demo made ready for training: its context parts and joint trajectory."""

    task: str
    class_id: str
    q: np.ndarray
    bag_path: str
    det: Detection | None = None
    image_size: tuple[int, int] | None = None
    image: np.ndarray | None = None  # preprocessed (3, h, w) float32
    # samples of q where the hand starts to close or open (tasks with the hand): training windows
    # do not span them (see hand_cuts)
    cuts: tuple[int, ...] = ()


class SkipError(Exception):
    """Why one demo cannot be used (its message is the reason reported)."""


def default_classes(detector=None, catalogue: Catalogue | None = None) -> list[str]:
    """The model's classes: the detector's when there is one, else the catalogue's."""
    if detector is not None:
        return list(detector.classes)
    return list((catalogue or default_catalogue()).classes)


def prepare_demos(
    demos: Sequence,
    encoder: str,
    classes: Sequence[str],
    detector=None,
    input_size: tuple[int, int] = CNN_INPUT_SIZE,
) -> tuple[list[DemoInput], list[tuple[str, str]]]:
    """Turn dataset Demos into training inputs; demos that cannot give a context are skipped with a reason."""
    kept: list[DemoInput] = []
    skipped: list[tuple[str, str]] = []
    for demo in demos:
        path = str(getattr(demo, "bag_path", "") or demo.task)
        try:
            item = DemoInput(task=demo.task, class_id=demo.object_class, q=_trajectory(demo), bag_path=path,
                             cuts=hand_cuts(demo))
            if encoder == "detector":
                item.det, item.image_size = _detection(demo, classes, detector)
            else:
                item.image = _first_image(demo, encoder, classes, input_size)
        except SkipError as why:
            skipped.append((path, str(why)))
            continue
        kept.append(item)
    return kept, skipped


# GripperStatus states that start a hand motion (vla_interfaces: MOVING = 1 opens or moves, GRASPING = 2)
HAND_MOTION_STATES = (1, 2)


def hand_cuts(demo) -> tuple[int, ...]:
    """The samples of the demo's trajectory at which the hand starts a motion (a grasp, an open).

    A window across one pairs states before the grasp with where the arm is after it, so the decoder
    learns to cut the corner: from 5 pick-and-place demonstrations its path turned up towards the
    carry 1-3 cm short of and above the grasp point, outside the hand's window. Cut there, the
    approach's pairs all lead to the grasp point, and the carry starts from it."""
    t = np.asarray(getattr(demo, "t", ()), dtype=np.float64)
    events = getattr(demo, "grasp_events", None) or ()
    if len(t) < 3:
        return ()
    cuts = {int(np.searchsorted(t, when)) for when, state, _held in events if state in HAND_MOTION_STATES}
    return tuple(sorted(c for c in cuts if 0 < c < len(t) - 1))


def _trajectory(demo) -> np.ndarray:
    q = np.asarray(demo.q, np.float64)
    if q.ndim != 2 or q.shape[1] != 7 or q.shape[0] < 2 or not np.all(np.isfinite(q)):
        raise SkipError(f"joint trajectory has shape {q.shape} or non-finite values")
    return q


def _detection(demo, classes: Sequence[str], detector) -> tuple[Detection, tuple[int, int]]:
    """The demo's recorded detection, else the detector's on its first image; and the image size."""
    recorded = getattr(demo, "detection", None)
    image = getattr(demo, "first_image", None)
    if recorded is not None:
        det = recorded
        size = tuple(int(v) for v in demo.image_size) if demo.image_size else None
    elif image is not None and detector is not None:
        img = np.asarray(image)
        det = best(detector.detect(img), prefer_class=demo.object_class)
        size = (img.shape[1], img.shape[0])
        if det is None:
            raise SkipError("the detector found nothing in the first image")
    else:
        raise SkipError("no recorded detection and no image + --detector-model to detect one")
    if size is None:
        raise SkipError("detection without image size")
    if det.class_id not in classes:
        raise SkipError(f"detected class {det.class_id!r} not in the model's classes")
    return det, size


def _first_image(demo, encoder: str, classes: Sequence[str], input_size: tuple[int, int]) -> np.ndarray:
    """The demo's first image, preprocessed for the CNN encoders."""
    img = getattr(demo, "first_image", None)
    if img is None:
        raise SkipError(f"the {encoder} encoder needs the demo's first image")
    if encoder == "localization" and demo.object_class not in classes:
        raise SkipError(f"class {demo.object_class!r} not in the model's classes")
    try:
        return preprocess_image(np.asarray(img), input_size)
    except ContextError as e:
        raise SkipError(str(e)) from None

"""Test fixtures for anything that uses latent-action models (NumPy only, no simulator, no torch).

- Synthetic demonstrations: each class moves the arm along its own joint direction, shifted with the
  object's position, like a planner's pushes would.
- Random (untrained) model directories in the shipped format, for the controller and its loaders.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vla_common.detection import Detection
from vla_common.robot import JOINT_NAMES, READY_POSE

from vla_latent_controller.artifacts import decoder_tensor_shapes, save_model
from vla_latent_controller.context import context_dim

CLASSES = ("bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box")
READY = np.array(READY_POSE)
IMAGE_SIZE = (640, 480)


@dataclass
class FakeDemo:
    task: str
    object_class: str
    t: np.ndarray
    q: np.ndarray
    first_image: np.ndarray | None
    detection: Detection | None
    image_size: tuple[int, int] | None
    bag_path: str


def class_direction(cls: str) -> np.ndarray:
    rng = np.random.default_rng(CLASSES.index(cls) + 100)
    v = rng.normal(size=7)
    return 0.6 * v / np.linalg.norm(v)


def make_demo(cls: str, rng: np.random.Generator, T: int = 60, with_image: bool = False) -> FakeDemo:
    x, y = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    shift = np.zeros(7)
    shift[0], shift[1] = 0.4 * (y - 0.5), 0.4 * (x - 0.5)
    q0 = READY + rng.normal(0, 0.02, 7)
    s = np.linspace(0, 1, T)
    p = 3 * s**2 - 2 * s**3
    q = q0 + np.outer(p, class_direction(cls) + shift)
    w, h = IMAGE_SIZE
    det = Detection(cls, 0.9, x * w, y * h, 40.0, 40.0, class_index=CLASSES.index(cls))
    img = None
    if with_image:
        img = np.full((h, w, 3), 60, np.uint8)
        colour = np.array([(37 * (i + 1)) % 255 for i in range(3)]) * 0 + 40 * (CLASSES.index(cls) + 1)
        img[int(y * h) - 30 : int(y * h) + 30, int(x * w) - 30 : int(x * w) + 30] = np.clip(colour, 0, 255)
    return FakeDemo(
        task=f"{cls}/push",
        object_class=cls,
        t=np.arange(T) * 0.1,
        q=q,
        first_image=img,
        detection=det,
        image_size=IMAGE_SIZE,
        bag_path="",
    )


def make_demos(classes=CLASSES[:4], per_class: int = 5, seed: int = 0, with_image: bool = False, T: int = 60):
    rng = np.random.default_rng(seed)
    return [make_demo(c, rng, T=T, with_image=with_image) for c in classes for _ in range(per_class)]


def make_pairs(demo, rng, windows: int = 10, sigma: float = 0.01):
    """Contract 7's make_pairs: a = q[t+w] - (q[t] + eps), eps drawn per demo."""
    q = np.asarray(demo.q)
    eps = rng.normal(0, sigma, size=q.shape)
    qs, acts = [], []
    for w in range(1, windows + 1):
        qn = q[:-w] + eps[:-w]
        qs.append(qn)
        acts.append(q[w:] - qn)
    return np.concatenate(qs), np.concatenate(acts)


def random_model_config(encoder: str = "detector", classes=CLASSES, feature_dim: int = 0) -> dict:
    k = context_dim(encoder, len(classes), feature_dim)
    return {
        "encoder": encoder,
        "classes": list(classes),
        "joint_names": list(JOINT_NAMES),
        "dims": {"context": k, "joints": 7, "latent": 1, "hidden": 30, "cnn_feature": feature_dim},
        "normalisation": {"enabled": True, "q_mean": [0.1] * 7, "q_std": [0.5] * 7, "a_scale": [0.2] * 7},
        "latent": {
            "bounded": True,
            "gain": {c: 0.8 for c in classes},
            "default_gain": 0.8,
            "bounds": [-1, 1],
        },
        "hyper_parameters": {},
    }


def write_random_model(path: Path, encoder: str = "detector", classes=CLASSES, seed: int = 0) -> Path:
    cfg = random_model_config(encoder, classes)
    rng = np.random.default_rng(seed)
    tensors = {k: rng.normal(0, 0.5, s).astype(np.float32) for k, s in decoder_tensor_shapes(cfg).items()}
    return save_model(path, cfg, tensors)

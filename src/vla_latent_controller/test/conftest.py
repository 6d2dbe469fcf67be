"""Fixtures: a random (untrained) model directory built with NumPy only, and a small trained one."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from synthetic import CLASSES, make_demos, make_pairs  # noqa: E402
from vla_latent_controller.artifacts import decoder_tensor_shapes, save_model  # noqa: E402
from vla_latent_controller.context import context_dim  # noqa: E402


def random_model_config(encoder: str = "detector", classes=CLASSES, feature_dim: int = 0) -> dict:
    k = context_dim(encoder, len(classes), feature_dim)
    return {
        "encoder": encoder,
        "classes": list(classes),
        "joint_names": [f"panda_joint{i}" for i in range(1, 8)],
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


@pytest.fixture
def random_model_dir(tmp_path) -> Path:
    return write_random_model(tmp_path / "model")


@pytest.fixture(scope="session")
def trained_model_dir(tmp_path_factory) -> Path:
    """A detector-context model trained briefly on synthetic demos (a few seconds)."""
    from vla_latent_controller.train import TrainConfig, train_model

    demos = make_demos(per_class=3, seed=1, T=30)
    res = train_model(
        demos,
        TrainConfig(epochs=80, batch_size=512, seed=0),
        classes=CLASSES,
        pairs_fn=make_pairs,
        progress=False,
        threads=1,
        log=lambda s: None,
    )
    out = tmp_path_factory.mktemp("trained") / "model"
    res.save(out)
    return out

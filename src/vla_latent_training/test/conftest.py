"""Fixtures: a random (untrained) model directory, and a small model trained on synthetic demos."""

from __future__ import annotations

from pathlib import Path

import pytest
from vla_latent_controller.testing import CLASSES, make_demos, make_pairs, write_random_model


@pytest.fixture
def random_model_dir(tmp_path) -> Path:
    return write_random_model(tmp_path / "model")


@pytest.fixture(scope="session")
def trained_model_dir(tmp_path_factory) -> Path:
    """A detector-context model trained briefly on synthetic demos (a few seconds)."""
    from vla_latent_training.train import TrainConfig, train_model  # torch: only where a test trains

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

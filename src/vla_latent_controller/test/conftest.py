"""Fixtures: a random (untrained) model directory built with NumPy only."""

from __future__ import annotations

from pathlib import Path

import pytest
from vla_latent_controller.testing import write_random_model


@pytest.fixture
def random_model_dir(tmp_path) -> Path:
    return write_random_model(tmp_path / "model")

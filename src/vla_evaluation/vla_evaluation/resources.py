"""Where the shipped models live: installed under share/<package>/models, else in the source tree."""
from __future__ import annotations

from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from vla_detector.inference import default_model_path

PACKAGE = "vla_latent_controller"
# the controller package's models/ in the source tree (installed to share/vla_latent_controller/models)
SOURCE_MODELS = Path(__file__).resolve().parents[2] / PACKAGE / "models"


def is_latent_model(d: Path) -> bool:
    """Whether `d` holds a latent-action model: its sealed config.json (the one test of what a model
    directory is, for every tool that refuses or makes a missing model)."""
    return (Path(d) / "config.json").is_file()


def latent_model_dir(name: str = "default") -> Path:
    """The shipped latent-action model directory `name` (may not exist yet); `default` is the
    controller's default: detector encoder trained on the base tasks."""
    try:
        p = Path(get_package_share_directory(PACKAGE)) / "models" / name
        if is_latent_model(p):
            return p
    except PackageNotFoundError:
        pass
    return SOURCE_MODELS / name


def source_model_dir(name: str = "default") -> Path:
    """Where a freshly trained model is written so that it ships with the repository."""
    return SOURCE_MODELS / name


def detector_model_path() -> Path:
    """The shipped detector (vla_detector's models/detector.onnx)."""
    return Path(default_model_path())

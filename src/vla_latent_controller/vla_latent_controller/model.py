"""A trained latent-action model at run time: config + NumPy decoder + (for image encoders) an ONNX CNN.

Imports neither torch nor rclpy. :meth:`LatentModel.context` turns a latched detection and/or image into
the decoder's context vector; :meth:`LatentModel.gain` maps the stick's [-1, 1] onto the latent so that
+1 does the demonstrated task at the demonstrated extent.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnxruntime as ort
from vla_common.detection import Detection

from vla_latent_controller.artifacts import ModelArtifacts, ModelError, load_model
from vla_latent_controller.context import (
    CNN_INPUT_SIZE,
    ContextError,
    detector_context,
    one_hot,
    preprocess_image,
)
from vla_latent_controller.decoder_np import LatentDecoder


class LatentModel:
    """Runtime view of a model directory (see :mod:`vla_latent_controller.artifacts`)."""

    def __init__(self, artifacts: ModelArtifacts):
        self.artifacts = artifacts
        self.config = artifacts.config
        self.encoder = artifacts.encoder
        self.classes = artifacts.classes
        self.joint_names = artifacts.joint_names
        self.decoder = LatentDecoder(artifacts.tensors, self.config)
        self._cnn = None
        self._cnn_input = tuple(self.config.get("cnn_input_size", CNN_INPUT_SIZE))
        if artifacts.cnn_path is not None:
            self._cnn = _cnn_session(artifacts.cnn_path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> LatentModel:
        return cls(load_model(Path(path)))

    @property
    def needs_image(self) -> bool:
        return self._cnn is not None

    @property
    def needs_class(self) -> bool:
        return self.encoder in ("detector", "localization")

    def path_fraction(self, override: float = 0.0) -> float:
        """The command's path fraction (decoder_np.LatentDecoder.velocity): `override` when set (> 0),
        else this model's calibrated latent.path_fraction, else 1 (the paper's command). Measured per
        model because it depends on its demonstrations: 0.65 lets a held stick follow the base tasks'
        corners with `default`, the cereal-box models miss their pushes with it (issue 20)."""
        if override > 0.0:
            return float(override)
        return float(self.config["latent"].get("path_fraction", 1.0))

    def tasks(self) -> dict[str, list[str]]:
        """The tasks the model was taught, by class ({class: [task, ...]}), from its training summary's
        demonstrations per task (the goals the controller's assistance may infer)."""
        names = list(self.config.get("training", {}).get("demos_per_task", {}))
        out: dict[str, list[str]] = {}
        for name in names:
            cls = str(name).split("/", 1)[0]
            out.setdefault(cls, []).append(str(name))
        return out

    def gain(self, class_id: str | None) -> float:
        """Latent per unit of stick for this goal class (sign: + does the task)."""
        lat = self.config["latent"]
        return float(lat.get("gain", {}).get(class_id, lat["default_gain"]))

    def cnn_feature(self, rgb: np.ndarray) -> np.ndarray:
        if self._cnn is None:
            raise ContextError(f"encoder {self.encoder!r} has no CNN")
        x = preprocess_image(rgb, self._cnn_input)[None]
        return np.asarray(self._cnn.run(None, {"image": x})[0][0], np.float64)

    def context(
        self,
        det: Detection | None = None,
        image_size: tuple[int, int] | None = None,
        image: np.ndarray | None = None,
        class_id: str | None = None,
    ) -> np.ndarray:
        """Context vector for this model's encoder; ContextError says what is missing or wrong."""
        if self.encoder == "detector":
            if det is None or image_size is None:
                raise ContextError("the detector encoder needs a detection and the image size")
            return detector_context(det, image_size, self.classes)
        if image is None:
            raise ContextError(f"the {self.encoder} encoder needs a camera image")
        f = self.cnn_feature(image)
        if self.encoder == "end_to_end":
            return f
        cls = class_id if class_id is not None else (det.class_id if det is not None else None)
        if cls is None:
            raise ContextError("the localization encoder needs the goal class (a detection or a fixed class)")
        return np.concatenate([f, one_hot(cls, self.classes)])


def _cnn_session(path: Path) -> ort.InferenceSession:
    """One-thread CPU session of the context CNN; ModelError when the graph does not load."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types for corrupt graphs
        raise ModelError(f"{path}: cannot load the CNN ({e})") from None

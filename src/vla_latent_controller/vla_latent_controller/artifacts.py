"""Model artifacts on disk: weights in safetensors, a JSON config, and an ONNX CNN for image encoders.

No pickle anywhere: loading reads JSON and safetensors (NumPy) only, checks every tensor's shape against
the config and the weights file's sha256, and raises :class:`ModelError` with the reason when anything
is missing, corrupt or inconsistent.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from vla_latent_controller.context import CNN_ENCODERS, ENCODERS, context_dim

FORMAT = "vla_latent_controller/cae"
FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
CNN_FILE = "context_cnn.onnx"


class ModelError(RuntimeError):
    """A model directory cannot be used; the message says why."""


@dataclass
class ModelArtifacts:
    """A loaded model: its config (dict, as in config.json), NumPy tensors and the CNN ONNX path if any."""

    path: Path
    config: dict
    tensors: dict[str, np.ndarray]
    cnn_path: Path | None = None
    extra: dict = field(default_factory=dict)

    @property
    def encoder(self) -> str:
        return self.config["encoder"]

    @property
    def classes(self) -> list[str]:
        return list(self.config["classes"])

    @property
    def joint_names(self) -> list[str]:
        return list(self.config["joint_names"])


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fingerprint_paths(paths: list[str]) -> str:
    """sha256 over the training bags' contents (a bag folder: each file, by relative name, sorted)."""
    h = hashlib.sha256()
    for p in sorted(set(paths)):
        pp = Path(p)
        files = (
            sorted(f for f in pp.rglob("*") if f.is_file()) if pp.is_dir() else [pp] if pp.is_file() else []
        )
        h.update(pp.name.encode())
        for f in files:
            h.update(str(f.relative_to(pp) if pp.is_dir() else f.name).encode())
            h.update(bytes.fromhex(sha256_file(f)))
    return h.hexdigest()


def decoder_tensor_shapes(config: Mapping) -> dict[str, tuple[int, ...]]:
    """The tensors a config promises, with their shapes (decoder and encoder MLPs)."""
    d = config["dims"]
    k, n, zl, hd = d["context"], d["joints"], d["latent"], d["hidden"]
    shapes: dict[str, tuple[int, ...]] = {}
    for name, n_in, n_out in (("decoder", k + n + zl, n), ("encoder", k + 2 * n, zl)):
        shapes[f"{name}.0.weight"] = (hd, n_in)
        shapes[f"{name}.0.bias"] = (hd,)
        shapes[f"{name}.2.weight"] = (hd, hd)
        shapes[f"{name}.2.bias"] = (hd,)
        shapes[f"{name}.4.weight"] = (n_out, hd)
        shapes[f"{name}.4.bias"] = (n_out,)
    return shapes


def save_model(
    out_dir: str | os.PathLike,
    config: dict,
    tensors: Mapping[str, np.ndarray],
    cnn_onnx: str | os.PathLike | None = None,
) -> Path:
    """Write model.safetensors (+ context_cnn.onnx) and config.json (last, with the files' sha256)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    arrays = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}
    save_file(arrays, str(out / WEIGHTS_FILE))
    cfg = dict(config)
    cfg["format"], cfg["format_version"] = FORMAT, FORMAT_VERSION
    files = {"weights": WEIGHTS_FILE, "weights_sha256": sha256_file(out / WEIGHTS_FILE)}
    if cnn_onnx is not None:
        if Path(cnn_onnx).resolve() != (out / CNN_FILE).resolve():
            (out / CNN_FILE).write_bytes(Path(cnn_onnx).read_bytes())
        files["cnn"] = CNN_FILE
        files["cnn_sha256"] = sha256_file(out / CNN_FILE)
    cfg["files"] = files
    tmp = out / (CONFIG_FILE + ".tmp")
    tmp.write_text(json.dumps(cfg, indent=2, allow_nan=False) + "\n")
    tmp.replace(out / CONFIG_FILE)
    return out


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ModelError(msg)


def validate_config(cfg: object, where: str = "config") -> dict:
    """Check the config's structure; returns it. Raises ModelError naming the first problem."""
    _require(isinstance(cfg, dict), f"{where}: expected a JSON object")
    assert isinstance(cfg, dict)
    _require(
        cfg.get("format") == FORMAT, f"{where}: not a latent-action model (format {cfg.get('format')!r})"
    )
    _require(
        cfg.get("format_version") == FORMAT_VERSION,
        f"{where}: format_version {cfg.get('format_version')!r} unsupported (expected {FORMAT_VERSION})",
    )
    for key in ("encoder", "classes", "joint_names", "dims", "normalisation", "latent", "files"):
        _require(key in cfg, f"{where}: missing key {key!r}")
    _require(cfg["encoder"] in ENCODERS, f"{where}: unknown encoder {cfg['encoder']!r}")
    _require(
        isinstance(cfg["classes"], list)
        and all(isinstance(c, str) for c in cfg["classes"])
        and len(cfg["classes"]) > 0,
        f"{where}: 'classes' must be a non-empty list of names",
    )
    dims = cfg["dims"]
    for key in ("context", "joints", "latent", "hidden"):
        _require(
            isinstance(dims.get(key), int) and dims[key] > 0, f"{where}: dims.{key} must be a positive int"
        )
    _require(
        len(cfg["joint_names"]) == dims["joints"],
        f"{where}: {len(cfg['joint_names'])} joint names but dims.joints = {dims['joints']}",
    )
    expect = context_dim(cfg["encoder"], len(cfg["classes"]), dims.get("cnn_feature", 0))
    _require(
        dims["context"] == expect,
        f"{where}: dims.context = {dims['context']} but encoder "
        f"{cfg['encoder']!r} with {len(cfg['classes'])} classes needs {expect}",
    )
    norm = cfg["normalisation"]
    for key in ("q_mean", "q_std", "a_scale"):
        v = norm.get(key)
        _require(
            isinstance(v, list)
            and len(v) == dims["joints"]
            and all(isinstance(x, (int, float)) and math.isfinite(x) for x in v),
            f"{where}: normalisation.{key} must be {dims['joints']} finite numbers",
        )
    _require(
        all(x > 0 for x in norm["q_std"]) and all(x > 0 for x in norm["a_scale"]),
        f"{where}: normalisation scales must be positive",
    )
    lat = cfg["latent"]
    gains = lat.get("gain", {})
    _require(
        isinstance(gains, dict)
        and all(isinstance(v, (int, float)) and math.isfinite(v) and v != 0 for v in gains.values()),
        f"{where}: latent.gain must map class names to finite non-zero numbers",
    )
    dg = lat.get("default_gain")
    _require(
        isinstance(dg, (int, float)) and math.isfinite(dg) and dg != 0,
        f"{where}: latent.default_gain must be a finite non-zero number",
    )
    return cfg


def load_model(path: str | os.PathLike) -> ModelArtifacts:
    """Load a model directory (or its config.json) without pickle; raises ModelError with the reason."""
    p = Path(path)
    if p.is_file() and p.name == CONFIG_FILE:
        p = p.parent
    _require(p.is_dir(), f"model path {str(p)!r} is not a directory")
    cfg_path = p / CONFIG_FILE
    _require(cfg_path.is_file(), f"{cfg_path}: missing (not a trained model directory?)")
    try:
        cfg = json.loads(cfg_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ModelError(f"{cfg_path}: corrupt JSON ({e})") from None
    try:
        validate_config(cfg, str(cfg_path))
    except (KeyError, TypeError, AttributeError) as e:
        raise ModelError(f"{cfg_path}: malformed config ({type(e).__name__}: {e})") from None
    files = cfg["files"]
    w_path = p / str(files.get("weights", WEIGHTS_FILE))
    _require(w_path.is_file(), f"{w_path}: missing")
    want = files.get("weights_sha256")
    if want is not None:
        _require(
            sha256_file(w_path) == want, f"{w_path}: sha256 differs from config.json (corrupt or replaced)"
        )
    try:
        tensors = load_file(str(w_path))
    except (SafetensorError, OSError, ValueError) as e:
        raise ModelError(f"{w_path}: corrupt safetensors file ({e})") from None
    for name, shape in decoder_tensor_shapes(cfg).items():
        _require(name in tensors, f"{w_path}: tensor {name!r} missing")
        _require(
            tuple(tensors[name].shape) == shape,
            f"{w_path}: tensor {name!r} has shape {tuple(tensors[name].shape)}, config says {shape}",
        )
        _require(bool(np.all(np.isfinite(tensors[name]))), f"{w_path}: tensor {name!r} has NaN or Inf")
    cnn_path = None
    if cfg["encoder"] in CNN_ENCODERS:
        _require("cnn" in files, f"{cfg_path}: encoder {cfg['encoder']!r} needs a CNN file (files.cnn)")
        cnn_path = p / str(files["cnn"])
        _require(cnn_path.is_file(), f"{cnn_path}: missing")
        want = files.get("cnn_sha256")
        if want is not None:
            _require(sha256_file(cnn_path) == want, f"{cnn_path}: sha256 differs from config.json")
    return ModelArtifacts(path=p, config=cfg, tensors=dict(tensors), cnn_path=cnn_path)

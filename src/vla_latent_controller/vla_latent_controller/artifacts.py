"""Model artifacts on disk: weights in safetensors, a JSON config, and an ONNX CNN for image encoders.

No pickle anywhere: loading reads JSON and safetensors (NumPy) only and raises :class:`ModelError` with
the reason when anything is missing, corrupt, inconsistent or implausible. config.json is sealed: its
`files.config_sha256` covers every other value in it (the numbers the decoder is folded with, the
weight files' own sha256), so an edit or a corruption is refused, and its numbers must be plausible
(:mod:`.config_check`). Format 1 had no seal: such a model is refused until :func:`reseal_model`
re-saves it (same numbers, checked).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from vla_latent_controller.config_check import ModelError, validate_config
from vla_latent_controller.context import CNN_ENCODERS

FORMAT = "vla_latent_controller/cae"
FORMAT_VERSION = 2  # 2: files.config_sha256 seals config.json; 1: no seal
UNSEALED_VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
CNN_FILE = "context_cnn.onnx"


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


def config_digest(cfg: Mapping) -> str:
    """sha256 of the config's canonical JSON (sorted keys, no spaces) without files.config_sha256."""
    c = dict(cfg)
    c["files"] = {k: v for k, v in dict(c.get("files", {})).items() if k != "config_sha256"}
    text = json.dumps(c, sort_keys=True, separators=(",", ":"), allow_nan=False, ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def seal_config(cfg: Mapping) -> dict:
    """The config as the current format writes it: format, version and files.config_sha256 set."""
    out = dict(cfg)
    out["format"], out["format_version"] = FORMAT, FORMAT_VERSION
    out["files"] = {k: v for k, v in dict(out.get("files", {})).items() if k != "config_sha256"}
    out["files"]["config_sha256"] = config_digest(out)
    return out


def _write_config(out: Path, cfg: Mapping) -> None:
    """Seal and write config.json atomically (a reader never sees half a file)."""
    tmp = out / (CONFIG_FILE + ".tmp")
    tmp.write_text(json.dumps(seal_config(cfg), indent=2, allow_nan=False) + "\n")
    tmp.replace(out / CONFIG_FILE)


def save_model(
    out_dir: str | os.PathLike,
    config: dict,
    tensors: Mapping[str, np.ndarray],
    cnn_onnx: str | os.PathLike | None = None,
) -> Path:
    """Write model.safetensors (+ context_cnn.onnx) and the sealed config.json (last, with the files'
    sha256). ModelError, and nothing written, for a config :func:`validate_config` refuses."""
    out = Path(out_dir)
    validate_config({**config, "files": {}}, "config to save")
    out.mkdir(parents=True, exist_ok=True)
    arrays = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}
    save_file(arrays, str(out / WEIGHTS_FILE))
    cfg = dict(config)
    files = {"weights": WEIGHTS_FILE, "weights_sha256": sha256_file(out / WEIGHTS_FILE)}
    if cnn_onnx is not None:
        if Path(cnn_onnx).resolve() != (out / CNN_FILE).resolve():
            (out / CNN_FILE).write_bytes(Path(cnn_onnx).read_bytes())
        files["cnn"] = CNN_FILE
        files["cnn_sha256"] = sha256_file(out / CNN_FILE)
    cfg["files"] = files
    _write_config(out, cfg)
    return out


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ModelError(msg)


def _model_dir(path: str | os.PathLike) -> Path:
    p = Path(path)
    if p.is_file() and p.name == CONFIG_FILE:
        p = p.parent
    _require(p.is_dir(), f"model path {str(p)!r} is not a directory")
    _require((p / CONFIG_FILE).is_file(), f"{p / CONFIG_FILE}: missing (not a trained model directory?)")
    return p


def _read_config(cfg_path: Path) -> dict:
    """config.json parsed, with its format checked (not yet its seal or numbers)."""
    try:
        cfg = json.loads(cfg_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ModelError(f"{cfg_path}: corrupt JSON ({e})") from None
    _require(isinstance(cfg, dict), f"{cfg_path}: expected a JSON object")
    _require(
        cfg.get("format") == FORMAT, f"{cfg_path}: not a latent-action model (format {cfg.get('format')!r})"
    )
    _require(
        cfg.get("format_version") in (FORMAT_VERSION, UNSEALED_VERSION),
        f"{cfg_path}: format_version {cfg.get('format_version')!r} unsupported (expected {FORMAT_VERSION})",
    )
    _require(isinstance(cfg.get("files"), dict), f"{cfg_path}: missing key 'files'")
    return cfg


def _check_seal(cfg: dict, cfg_path: Path) -> None:
    _require(
        cfg["format_version"] == FORMAT_VERSION,
        f"{cfg_path}: format_version {cfg['format_version']} has no checksum over its numbers; check "
        "them and reseal it (vla_latent_controller.artifacts.reseal_model)",
    )
    want = cfg["files"].get("config_sha256")
    _require(
        want is not None and config_digest(cfg) == want,
        f"{cfg_path}: its contents do not match files.config_sha256 (edited by hand or corrupt); "
        "re-save it with save_model",
    )


def _validated(cfg: dict, cfg_path: Path) -> None:
    try:
        validate_config(cfg, str(cfg_path))
    except (KeyError, TypeError, AttributeError) as e:
        raise ModelError(f"{cfg_path}: malformed config ({type(e).__name__}: {e})") from None


def _checked_file(p: Path, files: dict, key: str, default: str | None = None) -> Path:
    """The model file files[key] names, present and matching files[key + '_sha256']."""
    _require(key in files or default is not None, f"{p / CONFIG_FILE}: files.{key} missing")
    f = p / str(files.get(key, default))
    _require(f.is_file(), f"{f}: missing")
    want = files.get(f"{key}_sha256")
    _require(want is not None, f"{p / CONFIG_FILE}: files.{key}_sha256 missing")
    _require(sha256_file(f) == want, f"{f}: sha256 differs from config.json (corrupt or replaced)")
    return f


def _load_tensors(w_path: Path, cfg: Mapping) -> dict[str, np.ndarray]:
    """The weights, each tensor the config promises present, of its shape and finite."""
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
    return dict(tensors)


def load_model(path: str | os.PathLike) -> ModelArtifacts:
    """Load a model directory (or its config.json) without pickle; raises ModelError with the reason."""
    p = _model_dir(path)
    cfg_path = p / CONFIG_FILE
    cfg = _read_config(cfg_path)
    _check_seal(cfg, cfg_path)
    _validated(cfg, cfg_path)
    files = cfg["files"]
    tensors = _load_tensors(_checked_file(p, files, "weights", WEIGHTS_FILE), cfg)
    cnn_path = None
    if cfg["encoder"] in CNN_ENCODERS:
        _require("cnn" in files, f"{cfg_path}: encoder {cfg['encoder']!r} needs a CNN file (files.cnn)")
        cnn_path = _checked_file(p, files, "cnn")
    return ModelArtifacts(path=p, config=cfg, tensors=tensors, cnn_path=cnn_path)


def reseal_model(path: str | os.PathLike) -> Path:
    """Re-save a format-1 model's config.json sealed, changing no number: only format_version and
    files.config_sha256 change. Its numbers and files are checked first (ModelError)."""
    p = _model_dir(path)
    cfg_path = p / CONFIG_FILE
    cfg = _read_config(cfg_path)
    _require(cfg["format_version"] == UNSEALED_VERSION, f"{cfg_path}: already sealed")
    _validated(cfg, cfg_path)
    _load_tensors(_checked_file(p, cfg["files"], "weights", WEIGHTS_FILE), cfg)
    if cfg["encoder"] in CNN_ENCODERS:
        _checked_file(p, cfg["files"], "cnn")
    _write_config(p, cfg)
    return p

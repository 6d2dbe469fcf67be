"""Re-calibrating a trained model's latent without refitting it (torch; never imported by the controller).

What the stick's full deflection means is the calibration's choice, not the networks': the extent is a
percentile (``TrainConfig.gain_percentile``) of the demonstrated pairs' |z|. To change it on a trained
model, its own encoder (kept in the model file) re-encodes the demonstrations' pairs and
``calibrate_latent`` runs as at the end of training. The weights stay bit-identical; the config gets the
new gains, the percentile in ``hyper_parameters`` and, under ``latent.calibrated_on``, the fingerprint
of the bags the calibration read. Detector-encoder models only (the image encoders' contexts need the
CNN's training-time features).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path

import numpy as np
import torch
from vla_latent_controller.artifacts import load_model, save_model
from vla_latent_controller.context import detector_context
from vla_latent_controller.decoder_np import LatentDecoder

from vla_latent_training.cae import CAE
from vla_latent_training.calibrate import calibrate_latent
from vla_latent_training.config import TrainConfig
from vla_latent_training.inputs import prepare_demos
from vla_latent_training.pairs import make_pairs
from vla_latent_training.train import F32, JointScales, PairTensors, _fingerprint, build_pairs


def recipe_of(config: dict) -> TrainConfig:
    """The TrainConfig a model was trained with (its ``hyper_parameters``; defaults for any missing)."""
    hp = config.get("hyper_parameters", {})
    names = {f.name for f in fields(TrainConfig)}
    return TrainConfig(**{k: v for k, v in hp.items() if k in names})


def recalibrate_model(model_dir: str | Path, demos: Sequence, out_dir: str | Path,
                      gain_percentile: float | None = None, detector=None,
                      pairs_fn: Callable | None = None,
                      log: Callable[[str], None] = print) -> Path:
    """Write `model_dir`'s model to `out_dir` with its latent calibrated on `demos` at `gain_percentile`
    (default: TrainConfig's). ValueError for an image-encoder model or no usable demo."""
    art = load_model(model_dir)
    config = copy.deepcopy(art.config)
    cfg = recipe_of(config)
    if cfg.encoder != "detector":
        raise ValueError(f"recalibration needs a detector-encoder model, {model_dir} is {cfg.encoder!r}")
    cfg.gain_percentile = TrainConfig.gain_percentile if gain_percentile is None else float(gain_percentile)
    if not 0.0 < cfg.gain_percentile <= 100.0:
        raise ValueError(f"gain_percentile must be in (0, 100], got {cfg.gain_percentile}")
    classes = config["classes"]
    items, skipped = prepare_demos(demos, cfg.encoder, classes, detector)
    if not items:
        raise ValueError(f"no usable demos ({len(skipped)} skipped)")
    # the training's pairs, with the same noise draws (the forward pairs come first from the seeded rng)
    pairs = build_pairs(items, cfg, pairs_fn or make_pairs, np.random.default_rng(cfg.seed))
    norm = config["normalisation"]
    ctx = np.stack([detector_context(it.det, it.image_size, classes) for it in items])
    n = pairs.n_forward
    cae = CAE(ctx.shape[1], pairs.q.shape[1], 1, config["dims"]["hidden"], bounded=cfg.bounded_latent,
              signed=cfg.reverse_pairs)
    cae.load_state_dict({k: torch.tensor(v) for k, v in art.tensors.items() if not k.startswith("cnn.")})
    # the pairs as training fed them to the encoder, with the model's own normalisation
    data = PairTensors.of(pairs, JointScales(*(np.asarray(norm[k], dtype=float)
                                               for k in ("q_mean", "q_std", "a_scale"))))
    with torch.no_grad():
        d, q, a, sign = data.take(slice(0, n))
        z = cae.encode(torch.tensor(ctx, dtype=F32)[d], q, a, sign).double().numpy()[:, 0]
    latent, lines = calibrate_latent(items, ctx, z, pairs.demo[:n], LatentDecoder(art.tensors, config), cfg)
    latent["calibrated_on"] = {**_fingerprint(items), "demos": len(items), "pairs": int(n)}
    old = config["latent"]["gain"]
    config["latent"] = latent
    config.setdefault("hyper_parameters", {})["gain_percentile"] = cfg.gain_percentile
    config.pop("files", None)
    log(f"recalibrated at the {cfg.gain_percentile:g}th percentile of |z| on {len(items)} demos "
        f"({len(skipped)} skipped), weights unchanged:")
    for line in lines:
        log(line)
    for c, g in sorted(latent["gain"].items()):
        if c in old:
            log(f"  {c:14s} gain {old[c]:+.3f} -> {g:+.3f} ({g / old[c]:.2f}x)")
    return save_model(out_dir, config, art.tensors, art.cnn_path)

"""Training the latent-action CAE from demonstrations (torch; never imported by the controller node).

The paper's recipe (its public code: a 30-30 tanh CAE, Adam lr 0.01, StepLR(400, 0.1), 1000
epochs, ε drawn per demo) with improvements that are on by default and switched off by
``paper_exact``: a z = 0 term (zero stick → zero motion), a tanh-bounded latent, per-joint
normalisation of states and actions, reversed pairs with a direction-signed latent (the stick's −
side retraces the demonstrations; + is "do the task" in every context, even class-blind ones), and
128-unit hidden layers instead of 30 (on 30 demos per object smaller decoders underfit; see
docs/history/training.md). After training the latent's sign is checked and its extent calibrated
per class, so that stick +1 does the demonstrated task over the demonstrated range.

``train_model`` runs the steps in order: prepare_demos (inputs.py) → build_pairs → split_pairs →
joint_scales and context_inputs → fit → fold the context standardisation into the first layers →
calibrate_latent (calibrate.py) → the model's config and the summary.
"""

from __future__ import annotations

import copy
import hashlib
import math
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm
from vla_common.robot import JOINT_NAMES
from vla_latent_controller.artifacts import fingerprint_paths, save_model
from vla_latent_controller.context import (
    CNN_ENCODERS,
    CNN_INPUT_SIZE,
    context_dim,
    detector_context,
    one_hot,
)
from vla_latent_controller.decoder_np import LatentDecoder

from vla_latent_training.cae import CAE, ContextCNN, export_cnn_onnx
from vla_latent_training.calibrate import calibrate_latent
from vla_latent_training.config import (
    A_SCALE_FLOOR,
    Q_STD_FLOOR,
    ZERO_TERM_ROWS,
    TrainConfig,
    position_affine,
    scaled_schedule,
    steps_per_epoch,
)
from vla_latent_training.inputs import DemoInput, default_classes, prepare_demos
from vla_latent_training.pairs import make_pairs

F32 = torch.float32


@dataclass
class TrainResult:
    config: dict
    tensors: dict[str, np.ndarray]
    cnn_onnx: str | None
    summary: list[str]
    skipped: list[tuple[str, str]] = field(default_factory=list)
    history: list[tuple[float, float]] = field(default_factory=list)

    def save(self, out_dir: str | Path) -> Path:
        return save_model(out_dir, self.config, self.tensors, self.cnn_onnx)


# ------------------------------------------------------------------ pairs and their scales
@dataclass
class PairSet:
    """Every training pair: state, action, the demo it came from and its direction (+1 demonstrated,
    -1 reversed). The first ``n_forward`` are the demonstrated ones."""

    q: np.ndarray
    a: np.ndarray
    demo: np.ndarray
    sign: np.ndarray
    n_forward: int
    per_demo: list[int]  # demonstrated pairs of each demo

    def __len__(self) -> int:
        return len(self.q)


class _PairDemo:
    """The minimal Demo view make_pairs needs: one stretch of a demo's trajectory."""

    def __init__(self, item: DemoInput, q: np.ndarray):
        self.task, self.object_class, self.q = item.task, item.class_id, q
        self.t = np.arange(len(q)) * 0.1


def segments(item: DemoInput, cfg: TrainConfig) -> list[np.ndarray]:
    """The stretches of a demo's trajectory that windows may span: split at its hand motions
    (``cfg.hand_segments``; each cut sample ends one stretch and starts the next), else whole; each
    held at its last state for ``cfg.rest_samples`` more samples."""
    bounds = [0, *(item.cuts if cfg.hand_segments else ()), len(item.q) - 1]
    out = [item.q[a:b + 1] for a, b in zip(bounds, bounds[1:]) if b > a]
    if cfg.rest_samples:
        out = [np.vstack([q, np.repeat(q[-1:], cfg.rest_samples, axis=0)]) for q in out]
    return out


def build_pairs(items: Sequence[DemoInput], cfg: TrainConfig, pairs_fn: Callable,
                rng: np.random.Generator) -> PairSet:
    """The demos' pairs (``pairs_fn``, the paper's windows, within each segment), then their
    reverses when configured."""
    qs, acts, demo_of = [], [], []
    for i, item in enumerate(items):
        made = [pairs_fn(_PairDemo(item, q), rng, windows=cfg.windows, sigma=cfg.sigma)
                for q in segments(item, cfg)]
        qn = np.concatenate([np.asarray(m[0], np.float64).reshape(-1, item.q.shape[1]) for m in made])
        a = np.concatenate([np.asarray(m[1], np.float64).reshape(-1, item.q.shape[1]) for m in made])
        qs.append(qn)
        acts.append(a)
        demo_of.append(np.full(len(qn), i))
    q, a, d = np.concatenate(qs), np.concatenate(acts), np.concatenate(demo_of)
    n_forward = len(q)
    s = np.ones(n_forward)
    if cfg.reverse_pairs:  # from where the motion ended, the way back; noise on the state as for forward
        q = np.concatenate([q, q + a + rng.normal(0.0, cfg.sigma, q.shape)])
        a, d, s = np.concatenate([a, -a]), np.concatenate([d, d]), np.concatenate([s, -s])
    if cfg.corrective_copies:  # from beside the path to the same point: a - delta from q + delta
        k = cfg.corrective_copies
        delta = rng.normal(0.0, cfg.corrective_sigma, (k * len(q), q.shape[1]))
        q = np.concatenate([q, np.tile(q, (k, 1)) + delta])
        a = np.concatenate([a, np.tile(a, (k, 1)) - delta])
        d, s = np.tile(d, k + 1), np.tile(s, k + 1)
    if len(q) < 2:
        raise ValueError(f"only {len(q)} state-action pairs: demos too short")
    return PairSet(q, a, d, s, n_forward, [len(x) for x in qs])


def split_pairs(n_pairs: int, val_fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(training, validation) indices: a random ``val_fraction`` held out (none below 20 pairs)."""
    perm = rng.permutation(n_pairs)
    n_val = int(round(val_fraction * n_pairs)) if n_pairs >= 20 else 0
    return perm[n_val:], perm[:n_val]


@dataclass
class JointScales:
    """What states are standardised by and actions divided by (ones and zeros when not normalising)."""

    q_mean: np.ndarray
    q_std: np.ndarray
    a_scale: np.ndarray


def joint_scales(pairs: PairSet, train_idx: np.ndarray, normalise: bool) -> JointScales:
    n = pairs.q.shape[1]
    if not normalise:
        return JointScales(np.zeros(n), np.ones(n), np.ones(n))
    q, a = pairs.q[train_idx], pairs.a[train_idx]
    return JointScales(
        q.mean(0), np.maximum(q.std(0), Q_STD_FLOOR), np.maximum(np.sqrt((a**2).mean(0)), A_SCALE_FLOOR)
    )


@dataclass
class ContextInputs:
    """Per demo, the context's fixed part (detector: one-hot class + (x, y); localization: one-hot;
    end-to-end: nothing), what the whole context is standardised by, and the CNN encoders' images."""

    raw: np.ndarray  # (demos, fixed dims)
    mean: np.ndarray  # (context dims,)
    std: np.ndarray
    images: np.ndarray | None
    standardise: bool  # the fixed part is the whole context (detector) and is trained standardised

    def trained(self) -> np.ndarray:
        return (self.raw - self.mean) / self.std if self.standardise else self.raw


def context_inputs(items: Sequence[DemoInput], cfg: TrainConfig, classes: Sequence[str]) -> ContextInputs:
    k = context_dim(cfg.encoder, len(classes), cfg.feature_dim)
    mean, std = np.zeros(k), np.ones(k)
    if cfg.encoder == "detector":
        raw = np.stack([detector_context(it.det, it.image_size, classes) for it in items])
        if cfg.normalise:
            mean[-2:], std[-2:] = position_affine(raw[:, -2:], cfg.position_scale)
    elif cfg.encoder == "localization":
        raw = np.stack([one_hot(it.class_id, classes) for it in items])
    else:
        raw = np.zeros((len(items), 0), np.float32)
    images = np.stack([it.image for it in items]) if cfg.encoder in CNN_ENCODERS else None
    return ContextInputs(raw, mean, std, images, standardise=cfg.encoder == "detector")


@dataclass
class PairTensors:
    """The pairs as the networks see them: standardised states, scaled actions (float32)."""

    q: torch.Tensor
    a: torch.Tensor
    demo: torch.Tensor
    sign: torch.Tensor  # (N, 1)

    @classmethod
    def of(cls, pairs: PairSet, scales: JointScales, device: torch.device | None = None) -> PairTensors:
        return cls(
            torch.tensor((pairs.q - scales.q_mean) / scales.q_std, dtype=F32, device=device),
            torch.tensor(pairs.a / scales.a_scale, dtype=F32, device=device),
            torch.tensor(pairs.demo, device=device),
            torch.tensor(pairs.sign, dtype=F32, device=device)[:, None],
        )

    def take(self, idx) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(demo, q, a, sign) of the pairs at ``idx``."""
        return self.demo[idx], self.q[idx], self.a[idx], self.sign[idx]


# ------------------------------------------------------------------ the networks and their fit
class Networks:
    """The CAE and, for the image encoders, the CNN whose features lead each demo's context."""

    def __init__(self, cfg: TrainConfig, ctx: ContextInputs, n_joints: int, device: str | None = None):
        torch.manual_seed(cfg.seed)
        self.device = torch.device(device or "cpu")
        self.cae = CAE(len(ctx.mean), n_joints, 1, cfg.hidden, bounded=cfg.bounded_latent,
                       signed=cfg.reverse_pairs).to(self.device)
        self.cnn = ContextCNN(cfg.feature_dim).to(self.device) if cfg.encoder in CNN_ENCODERS else None
        self.static = torch.tensor(ctx.trained(), dtype=F32, device=self.device)
        self.images = torch.tensor(ctx.images, device=self.device) if ctx.images is not None else None

    def contexts(self) -> torch.Tensor:
        """Every demo's context (with a CNN, computed from the images, so gradients reach it)."""
        if self.cnn is None:
            return self.static
        return torch.cat([self.cnn(self.images), self.static], dim=1)

    def parameters(self) -> list[torch.nn.Parameter]:
        return list(self.cae.parameters()) + (list(self.cnn.parameters()) if self.cnn is not None else [])

    def train(self, mode: bool) -> None:
        self.cae.train(mode)
        if self.cnn is not None:
            self.cnn.train(mode)

    def snapshot(self) -> tuple[dict, dict | None]:
        cnn = copy.deepcopy(self.cnn.state_dict()) if self.cnn is not None else None
        return copy.deepcopy(self.cae.state_dict()), cnn

    def restore(self, snap: tuple[dict, dict | None]) -> None:
        self.cae.load_state_dict(snap[0])
        if self.cnn is not None:
            self.cnn.load_state_dict(snap[1])

    def fold_context_standardisation(self, ctx: ContextInputs) -> None:
        """From now on the networks take the raw contexts (as the saved decoder does at run time)."""
        _fold_input_affine(self.cae, ctx.mean, ctx.std)
        self.static = torch.tensor(ctx.raw, dtype=F32, device=self.device)

    def encoded_latents(self, data: PairTensors, n_forward: int) -> tuple[np.ndarray, np.ndarray]:
        """(every demo's context, the latent of each demonstrated pair), for the calibration."""
        with torch.no_grad():
            ctx = self.contexts()
            d, q, a, s = data.take(slice(0, n_forward))
            z = self.cae.encode(ctx[d], q, a, s)
        return ctx.double().cpu().numpy(), z.double().cpu().numpy()[:, 0]

    def tensors(self) -> dict[str, np.ndarray]:
        """The CAE's weights, and the CNN's as ``cnn.*`` (kept beside its ONNX export, for inspection
        and fine-tuning)."""
        out = {k: v.detach().cpu().numpy().copy() for k, v in self.cae.state_dict().items()}
        if self.cnn is not None:
            cnn = self.cnn.state_dict().items()
            out.update({f"cnn.{k}": v.detach().cpu().numpy().copy() for k, v in cnn})
        return out


def pair_loss(nets: Networks, cfg: TrainConfig, c, q, a, d) -> torch.Tensor:
    """Reconstruction MSE, plus the z = 0 term (a mean: a subset of the batch estimates it)."""
    mse = torch.nn.functional.mse_loss
    z = nets.cae.encode(c, q, a, d)
    loss = mse(nets.cae.decode(c, q, z), a)
    if cfg.zero_weight > 0:  # zero stick -> zero motion
        m = min(len(q), ZERO_TERM_ROWS)
        zero = nets.cae.decode(c[:m], q[:m], torch.zeros(m, 1, device=q.device))
        loss = loss + cfg.zero_weight * mse(zero, torch.zeros_like(zero))
    return loss


@dataclass
class Fit:
    epochs: int
    best_epoch: int  # 0-based
    history: list[tuple[float, float]]  # (train, validation) loss per epoch
    time_s: float

    @property
    def best_losses(self) -> tuple[float, float]:
        return self.history[self.best_epoch]


def fit(nets: Networks, data: PairTensors, train_idx: np.ndarray, val_idx: np.ndarray, cfg: TrainConfig,
        progress: bool) -> Fit:
    """Adam with a step schedule; the networks end with the epoch of lowest validation loss."""
    epochs, step_size = scaled_schedule(cfg, len(train_idx))
    opt = torch.optim.Adam(nets.parameters(), lr=cfg.lr, fused=True)  # fused: same update, less overhead
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=step_size, gamma=cfg.gamma)
    gen = torch.Generator().manual_seed(cfg.seed)  # on the CPU: the same order on any device
    tr_t, val_t = torch.tensor(train_idx), torch.tensor(val_idx, device=nets.device)
    best_loss, best_epoch, best_state = math.inf, 0, None
    history: list[tuple[float, float]] = []
    t0 = time.perf_counter()
    bar = tqdm(range(epochs), desc=f"train {cfg.encoder}", disable=not progress, leave=False,
               dynamic_ncols=True)
    for epoch in bar:
        train_loss = _train_epoch(nets, data, tr_t, cfg, opt, gen)
        sched.step()
        val_loss = _validation_loss(nets, data, val_t, cfg) if len(val_idx) else train_loss
        history.append((train_loss, val_loss))
        if val_loss < best_loss:
            best_loss, best_epoch, best_state = val_loss, epoch, nets.snapshot()
        if progress and (epoch % 10 == 0 or epoch == epochs - 1):
            bar.set_postfix(train=f"{train_loss:.3g}", val=f"{val_loss:.3g}")
    bar.close()
    elapsed = time.perf_counter() - t0
    if best_state is None:
        raise ValueError(f"training diverged: the validation loss was never finite (last {history[-1]})")
    nets.restore(best_state)
    nets.train(False)
    return Fit(epochs, best_epoch, history, elapsed)


def _train_epoch(nets: Networks, data: PairTensors, tr_t: torch.Tensor, cfg: TrainConfig, opt,
                 gen: torch.Generator) -> float:
    """One pass over the training pairs in a fresh order; the mean training loss."""
    nets.train(True)
    order = tr_t[torch.randperm(len(tr_t), generator=gen)].to(nets.device)
    d, q, a, s = data.take(order)  # one gather per epoch
    fixed = nets.static[d] if nets.cnn is None else None
    total, count = 0.0, 0
    for start in range(0, len(order), cfg.batch_size):
        end = start + cfg.batch_size
        c = fixed[start:end] if fixed is not None else nets.contexts()[d[start:end]]
        loss = pair_loss(nets, cfg, c, q[start:end], a[start:end], s[start:end])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        n = len(q[start:end])
        total += loss.item() * n
        count += n
    return total / max(count, 1)


def _validation_loss(nets: Networks, data: PairTensors, val_t: torch.Tensor, cfg: TrainConfig) -> float:
    nets.train(False)
    with torch.no_grad():
        d, q, a, s = data.take(val_t)
        return float(pair_loss(nets, cfg, nets.contexts()[d], q, a, s))


def _fold_input_affine(model, mean: np.ndarray, std: np.ndarray) -> None:
    """Make the encoder's and decoder's first layers take raw contexts: their first len(mean) inputs
    were trained on (c - mean) / std, so W' = W / std and b' = b - W' mean. The saved model then
    needs no extra normalisation step at run time."""
    device = model.encoder[0].weight.device
    m = torch.tensor(mean, dtype=F32, device=device)
    s = torch.tensor(std, dtype=F32, device=device)
    k = len(mean)
    with torch.no_grad():
        for net in (model.encoder, model.decoder):
            layer = net[0]
            layer.weight[:, :k] /= s
            layer.bias -= layer.weight[:, :k] @ m


# ------------------------------------------------------------------ what is saved and reported
def model_config(cfg: TrainConfig, classes: Sequence[str], ctx: ContextInputs, scales: JointScales,
                 n_joints: int) -> dict:
    """The saved model's config.json, up to the latent calibration and the training facts."""
    config = {
        "encoder": cfg.encoder,
        "classes": list(classes),
        "joint_names": _joint_names(n_joints),
        "dims": {
            "context": len(ctx.mean),
            "joints": n_joints,
            "latent": 1,
            "hidden": cfg.hidden,
            "cnn_feature": cfg.feature_dim if cfg.encoder in CNN_ENCODERS else 0,
        },
        "normalisation": {
            "enabled": cfg.normalise,
            "q_mean": scales.q_mean.tolist(),
            "q_std": scales.q_std.tolist(),
            "a_scale": scales.a_scale.tolist(),
            "context_mean": ctx.mean.tolist(),  # folded into the first layers (they take raw contexts)
            "context_std": ctx.std.tolist(),
        },
        "hyper_parameters": asdict(cfg),
    }
    if cfg.encoder in CNN_ENCODERS:
        config["cnn_input_size"] = list(CNN_INPUT_SIZE)
    return config


def training_facts(items: Sequence[DemoInput], pairs: PairSet, n_train: int, n_val: int, result: Fit,
                   cfg: TrainConfig, skipped: list[tuple[str, str]]) -> dict:
    train_loss, val_loss = result.best_losses
    return {
        "demos": len(items),
        "demos_per_task": dict(Counter(it.task for it in items)),
        "pairs": len(pairs),
        "forward_pairs": pairs.n_forward,
        "train_pairs": n_train,
        "val_pairs": n_val,
        "epochs": result.epochs,
        "optimiser_steps": result.epochs * steps_per_epoch(cfg, n_train),
        "best_epoch": result.best_epoch + 1,
        "train_loss": train_loss,
        "val_loss": val_loss,
        "time_s": result.time_s,
        "skipped": [list(s) for s in skipped],
    }


def summary_lines(cfg: TrainConfig, items: Sequence[DemoInput], pairs: PairSet, n_train: int, n_val: int,
                  result: Fit, calibration: list[str], skipped: list[tuple[str, str]]) -> list[str]:
    by_task = Counter(it.task for it in items)
    pairs_by_task: Counter = Counter()
    for it, n in zip(items, pairs.per_demo):
        pairs_by_task[it.task] += n
    train_loss, val_loss = result.best_losses
    lines = [
        f"Trained {cfg.encoder} CAE [{cfg.mode()}] on {len(items)} demos of {len(by_task)} tasks, "
        f"{len(pairs)} pairs ({n_train} train / {n_val} val), seed {cfg.seed}, {result.epochs} epochs in "
        f"{result.time_s:.1f} s",
    ]
    lines += [f"  {t:32s} {by_task[t]:3d} demos {pairs_by_task[t]:7d} pairs" for t in sorted(by_task)]
    lines += calibration
    lines.append(
        f"  best epoch {result.best_epoch + 1}: train loss {train_loss:.4g}, val loss {val_loss:.4g}"
        + (" (normalised units)" if cfg.normalise else " (rad²)")
    )
    lines += [f"  skipped {p}: {r}" for p, r in skipped]
    return lines


def _joint_names(n: int) -> list[str]:
    return list(JOINT_NAMES) if len(JOINT_NAMES) == n else [f"panda_joint{i}" for i in range(1, n + 1)]


def _fingerprint(items: Sequence[DemoInput]) -> dict:
    """What the model was trained on: a hash of the bags (or, for in-memory demos, of the trajectories)."""
    paths = [it.bag_path for it in items if it.bag_path and Path(it.bag_path).exists()]
    if len(paths) == len(items):
        digest = fingerprint_paths(paths)
    else:
        h = hashlib.sha256()
        for it in sorted(items, key=lambda x: (x.task, x.bag_path)):
            h.update(it.task.encode())
            h.update(np.ascontiguousarray(it.q, np.float64).tobytes())
        digest = h.hexdigest()
    return {"sha256": digest, "bags": sorted({Path(it.bag_path).name for it in items})}


def _export_cnn(cnn: ContextCNN) -> str:
    path = Path(tempfile.mkdtemp(prefix="vla_cnn_")) / "context_cnn.onnx"
    export_cnn_onnx(cnn, str(path))
    return str(path)


# ------------------------------------------------------------------ the whole recipe
def train_model(
    demos: Sequence,
    cfg: TrainConfig,
    classes: Sequence[str] | None = None,
    detector=None,
    pairs_fn: Callable | None = None,
    progress: bool = True,
    threads: int | None = None,
    log: Callable[[str], None] = print,
    device: str | None = None,
) -> TrainResult:
    """Train a CAE on ``demos`` (vla_demo_recorder.dataset.Demo objects) and calibrate its latent.
    ``device``: a torch device to train on ("cuda" on a GPU worker of a sweep; default the CPU)."""
    cfg.validate()
    if threads:
        torch.set_num_threads(threads)
    classes = list(classes) if classes is not None else default_classes(detector)
    items, skipped = prepare_demos(demos, cfg.encoder, classes, detector)
    if not items:
        reasons = "; ".join(f"{p}: {r}" for p, r in skipped[:5])
        raise ValueError(f"no usable demos ({len(skipped)} skipped: {reasons})")
    rng = np.random.default_rng(cfg.seed)
    pairs = build_pairs(items, cfg, pairs_fn or make_pairs, rng)
    train_idx, val_idx = split_pairs(len(pairs), cfg.val_fraction, rng)
    scales = joint_scales(pairs, train_idx, cfg.normalise)
    ctx = context_inputs(items, cfg, classes)
    nets = Networks(cfg, ctx, pairs.q.shape[1], device)
    data = PairTensors.of(pairs, scales, nets.device)
    result = fit(nets, data, train_idx, val_idx, cfg, progress)
    if ctx.standardise:
        nets.fold_context_standardisation(ctx)
    ctx_np, z = nets.encoded_latents(data, pairs.n_forward)
    tensors = nets.tensors()
    config = model_config(cfg, classes, ctx, scales, pairs.q.shape[1])
    config["latent"], calibration = calibrate_latent(
        items, ctx_np, z, pairs.demo[: pairs.n_forward], LatentDecoder(tensors, config), cfg
    )
    config["training"] = training_facts(items, pairs, len(train_idx), len(val_idx), result, cfg, skipped)
    config["fingerprint"] = _fingerprint(items)
    summary = summary_lines(cfg, items, pairs, len(train_idx), len(val_idx), result, calibration, skipped)
    for line in summary:
        log(line)
    cnn_onnx = _export_cnn(nets.cnn.cpu()) if nets.cnn is not None else None
    return TrainResult(config, tensors, cnn_onnx, summary, skipped, result.history)

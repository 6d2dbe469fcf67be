"""Training the latent-action CAE from demonstrations (torch; never imported by the controller node).

The paper's recipe (FACTS.md §2) with improvements that are on by default and switched off by
``paper_exact``: a z = 0 term (zero stick → zero motion), a tanh-bounded latent, per-joint
normalisation of states and actions, reversed pairs with a direction-signed latent (the stick's −
side retraces the demonstrations; + is "do the task" in every context, even class-blind ones), and
128-unit hidden layers instead of 30 (on 30 demos per object smaller decoders underfit: the
simulated teleoperator's success went from 35-100 % per task at 30 units to 70-95 % at 64 and
90-100 % at 128). After
training the latent's sign is checked and its extent calibrated per class, so that stick +1 does the
demonstrated task over the demonstrated range.
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from vla_latent_controller.artifacts import fingerprint_paths, save_model
from vla_latent_controller.context import (
    CNN_ENCODERS,
    CNN_FEATURE_DIM,
    CNN_INPUT_SIZE,
    ENCODERS,
    ContextError,
    Det,
    context_dim,
    detector_context,
    one_hot,
    preprocess_image,
)

from vla_latent_training.pairs import make_pairs

Q_STD_FLOOR = 1e-2  # rad: a joint the demos barely move must not blow up its normalised value
A_SCALE_FLOOR = 1e-3  # rad
CTX_STD_FLOOR = 0.02  # of the image size: demos with the object always in one spot
# The spread of an image coordinate uniform over the image, sqrt(1/12) of its size: a fixed scale
# for the detector context's (x, y) (see position_affine).
POSITION_PRIOR_SCALE = math.sqrt(1.0 / 12.0)
ZERO_TERM_ROWS = 1024  # rows of each batch the z = 0 term is evaluated on


@dataclass
class TrainConfig:
    """Hyper-parameters; the defaults are the paper's plus the improvements (see ``paper()``)."""

    encoder: str = "detector"
    epochs: int = 1000
    lr: float = 0.01
    step_size: int = 400
    gamma: float = 0.1
    batch_size: int = 6000
    val_fraction: float = 0.1
    hidden: int = 128  # the paper: 30
    windows: int = 10
    sigma: float = 0.01
    seed: int = 0
    zero_weight: float = 10.0
    reverse_pairs: bool = True
    bounded_latent: bool = True
    normalise: bool = True
    feature_dim: int = CNN_FEATURE_DIM
    gain_percentile: float = 95.0
    paper_exact: bool = False
    # Optimiser updates at least this many (0: off): epochs (and the lr step) are scaled up for small
    # datasets, where full batches of 6000 pairs leave a few demos with one update per epoch.
    min_steps: int = 0
    # What the detector context's (x, y) are divided by (after subtracting their mean over the demos):
    # None (default) for their spread over the demos, or a fixed scale. See position_affine.
    position_scale: float | None = None

    @classmethod
    def paper(cls, **overrides) -> TrainConfig:
        """Exactly the paper's public code: unbounded latent, raw units, no z = 0 term."""
        kw = dict(
            zero_weight=0.0, reverse_pairs=False, bounded_latent=False, normalise=False, paper_exact=True,
            hidden=30,
        )
        kw.update(overrides)
        return cls(**kw)

    def validate(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"unknown encoder {self.encoder!r}; expected one of {ENCODERS}")
        if self.epochs < 1 or self.batch_size < 1 or self.windows < 1:
            raise ValueError("epochs, batch_size and windows must be >= 1")
        if self.min_steps < 0:
            raise ValueError("min_steps must be >= 0")
        check_position_scale(self.position_scale)
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError("val_fraction must be in [0, 1)")


@dataclass
class DemoInput:
    """One demo made ready for training: its context parts and pairs."""

    task: str
    class_id: str
    q: np.ndarray
    bag_path: str
    det: Det | None = None
    image_size: tuple[int, int] | None = None
    image: np.ndarray | None = None  # preprocessed (3, h, w) float32


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


def default_classes(detector=None) -> list[str]:
    if detector is not None:
        return list(detector.classes)
    from vla_common.objects import OBJECT_CLASSES

    return list(OBJECT_CLASSES)


def _detect(detector, rgb: np.ndarray, want_class: str) -> Det | None:
    dets = [
        Det(
            class_id=d.class_id,
            score=float(d.score),
            cx=float(d.cx),
            cy=float(d.cy),
            width=float(getattr(d, "w", 0.0)),
            height=float(getattr(d, "h", 0.0)),
            class_index=int(getattr(d, "class_index", -1)),
        )
        for d in detector.detect(rgb)
    ]
    same = [d for d in dets if d.class_id == want_class]
    pool = same or dets
    return max(pool, key=lambda d: d.score) if pool else None


def prepare_demos(
    demos: Sequence,
    encoder: str,
    classes: Sequence[str],
    detector=None,
    input_size: tuple[int, int] = CNN_INPUT_SIZE,
) -> tuple[list[DemoInput], list[tuple[str, str]]]:
    """Turn dataset Demos into training inputs; demos that cannot give a context are skipped with a reason."""
    kept: list[DemoInput] = []
    skipped: list[tuple[str, str]] = []
    for demo in demos:
        path = str(getattr(demo, "bag_path", "") or demo.task)
        q = np.asarray(demo.q, np.float64)
        if q.ndim != 2 or q.shape[1] != 7 or q.shape[0] < 2 or not np.all(np.isfinite(q)):
            skipped.append((path, f"joint trajectory has shape {q.shape} or non-finite values"))
            continue
        item = DemoInput(task=demo.task, class_id=demo.object_class, q=q, bag_path=path)
        if encoder == "detector":
            det_d = getattr(demo, "detection", None)
            if det_d is not None:
                item.det = Det.from_dict(det_d)
                item.image_size = tuple(int(v) for v in demo.image_size) if demo.image_size else None
            elif getattr(demo, "first_image", None) is not None and detector is not None:
                img = np.asarray(demo.first_image)
                item.det = _detect(detector, img, demo.object_class)
                item.image_size = (img.shape[1], img.shape[0])
                if item.det is None:
                    skipped.append((path, "the detector found nothing in the first image"))
                    continue
            else:
                skipped.append((path, "no recorded detection and no image + --detector-model to detect one"))
                continue
            if item.image_size is None:
                skipped.append((path, "detection without image size"))
                continue
            if item.det.class_id not in classes:
                skipped.append((path, f"detected class {item.det.class_id!r} not in the model's classes"))
                continue
        else:
            img = getattr(demo, "first_image", None)
            if img is None:
                skipped.append((path, f"the {encoder} encoder needs the demo's first image"))
                continue
            if encoder == "localization" and demo.object_class not in classes:
                skipped.append((path, f"class {demo.object_class!r} not in the model's classes"))
                continue
            try:
                item.image = preprocess_image(np.asarray(img), input_size)
            except ContextError as e:
                skipped.append((path, str(e)))
                continue
        kept.append(item)
    return kept, skipped


def scaled_schedule(cfg: TrainConfig, n_train: int) -> tuple[int, int]:
    """(epochs, lr step in epochs) for `n_train` training pairs: the configured ones, both scaled by
    the same whole factor when that gives fewer than `cfg.min_steps` optimiser updates."""
    per_epoch = max(1, math.ceil(n_train / cfg.batch_size))
    factor = max(1, math.ceil(cfg.min_steps / (cfg.epochs * per_epoch)))
    return cfg.epochs * factor, cfg.step_size * factor


def check_position_scale(scale: float | None) -> None:
    """ValueError unless `scale` is None (the demos' spread) or a finite positive number."""
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"position_scale must be a positive number or None, got {scale}")


def position_affine(xy: np.ndarray, scale: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std) the detector context's normalised (x, y) are standardised by.

    ``scale=None`` (default): the demos' spread, floored at CTX_STD_FLOOR, so position is as loud an
    input as the class and the decoder learns quickly where each object sends the arm. A fixed
    scale (e.g. POSITION_PRIOR_SCALE, the spread of a coordinate over the whole image, about 5x the
    demos') makes position a quieter input: worse when the demos can show what it does (5 planner
    demos per task: less progress toward each layout's hover pose, test_planner_tasks), better with
    one demo per object, where each class's position is a single point, any position effect the
    decoder learns is spurious, and a new layout's position is then extrapolated from (Figure 2a).
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    mean = xy.mean(0)
    std = np.maximum(xy.std(0), CTX_STD_FLOOR) if scale is None else np.full(2, float(scale))
    return mean, std


def _fold_input_affine(model, mean: np.ndarray, std: np.ndarray) -> None:
    """Make the encoder's and decoder's first layers take raw contexts: their first len(mean) inputs
    were trained on (c - mean) / std, so W' = W / std and b' = b - W' mean. The saved model then
    needs no extra normalisation step at run time."""
    import torch

    m = torch.tensor(mean, dtype=torch.float32)
    s = torch.tensor(std, dtype=torch.float32)
    k = len(mean)
    with torch.no_grad():
        for net in (model.encoder, model.decoder):
            layer = net[0]
            layer.weight[:, :k] /= s
            layer.bias -= layer.weight[:, :k] @ m


class _PairDemo:
    """The minimal Demo view make_pairs needs."""

    def __init__(self, item: DemoInput):
        self.task, self.object_class, self.q = item.task, item.class_id, item.q
        self.t = np.arange(len(item.q)) * 0.1


def train_model(
    demos: Sequence,
    cfg: TrainConfig,
    classes: Sequence[str] | None = None,
    detector=None,
    pairs_fn: Callable | None = None,
    progress: bool = True,
    threads: int | None = None,
    log: Callable[[str], None] = print,
) -> TrainResult:
    """Train a CAE on ``demos`` (vla_demo_recorder.dataset.Demo objects) and calibrate its latent."""
    import torch
    from tqdm import tqdm

    from vla_latent_training.cae import CAE, ContextCNN

    cfg.validate()
    if threads:
        torch.set_num_threads(threads)
    classes = list(classes) if classes is not None else default_classes(detector)
    items, skipped = prepare_demos(demos, cfg.encoder, classes, detector)
    if not items:
        reasons = "; ".join(f"{p}: {r}" for p, r in skipped[:5])
        raise ValueError(f"no usable demos ({len(skipped)} skipped: {reasons})")
    pairs_fn = pairs_fn or make_pairs
    rng = np.random.default_rng(cfg.seed)
    Qs, As, Ds = [], [], []
    for i, item in enumerate(items):
        qn, a = pairs_fn(_PairDemo(item), rng, windows=cfg.windows, sigma=cfg.sigma)
        Qs.append(np.asarray(qn, np.float64))
        As.append(np.asarray(a, np.float64))
        Ds.append(np.full(len(qn), i))
    Q, A, D = np.concatenate(Qs), np.concatenate(As), np.concatenate(Ds)
    n_fwd, n_joints = Q.shape
    S = np.ones(n_fwd)
    if cfg.reverse_pairs:  # from where the motion ended, the way back; noise on the state as for forward
        Q = np.concatenate([Q, Q + A + rng.normal(0.0, cfg.sigma, Q.shape)])
        A, D, S = np.concatenate([A, -A]), np.concatenate([D, D]), np.concatenate([S, -S])
    n_pairs = len(Q)
    if n_pairs < 2:
        raise ValueError(f"only {n_pairs} state-action pairs: demos too short")

    perm = rng.permutation(n_pairs)
    n_val = int(round(cfg.val_fraction * n_pairs)) if n_pairs >= 20 else 0
    val_idx, tr_idx = perm[:n_val], perm[n_val:]
    if cfg.normalise:
        q_mean = Q[tr_idx].mean(0)
        q_std = np.maximum(Q[tr_idx].std(0), Q_STD_FLOOR)
        a_scale = np.maximum(np.sqrt((A[tr_idx] ** 2).mean(0)), A_SCALE_FLOOR)
    else:
        q_mean, q_std, a_scale = np.zeros(n_joints), np.ones(n_joints), np.ones(n_joints)

    k = context_dim(cfg.encoder, len(classes), cfg.feature_dim)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    f32 = torch.float32
    model = CAE(k, n_joints, 1, cfg.hidden, bounded=cfg.bounded_latent, signed=cfg.reverse_pairs)
    cnn = ContextCNN(cfg.feature_dim) if cfg.encoder in CNN_ENCODERS else None
    ctx_mean, ctx_std = np.zeros(k), np.ones(k)
    if cfg.encoder == "detector":
        raw = np.stack([detector_context(it.det, it.image_size, classes) for it in items])
        if cfg.normalise:
            ctx_mean[-2:], ctx_std[-2:] = position_affine(raw[:, -2:], cfg.position_scale)
        static = torch.tensor((raw - ctx_mean) / ctx_std, dtype=f32)
    elif cfg.encoder == "localization":
        static = torch.tensor(np.stack([one_hot(it.class_id, classes) for it in items]), dtype=f32)
    else:
        static = torch.zeros(len(items), 0)
    images = torch.tensor(np.stack([it.image for it in items])) if cnn is not None else None

    def contexts() -> torch.Tensor:
        if cnn is None:
            return static
        return torch.cat([cnn(images), static], dim=1)

    Qt = torch.tensor((Q - q_mean) / q_std, dtype=f32)
    At = torch.tensor(A / a_scale, dtype=f32)
    Dt = torch.tensor(D)
    St = torch.tensor(S, dtype=f32)[:, None]
    params = list(model.parameters()) + (list(cnn.parameters()) if cnn is not None else [])
    opt = torch.optim.Adam(params, lr=cfg.lr, fused=True)  # the fused kernel: same update, less overhead
    epochs, step_size = scaled_schedule(cfg, len(tr_idx))
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=step_size, gamma=cfg.gamma)
    mse = torch.nn.functional.mse_loss

    def loss_on(
        c: torch.Tensor, q: torch.Tensor, a: torch.Tensor, d: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        z = model.encode(c, q, a, d)
        rec = mse(model.decode(c, q, z), a)
        loss = rec
        if cfg.zero_weight > 0:  # zero stick -> zero motion (a mean: a subset of the batch estimates it)
            m = min(len(q), ZERO_TERM_ROWS)
            zero = model.decode(c[:m], q[:m], torch.zeros(m, 1))
            loss = loss + cfg.zero_weight * mse(zero, torch.zeros_like(zero))
        return loss, rec

    def loss_idx(idx: torch.Tensor) -> torch.Tensor:
        return loss_on(contexts()[Dt[idx]], Qt[idx], At[idx], St[idx])[0]

    tr_t, val_t = torch.tensor(tr_idx), torch.tensor(val_idx)
    best = (math.inf, 0, None, None)
    history: list[tuple[float, float]] = []
    t0 = time.perf_counter()
    bar = tqdm(
        range(epochs), desc=f"train {cfg.encoder}", disable=not progress, leave=False, dynamic_ncols=True
    )
    for epoch in bar:
        model.train()
        if cnn is not None:
            cnn.train()
        order = tr_t[torch.randperm(len(tr_t), generator=gen)]
        De, Qe, Ae, Se = Dt[order], Qt[order], At[order], St[order]  # one gather per epoch
        Ce = static[De] if cnn is None else None
        total, count = 0.0, 0
        for s in range(0, len(order), cfg.batch_size):
            e = s + cfg.batch_size
            c = Ce[s:e] if Ce is not None else contexts()[De[s:e]]
            loss, _ = loss_on(c, Qe[s:e], Ae[s:e], Se[s:e])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.item() * len(Qe[s:e])
            count += len(Qe[s:e])
        sched.step()
        train_loss = total / max(count, 1)
        model.eval()
        if cnn is not None:
            cnn.eval()
        with torch.no_grad():
            val_loss = float(loss_idx(val_t)) if n_val else train_loss
        history.append((train_loss, val_loss))
        if val_loss < best[0]:
            best = (
                val_loss,
                epoch,
                copy.deepcopy(model.state_dict()),
                copy.deepcopy(cnn.state_dict()) if cnn is not None else None,
            )
        if progress and (epoch % 10 == 0 or epoch == epochs - 1):
            bar.set_postfix(train=f"{train_loss:.3g}", val=f"{val_loss:.3g}")
    bar.close()
    train_time = time.perf_counter() - t0
    model.load_state_dict(best[2])
    if cnn is not None:
        cnn.load_state_dict(best[3])
    model.eval()
    if cnn is not None:
        cnn.eval()
    if cfg.encoder == "detector":  # fold the context standardisation into the first layers
        _fold_input_affine(model, ctx_mean, ctx_std)
        static = torch.tensor(raw, dtype=f32)

    with torch.no_grad():
        ctx_np = contexts().double().numpy()
        fwd = slice(0, n_fwd)
        z_all = model.encode(contexts()[Dt[fwd]], Qt[fwd], At[fwd], St[fwd]).double().numpy()[:, 0]
    tensors = {k_: v.detach().numpy().copy() for k_, v in model.state_dict().items()}
    if cnn is not None:  # kept beside the ONNX export, for inspection and fine-tuning
        tensors.update({f"cnn.{k_}": v.detach().numpy().copy() for k_, v in cnn.state_dict().items()})
    norm = {
        "enabled": cfg.normalise,
        "q_mean": q_mean.tolist(),
        "q_std": q_std.tolist(),
        "a_scale": a_scale.tolist(),
        "context_mean": ctx_mean.tolist(),  # folded into the first layers (they take raw contexts)
        "context_std": ctx_std.tolist(),
    }
    config = {
        "encoder": cfg.encoder,
        "classes": list(classes),
        "joint_names": _joint_names(n_joints),
        "dims": {
            "context": k,
            "joints": n_joints,
            "latent": 1,
            "hidden": cfg.hidden,
            "cnn_feature": cfg.feature_dim if cnn is not None else 0,
        },
        "normalisation": norm,
        "hyper_parameters": asdict(cfg),
    }
    if cnn is not None:
        config["cnn_input_size"] = list(CNN_INPUT_SIZE)
    from vla_latent_controller.decoder_np import LatentDecoder

    decoder = LatentDecoder(tensors, config)
    latent, calib_lines = calibrate_latent(items, ctx_np, z_all, D[:n_fwd], decoder, cfg)
    config["latent"] = latent
    by_task = Counter(it.task for it in items)
    pairs_by_task: Counter = Counter()
    for it, n in zip(items, (len(x) for x in Qs)):
        pairs_by_task[it.task] += n
    config["training"] = {
        "demos": len(items),
        "demos_per_task": dict(by_task),
        "pairs": int(n_pairs),
        "forward_pairs": int(n_fwd),
        "train_pairs": len(tr_idx),
        "val_pairs": int(n_val),
        "epochs": epochs,
        "optimiser_steps": epochs * max(1, math.ceil(len(tr_idx) / cfg.batch_size)),
        "best_epoch": best[1] + 1,
        "train_loss": history[best[1]][0],
        "val_loss": history[best[1]][1],
        "time_s": train_time,
        "skipped": [list(s) for s in skipped],
    }
    config["fingerprint"] = {
        "sha256": _fingerprint(items),
        "bags": sorted({Path(it.bag_path).name for it in items}),
    }
    cnn_path = None
    if cnn is not None:
        import tempfile

        from vla_latent_training.cae import export_cnn_onnx

        cnn_path = str(Path(tempfile.mkdtemp(prefix="vla_cnn_")) / "context_cnn.onnx")
        export_cnn_onnx(cnn, cnn_path)

    mode = (
        "paper-exact"
        if cfg.paper_exact
        else "improved: "
        + ", ".join(
            n
            for n, on in (
                ("z=0 term", cfg.zero_weight > 0),
                ("tanh latent", cfg.bounded_latent),
                ("normalised", cfg.normalise),
                ("reversed pairs", cfg.reverse_pairs),
            )
            if on
        )
    )
    summary = [
        f"Trained {cfg.encoder} CAE [{mode}] on {len(items)} demos of {len(by_task)} tasks, {n_pairs} pairs "
        f"({len(tr_idx)} train / {n_val} val), seed {cfg.seed}, {epochs} epochs in {train_time:.1f} s",
    ]
    for task in sorted(by_task):
        summary.append(f"  {task:32s} {by_task[task]:3d} demos {pairs_by_task[task]:7d} pairs")
    summary += calib_lines
    summary.append(
        f"  best epoch {best[1] + 1}: train loss {history[best[1]][0]:.4g}, "
        f"val loss {history[best[1]][1]:.4g}" + (" (normalised units)" if cfg.normalise else " (rad²)")
    )
    for p, r in skipped:
        summary.append(f"  skipped {p}: {r}")
    for line in summary:
        log(line)
    return TrainResult(
        config=config, tensors=tensors, cnn_onnx=cnn_path, summary=summary, skipped=skipped, history=history
    )


def _joint_names(n: int) -> list[str]:
    try:
        from vla_common.robot import JOINT_NAMES

        if len(JOINT_NAMES) == n:
            return list(JOINT_NAMES)
    except ImportError:
        pass
    return [f"panda_joint{i}" for i in range(1, n + 1)]


def _fingerprint(items: Sequence[DemoInput]) -> str:
    paths = [it.bag_path for it in items if it.bag_path and Path(it.bag_path).exists()]
    if len(paths) == len(items):
        return fingerprint_paths(paths)
    import hashlib

    h = hashlib.sha256()
    for it in sorted(items, key=lambda x: (x.task, x.bag_path)):
        h.update(it.task.encode())
        h.update(np.ascontiguousarray(it.q, np.float64).tobytes())
    return h.hexdigest()


def demonstrated_direction(q: np.ndarray, horizon: int = 10, starts: int = 5) -> np.ndarray:
    """Mean joint displacement over ``horizon`` samples from the first ``starts`` states of a demo."""
    T = len(q)
    h = min(horizon, T - 1)
    n = max(1, min(starts, T - h))
    return np.mean([q[t + h] - q[t] for t in range(n)], axis=0)


def calibrate_latent(
    items: Sequence[DemoInput],
    ctx: np.ndarray,
    z: np.ndarray,
    demo_of_pair: np.ndarray,
    decoder,
    cfg: TrainConfig,
) -> tuple[dict, list[str]]:
    """Per-class gain: sign so that +1 moves like the demos' start, extent = the demos' latent range.

    The sign is fixed by decoding from each demo's start state and comparing with the demonstrated
    direction (cosine); the extent is the ``gain_percentile`` of |z| on the demonstrated side (1.0 for the
    paper's unbounded latent, which the paper drives with the raw stick).
    """
    by_class: dict[str, list[int]] = defaultdict(list)
    for i, it in enumerate(items):
        by_class[it.class_id].append(i)
    gains: dict[str, float] = {}
    lines: list[str] = []
    checks: dict[str, tuple[int, int, float]] = {}
    weighted_sign = 0.0
    for cls, idxs in sorted(by_class.items()):
        zc = z[np.isin(demo_of_pair, idxs)]
        side = 1.0 if np.median(zc) >= 0 else -1.0
        on_side = np.abs(zc[zc * side > 0])
        extent = (
            float(np.percentile(on_side, cfg.gain_percentile)) if len(on_side) else float(np.max(np.abs(zc)))
        )
        if not cfg.bounded_latent and cfg.paper_exact:
            extent = 1.0
        extent = max(extent, 1e-3)
        cos = _decode_cosines(items, idxs, ctx, decoder, side * extent)
        if np.sum(cos) < 0:
            side = -side
            cos = -cos
        gains[cls] = side * extent
        checks[cls] = (int(np.sum(cos > 0)), len(idxs), float(np.mean(cos)))
        weighted_sign += side * len(idxs)
        lines.append(
            f"  latent {cls:14s} gain {gains[cls]:+.3f}  decode(+1) agrees with demos "
            f"{checks[cls][0]}/{checks[cls][1]} (mean cos {checks[cls][2]:.2f})"
        )
    global_sign = 1.0 if weighted_sign >= 0 else -1.0
    extents = [abs(g) for g in gains.values()]
    default_gain = global_sign * float(np.median(extents))
    disagree = [c for c, g in gains.items() if np.sign(g) != global_sign]
    if disagree:
        lines.append(
            f"  note: latent sign differs between classes ({', '.join(disagree)} flipped); "
            "a class-blind encoder uses the majority sign"
        )
    z_lo, z_hi = float(np.min(z)), float(np.max(z))
    latent = {
        "bounded": cfg.bounded_latent,
        "gain": gains,
        "default_gain": default_gain,
        "bounds": [z_lo, z_hi],
        "decode_check": {c: list(v) for c, v in checks.items()},
    }
    return latent, lines


def _decode_cosines(items, idxs, ctx, decoder, zval) -> np.ndarray:
    out = []
    for i in idxs:
        ref = demonstrated_direction(items[i].q)
        decoder.set_context(ctx[i])
        a = decoder.decode(items[i].q[0], zval).copy()
        den = float(np.linalg.norm(a) * np.linalg.norm(ref))
        out.append(float(a @ ref) / den if den > 1e-12 else 0.0)
    return np.asarray(out)

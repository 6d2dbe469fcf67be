"""After training: the latent's sign and extent per class, so that stick +1 does the demonstrated task
over the demonstrated range (NumPy, on the exported decoder)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from vla_latent_training.config import TrainConfig
from vla_latent_training.inputs import DemoInput


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
        side, extent = _side_and_extent(z[np.isin(demo_of_pair, idxs)], cfg)
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
    latent = {
        "bounded": cfg.bounded_latent,
        "gain": gains,
        "default_gain": default_gain,
        "bounds": [float(np.min(z)), float(np.max(z))],
        "decode_check": {c: list(v) for c, v in checks.items()},
    }
    return latent, lines


def _side_and_extent(zc: np.ndarray, cfg: TrainConfig) -> tuple[float, float]:
    """The latent's side (+1 or -1, the median's) for one class's pairs and its extent on that side."""
    side = 1.0 if np.median(zc) >= 0 else -1.0
    on_side = np.abs(zc[zc * side > 0])
    extent = float(np.percentile(on_side, cfg.gain_percentile)) if len(on_side) else float(np.max(np.abs(zc)))
    if not cfg.bounded_latent and cfg.paper_exact:
        extent = 1.0
    return side, max(extent, 1e-3)


def _decode_cosines(items, idxs, ctx, decoder, zval) -> np.ndarray:
    out = []
    for i in idxs:
        ref = demonstrated_direction(items[i].q)
        decoder.set_context(ctx[i])
        a = decoder.decode(items[i].q[0], zval).copy()
        den = float(np.linalg.norm(a) * np.linalg.norm(ref))
        out.append(float(a @ ref) / den if den > 1e-12 else 0.0)
    return np.asarray(out)

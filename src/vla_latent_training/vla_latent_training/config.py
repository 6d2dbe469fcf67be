"""The training recipe's hyper-parameters and the arithmetic on them (no torch: the CLIs and the
experiments read these without loading it)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from vla_latent_controller.context import CNN_FEATURE_DIM, ENCODERS

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
    # training windows never span a hand motion (a grasp, an open): see inputs.hand_cuts
    hand_segments: bool = True
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
    # Where a task ends and how to get back to it (issue 34; off by default, the recipe the shipped
    # models were trained with): each stretch of a demonstration is held at its last state for
    # `rest_samples` more samples (windows that reach past the end then lead to it and stop there, not
    # on in the direction the motion had), and every pair gets `corrective_copies` copies from a state
    # perturbed by N(0, corrective_sigma^2) rad per joint whose action still leads to the same point
    # (DART's corrections: from beside the path, back to it).
    rest_samples: int = 0
    corrective_copies: int = 0
    corrective_sigma: float = 0.03

    @classmethod
    def paper(cls, **overrides) -> TrainConfig:
        """Exactly the paper's public code: unbounded latent, raw units, no z = 0 term."""
        kw = dict(
            zero_weight=0.0, reverse_pairs=False, bounded_latent=False, normalise=False, paper_exact=True,
            hidden=30, hand_segments=False,
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
        if self.rest_samples < 0 or self.corrective_copies < 0:
            raise ValueError("rest_samples and corrective_copies must be >= 0")
        if not (math.isfinite(self.corrective_sigma) and self.corrective_sigma > 0):
            raise ValueError("corrective_sigma must be a positive number of radians")
        check_position_scale(self.position_scale)
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError("val_fraction must be in [0, 1)")

    def mode(self) -> str:
        """One line naming the recipe: paper-exact, or which improvements are on."""
        if self.paper_exact:
            return "paper-exact"
        on = (
            ("z=0 term", self.zero_weight > 0),
            ("tanh latent", self.bounded_latent),
            ("normalised", self.normalise),
            ("reversed pairs", self.reverse_pairs),
            ("hand-split windows", self.hand_segments),
            (f"rest {self.rest_samples}", self.rest_samples > 0),
            (f"corrective {self.corrective_copies} x {self.corrective_sigma:g} rad",
             self.corrective_copies > 0),
        )
        return "improved: " + ", ".join(name for name, enabled in on if enabled)


def scaled_schedule(cfg: TrainConfig, n_train: int) -> tuple[int, int]:
    """(epochs, lr step in epochs) for `n_train` training pairs: the configured ones, both scaled by
    the same whole factor when that gives fewer than `cfg.min_steps` optimiser updates."""
    per_epoch = steps_per_epoch(cfg, n_train)
    factor = max(1, math.ceil(cfg.min_steps / (cfg.epochs * per_epoch)))
    return cfg.epochs * factor, cfg.step_size * factor


def steps_per_epoch(cfg: TrainConfig, n_train: int) -> int:
    return max(1, math.ceil(n_train / cfg.batch_size))


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

"""Choosing a model's path fraction by one procedure: a held full stick in the kinematic loop.

The controller commands the speed of the decoder's chord at z and the direction of the chord at
path_fraction x z (vla_latent_controller.decoder_np): 1 is the paper's command, which a held stick
drives across the demonstrations' corners (issue 20: the hand turned toward the push 15-20 cm up and
slid over the object). A person holds one direction of the stick for long stretches, so the fraction
is chosen for that: from each layout's start pose, hold +1 for the time limit, integrating the
controller's command as the kinematic loop does (q <- q + command dt at the given rate), and measure
how close the path comes to each of the planner's waypoints (pre-push and post-push; a circle's loop),
averaged over the waypoints. The fraction of FRACTIONS whose median over the layouts is smallest is
chosen, the largest one within TIE_RAD of it (nearest the paper's command). Deterministic, no physics,
about a second per model and layout set; the layouts must be development layouts (the caller's
responsibility: vla_study.layouts.development_layouts never gives a test layout).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from vla_common.robot import Q_MAX, Q_MIN
from vla_latent_controller.context import ContextError

from vla_evaluation.kinematic import Layout, TeleopSettings, layout_command

FRACTIONS = (0.5, 0.65, 0.8, 1.0)
TIE_RAD = 0.01  # scores this close to the best count as equal: the larger fraction wins
HOLD = 1.0  # the stick held, full deflection


def held_approach(model, layout: Layout, settings: TeleopSettings, fraction: float) -> float:
    """Mean over the layout's waypoints of the closest joint-space approach (rad) of the path a held
    full stick drives from the start pose over `settings.time_limit` (inf without a context)."""
    s = replace(settings, path_fraction=float(fraction))
    try:
        command, _ = layout_command(model, layout, s)
    except (ContextError, ValueError):
        return float("inf")
    wps = np.stack([np.asarray(w, float) for w in layout.waypoints])
    q = np.asarray(layout.q0, float).copy()
    best = np.linalg.norm(wps - q, axis=1)
    dt = 1.0 / s.rate
    stick = np.array([HOLD])
    for _ in range(int(round(s.time_limit * s.rate))):
        q = np.clip(q + command(stick, q)[0] * dt, Q_MIN, Q_MAX)
        best = np.minimum(best, np.linalg.norm(wps - q, axis=1))
    return float(best.mean())


@dataclass(frozen=True)
class FractionChoice:
    fraction: float
    scores: dict[float, float]  # fraction -> median over the layouts of held_approach (rad)
    layouts: int

    def describe(self) -> str:
        shown = ", ".join(f"{f:g}: {v:.3f}" for f, v in self.scores.items())
        return (f"held +1 in the kinematic loop on {self.layouts} development layouts, median closest "
                f"approach to the waypoints (rad) {shown}; the largest within {TIE_RAD} rad of the best")

    def to_dict(self) -> dict:
        return {"chosen": self.fraction, "median_approach_rad": {str(f): round(v, 4) for f, v in
                                                                  self.scores.items()},
                "layouts": self.layouts, "procedure": self.describe()}


def choose_path_fraction(model, layouts: Sequence[Layout], settings: TeleopSettings,
                         fractions: Sequence[float] = FRACTIONS, tie: float = TIE_RAD) -> FractionChoice:
    """The procedure of this module on `layouts` (development layouts)."""
    if not layouts:
        raise ValueError("no layouts to choose a path fraction on")
    scores = {float(f): float(np.median([held_approach(model, lay, settings, f) for lay in layouts]))
              for f in fractions}
    best = min(scores.values())
    chosen = max(f for f, v in scores.items() if v <= best + tie)
    return FractionChoice(chosen, scores, len(layouts))


def set_path_fraction(model_dir: str | Path, fraction: float, measured: str) -> Path:
    """Write `fraction` into a saved model's latent.path_fraction (with how it was measured); the
    weights stay as they are, config.json is sealed again."""
    from vla_latent_controller.artifacts import load_model, save_model

    art = load_model(model_dir)
    config = dict(art.config)
    config["latent"] = {**config["latent"], "path_fraction": float(fraction),
                        "path_fraction_measured": measured}
    config.pop("files", None)
    return save_model(model_dir, config, art.tensors, art.cnn_path)

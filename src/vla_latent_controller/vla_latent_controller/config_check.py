"""Is a model's config.json usable: its structure, and numbers a trainer could have written.

The bounds are wide (any 7-DoF arm, the paper's settings and ours) but refuse what no training run
writes and what would move the arm wildly: a state scale of 1e-300 saturates every unit, an action scale
of 1e6 or a gain of 1e300 turns any stick deflection into full speed in an arbitrary direction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from vla_latent_controller.context import ENCODERS, context_dim


class ModelError(RuntimeError):
    """A model directory cannot be used; the message says why."""


MAX_DIM = {"context": 4096, "joints": 32, "latent": 1, "hidden": 4096}
Q_MEAN_MAX = 2 * math.pi  # rad: a revolute joint's mean position
Q_STD_RANGE = (1e-3, 2 * math.pi)  # rad; the trainer's floor is 1e-2, no normalisation writes 1
A_SCALE_RANGE = (1e-4, math.pi)  # rad per demo window (<= 1 s); the trainer's floor is 1e-3
GAIN_MAX_BOUNDED = 1.0  # a tanh-bounded latent: the gain is an extent within (-1, 1)
GAIN_MAX_UNBOUNDED = 1e3


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ModelError(msg)


def _is_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def validate_config(cfg: object, where: str = "config") -> dict:
    """Check the config's structure and numbers; returns it. Raises ModelError naming the first problem."""
    _require(isinstance(cfg, dict), f"{where}: expected a JSON object")
    assert isinstance(cfg, dict)
    for key in ("encoder", "classes", "joint_names", "dims", "normalisation", "latent", "files"):
        _require(key in cfg, f"{where}: missing key {key!r}")
    _require(cfg["encoder"] in ENCODERS, f"{where}: unknown encoder {cfg['encoder']!r}")
    _check_names(cfg["classes"], f"{where}: 'classes'")
    _check_names(cfg["joint_names"], f"{where}: 'joint_names'")
    _check_dims(cfg, where)
    _check_normalisation(cfg["normalisation"], cfg["joint_names"], cfg["dims"]["context"], where)
    _check_latent(cfg["latent"], where)
    return cfg


def _check_names(names: object, what: str) -> None:
    _require(
        isinstance(names, list) and len(names) > 0 and all(isinstance(c, str) and c for c in names),
        f"{what} must be a non-empty list of names",
    )
    _require(len(set(names)) == len(names), f"{what} names one twice")


def _check_dims(cfg: dict, where: str) -> None:
    dims = cfg["dims"]
    _require(isinstance(dims, dict), f"{where}: 'dims' must be an object")
    for key, most in MAX_DIM.items():
        v = dims.get(key)
        _require(
            isinstance(v, int) and not isinstance(v, bool) and 0 < v <= most,
            f"{where}: dims.{key} must be an int in 1..{most}, got {v!r}",
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


def _check_vector(norm: dict, key: str, n: int, lo: float, hi: float, names: Sequence[str], where: str):
    v = norm.get(key)
    _require(
        isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v),
        f"{where}: normalisation.{key} must be {n} finite numbers",
    )
    for name, x in zip(names, v):
        _require(
            lo <= x <= hi, f"{where}: normalisation.{key} must be in [{lo:g}, {hi:g}], got {x!r} for {name}"
        )


def _check_normalisation(norm: object, joints: list[str], k: int, where: str) -> None:
    _require(isinstance(norm, dict), f"{where}: 'normalisation' must be an object")
    assert isinstance(norm, dict)
    n = len(joints)
    _check_vector(norm, "q_mean", n, -Q_MEAN_MAX, Q_MEAN_MAX, joints, where)
    _check_vector(norm, "q_std", n, *Q_STD_RANGE, joints, where)
    _check_vector(norm, "a_scale", n, *A_SCALE_RANGE, joints, where)
    slots = [f"context[{i}]" for i in range(k)]
    if "context_mean" in norm:  # recorded for reference: already folded into the weights
        _check_vector(norm, "context_mean", k, -1e6, 1e6, slots, where)
    if "context_std" in norm:
        _check_vector(norm, "context_std", k, 1e-9, 1e6, slots, where)


def _check_latent(lat: object, where: str) -> None:
    _require(isinstance(lat, dict), f"{where}: 'latent' must be an object")
    assert isinstance(lat, dict)
    if "path_fraction" in lat:   # the command's path fraction calibrated for this model (teleop.py)
        pf = lat["path_fraction"]
        _require(_is_number(pf) and 0 < pf <= 1,
                 f"{where}: latent.path_fraction must be a number in (0, 1], got {pf!r}")
    most = GAIN_MAX_BOUNDED if lat.get("bounded", False) else GAIN_MAX_UNBOUNDED
    gains = lat.get("gain", {})
    _require(isinstance(gains, dict), f"{where}: latent.gain must map class names to numbers")
    for name, g in [*gains.items(), ("default_gain", lat.get("default_gain"))]:
        what = "latent.default_gain" if name == "default_gain" else f"latent.gain[{name!r}]"
        _require(
            _is_number(g) and 0 < abs(g) <= most,
            f"{where}: {what} must be a non-zero number with |gain| <= {most:g} "
            f"({'bounded' if most == GAIN_MAX_BOUNDED else 'unbounded'} latent), got {g!r}",
        )

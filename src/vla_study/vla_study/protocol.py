"""The study protocol file (YAML): participants, strategies, tasks, trials, practice, counterbalancing,
and which trials are for development and which the study's test.

A protocol is read as a catalogue is (vla_common.safe_yaml: a regular file of at most MAX_BYTES, no
aliases, no duplicate keys, bounded nesting, UTF-8), checked by its schema (protocol_schema.py,
pydantic) and then across keys; every problem is reported as `file:line: message`, all at once, and the
study does not start. Nothing of the file is quoted beyond a name of at most 40 characters.
The paper's procedure (Section 7) is `protocols/paper.yaml` beside this module.
"""
from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import ValidationError
from vla_common.catalogue import Catalogue, CatalogueError, load_catalogue
from vla_common.safe_yaml import Lines, UnreadableError, YamlFileError, key_name, load_yaml_lines
from vla_common.tasks import parse_task

from vla_study.protocol_schema import (
    EE_AXES,
    HYBRID,
    LAYOUT_SEEDS,
    STRATEGIES,
    ProtocolFile,
    base_strategy,
    describe,
    line_of,
)

# The shipped models per strategy and setting (vla_latent_controller/models); the localization models'
# are named by the protocols that use them.
DEFAULT_MODELS = {"latent-YOLO": {"base": "default", "Seen": "cereal_box_push_south",
                                  "Near": "cereal_box_push_south_east", "Far": "cereal_box_circle"}}
PAPER = Path(__file__).with_name("protocols") / "paper.yaml"
SHIPPED = PAPER.with_name("shipped.yaml")  # the paper's procedure with latent-YOLO and the end-effector only
MAX_BYTES = 256 * 1024  # a protocol is a page of YAML
__all__ = ["EE_AXES", "STRATEGIES", "Protocol", "ProtocolError", "load_protocol", "model_for", "model_names",
           "robot_refusal"]


class ProtocolError(ValueError):
    """A protocol file with errors; str() lists them as file:line: message."""

    def __init__(self, errors: list[str]):
        super().__init__("\n".join(errors))
        self.errors = errors


@dataclass
class Protocol:
    name: str
    participants: list[str]  # "sim:1".."sim:N" or real ids
    population_seed: int
    strategies: list[str]
    settings: dict[str, list[str]]  # setting -> tasks
    trials: int
    practice_trials: int
    practice_seed: int
    counterbalance: str
    time_limit: float
    rate: float
    # strategy -> setting -> a model, or a list of models (one per training seed; model_for says whose)
    models: dict[str, dict[str, str | list[str]]] = field(default_factory=dict)
    backend: str = "graph"
    # what the end-effector mode button cycles (the controller's ee_axes); the participant needs x, y, z
    end_effector_axes: tuple[str, ...] = EE_AXES
    end_effector_debounce: float = 0.25  # s between mode presses (the controller's ee_debounce)
    robot: str = "sim"
    role: str = "test"  # or "development" (protocol_schema.Role)
    layout_seeds: int = LAYOUT_SEEDS  # the first test trial's layout seed
    operator_seeds: str = ""  # the salt of the operator seeds ("": the trial's key alone)
    development: tuple[str, ...] = ()  # development protocol files whose trials the test must not reuse
    source: str = ""
    # where a value came from, for messages: "file:line" of its key, or the command-line flag
    origin: dict[str, str] = field(default_factory=dict)

    def digest(self) -> str:
        """What the trials depend on. Keys added later are left out at their defaults (robot sim, the
        first seeds), so that study folders made before them resume as they were; role and development
        never change a trial."""
        defaults = {"robot": "sim", "layout_seeds": LAYOUT_SEEDS, "operator_seeds": ""}
        d = {k: v for k, v in self.__dict__.items()
             if k not in ("source", "participants", "origin", "role", "development")
             and not (k in defaults and v == defaults[k])}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def model_names(p: Protocol, strategy: str, setting: str) -> list[str]:
    """Every model the protocol names for a latent strategy and setting (one per training seed); an
    assisted condition's are its strategy's."""
    names = p.models[base_strategy(strategy)][setting]
    return [names] if isinstance(names, str) else list(names)


def model_for(p: Protocol, trial) -> str:
    """The model a latent trial drives: the one named for its strategy and setting or, where a list
    (one model per training seed) is named, the participant's: participant i (0-based, in the order of
    the protocol's participants, as trial_plan numbers them) drives the model at i mod the list's
    length, in every setting and for every trial. So the training seeds spread evenly over the
    participants, and a participant's practice and test trials use one model."""
    names = model_names(p, trial.strategy, trial.setting)
    return names[p.participants.index(trial.participant) % len(names)]


def robot_refusal(p: Protocol) -> str | None:
    """Why this protocol cannot run (None: it can): simulated participants see the simulator's ground
    truth and publish a stick themselves; on the real robot only persons drive, and only through the
    launched graph. The message names where each value came from (file:line, or the flag)."""
    if p.robot != "real":
        return None
    robot_at = p.origin.get("robot", p.source or "the protocol")
    sims = [w for w in p.participants if w.startswith("sim:")]
    if sims:
        at = p.origin.get("participants", p.source or "the protocol")
        shown = ", ".join(sims[:3]) + (", ..." if len(sims) > 3 else "")
        said = f"{robot_at} real" if robot_at.startswith("--") else f"{robot_at}: robot: real"
        return (f"{at}: simulated participants ({shown}) cannot run on the real robot ({said}): "
                "they read the simulator's object poses and drive without a person; give "
                "real participant ids (P01,P02) or use robot: sim")
    if p.backend != "graph":
        at = p.origin.get("backend", p.source or "the protocol")
        return f"{at}: the {p.backend} backend has no robot; the real robot ({robot_at}) needs backend: graph"
    return None


def parse_participants(text: str) -> list[str]:
    """`sim:9` -> sim:1..sim:9; `P01,P02` -> real participants."""
    text = str(text).strip()
    if text.startswith("sim:"):
        n = int(text[4:]) if text[4:].isdigit() else 0
        if not 1 <= n <= 1000:
            raise ValueError("sim:N needs a whole number 1 <= N <= 1000")
        return [f"sim:{i}" for i in range(1, n + 1)]
    ids = [p.strip() for p in text.split(",") if p.strip()]
    if not ids or any(not p.replace("_", "").replace("-", "").isalnum() or len(p) > 40 for p in ids):
        raise ValueError("participants are sim:N or comma-separated ids of letters, digits, - and _")
    return ids


def load_protocol(path: str | Path, catalogue: Catalogue | None = None, model_exists=None,
                  _role: str | None = None) -> Protocol:
    """Read and validate a protocol file; ProtocolError with every problem as file:line: message.
    `model_exists(name)`: whether a latent model is installed (None: not checked)."""
    path = Path(path)
    where = str(path)
    try:
        data, lines = load_yaml_lines(path, MAX_BYTES, "protocol")
    except UnreadableError as e:
        raise ProtocolError([f"{where}:0: cannot read the protocol: {e.reason}"]) from None
    except YamlFileError as e:
        raise ProtocolError([f"{where}:{_yaml_line(str(e))}: {_after_path(str(e), where)}"]) from None
    if not isinstance(data, dict):
        raise ProtocolError([f"{where}:1: the protocol must be a mapping of keys to values"])
    try:
        cat = catalogue or load_catalogue("")
    except CatalogueError as e:
        raise ProtocolError([f"{where}:0: cannot load the object catalogue ({e.reason})"]) from None
    try:
        f = ProtocolFile.model_validate(data, context={"catalogue": cat})
    except ValidationError as e:
        raise ProtocolError(describe(e, where, lines)) from None
    errors = _across_keys(f, path, lines, cat, model_exists)
    if _role is not None and f.role != _role:
        errors.append(f"{where}:{line_of(lines, ('role',))}: role is {f.role}, a {_role} protocol is "
                      "needed here")
    if errors:
        raise ProtocolError(errors)
    participants = parse_participants(f.participants)
    models = {k: dict(v) for k, v in DEFAULT_MODELS.items()}
    for k, v in f.models.items():
        models.setdefault(k, {}).update(v)
    # robot_refusal() is asked after the command line's overrides (--participants may replace sim:N)
    origin = {k: f"{where}:{lines[(k,)]}" for k in ("participants", "robot", "backend", "development")
              if (k,) in lines}
    return Protocol(name=f.study or path.stem, participants=participants, population_seed=f.population_seed,
                    strategies=list(f.strategies), settings=f.settings, trials=f.trials,
                    practice_trials=f.practice.trials, practice_seed=f.practice.reset_seed,
                    counterbalance=f.counterbalance, time_limit=float(f.time_limit), rate=float(f.rate),
                    models=models, backend=f.backend, end_effector_axes=tuple(f.end_effector_axes),
                    end_effector_debounce=float(f.end_effector_debounce), robot=f.robot, role=f.role,
                    layout_seeds=f.seeds.layouts, operator_seeds=f.seeds.operators,
                    development=tuple(str(_beside(path, d)) for d in f.development), source=where,
                    origin=origin)


def _across_keys(f: ProtocolFile, path: Path, lines: Lines, cat: Catalogue, model_exists) -> list[str]:
    """What needs several keys: participants, a model for every latent strategy and setting,
    development files that exist and say they are."""
    where = str(path)
    errors: list[str] = []
    try:
        parse_participants(f.participants)
    except ValueError as e:
        errors.append(f"{where}:{line_of(lines, ('participants',))}: participants: {e}")
    return (errors + _model_errors(f, where, lines, model_exists) + _hand_errors(f, where, lines, cat)
            + _development_errors(f, path, lines, cat))


def _hand_errors(f: ProtocolFile, where: str, lines: Lines, cat: Catalogue) -> list[str]:
    """Tasks with the hand run through the graph (the bridge's gripper; the physics backend has no
    hand), and hybrid control is for them only (its end-effector part finishes a grasp or a place)."""
    errors: list[str] = []
    for setting, tasks in f.settings.items():
        hand = [parse_task(t, cat).kind == "pick_place" for t in tasks]
        if any(hand) and f.backend != "graph":
            errors.append(f"{where}:{line_of(lines, ('settings', setting))}: setting {key_name(setting)}: "
                          f"a pick_place task needs backend: graph (the {f.backend} backend has no hand)")
        if HYBRID in map(base_strategy, f.strategies) and not all(hand):
            errors.append(f"{where}:{line_of(lines, ('strategies',))}: strategy {HYBRID!r} is for "
                          f"pick_place tasks only; setting {key_name(setting)} has others")
    return errors


def _model_errors(f: ProtocolFile, where: str, lines: Lines, model_exists) -> list[str]:
    """A model for every latent strategy and setting (the shipped ones by default), installed."""
    errors: list[str] = []
    models = {**DEFAULT_MODELS, **f.models}
    for s in dict.fromkeys(base_strategy(s) for s in f.strategies if STRATEGIES[s] == "latent"):
        for setting in f.settings:
            m = models.get(s, {}).get(setting)
            at = line_of(lines, ("models", s, setting) if (f.models.get(s) or {}).get(setting) else
                         ("models",) if f.models else ("strategies",))
            if m is None:
                errors.append(f"{where}:{at}: strategy {s!r} has no model for setting {key_name(setting)} "
                              "(give it under models)")
                continue
            for name in ([m] if isinstance(m, str) else m):
                if model_exists is not None and not model_exists(name):
                    errors.append(f"{where}:{at}: strategy {s!r}, setting {key_name(setting)}: model "
                                  f"{key_name(name)} is not installed")
    return errors


def _development_errors(f: ProtocolFile, path: Path, lines: Lines, cat: Catalogue) -> list[str]:
    """Each development file a test protocol names exists, is valid and says role: development."""
    where = str(path)
    if f.role == "development" and f.development:
        return [f"{where}:{line_of(lines, ('development',))}: development: only a test protocol names "
                "development files"]
    errors: list[str] = []
    for i, d in enumerate(f.development):
        try:
            load_protocol(_beside(path, d), cat, None, _role="development")
        except ProtocolError as e:
            errors.append(f"{where}:{line_of(lines, ('development', i))}: development file {key_name(d)}: "
                          f"{e.errors[0]}")
    return errors


def _beside(path: Path, name: str) -> Path:
    """A file a protocol names, relative to the protocol's folder."""
    return (path.parent / name) if not Path(name).is_absolute() else Path(name)


def _yaml_line(text: str) -> int:
    """The line a safe_yaml error names ('line N, column M'), or 0."""
    m = re.search(r"line (\d+), column", text)
    return int(m.group(1)) if m else 0


def _after_path(text: str, where: str) -> str:
    """safe_yaml's message without its leading 'protocol <path>' (file:line already says it)."""
    for lead in (f"protocol {where}: ", f"protocol {where} "):
        if text.startswith(lead):
            return text[len(lead):]
    return text


def latin_square(n: int) -> list[list[int]]:
    """A Williams-style Latin square: row i is participant i's order (each strategy once per position).
    For even n each strategy also follows each other once; for odd n the rows and their mirrors."""
    first = [0]
    lo, hi = 1, n - 1
    while len(first) < n:
        first.append(lo)
        lo += 1
        if len(first) < n:
            first.append(hi)
            hi -= 1
    rows = [[(x + i) % n for x in first] for i in range(n)]
    if n % 2:
        rows += [list(reversed(r)) for r in rows]
    return rows

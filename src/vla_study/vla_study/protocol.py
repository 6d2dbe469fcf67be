"""The study protocol file (YAML): participants, strategies, tasks, trials, practice, counterbalancing.

Errors are collected and reported as `file:line: message`, all at once, and the study does not start.
The paper's procedure (Section 7) is `protocols/paper.yaml` beside this module.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.tasks import parse_task

STRATEGIES = {"latent-YOLO": "latent", "latent-localization": "latent", "end-effector": "end_effector"}
# The shipped models per strategy and setting (vla_latent_controller/models); localization models are
# not shipped: a protocol naming that strategy must give its models.
DEFAULT_MODELS = {"latent-YOLO": {"base": "default", "Seen": "cereal_box_push_south",
                                  "Near": "cereal_box_push_south_east", "Far": "cereal_box_circle"}}
KEYS = {"study", "participants", "population_seed", "strategies", "settings", "trials", "practice",
        "counterbalance", "time_limit", "rate", "models", "backend", "end_effector_axes",
        "end_effector_debounce", "robot"}
EE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")  # the controller's (vla_latent_controller.ee_baseline)
PAPER = Path(__file__).with_name("protocols") / "paper.yaml"
SHIPPED = PAPER.with_name("shipped.yaml")  # the paper's procedure with latent-YOLO and the end-effector only
# graph: the shipped launch file, the participant's stick as sensor_msgs/Joy (the study's backend);
# physics: the same participant and scoring with the graph's computations in one process (fast sweeps)
BACKENDS = ("graph", "physics")
# sim: the runner launches the simulated Panda and resets its scene by ~/reset; real: it attaches to the
# graph the lab started (the robot's launch) and the experimenter places the object and scores the trial
ROBOTS = ("sim", "real")


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
    models: dict[str, dict[str, str]] = field(default_factory=dict)
    backend: str = "graph"
    # what the end-effector mode button cycles (the controller's ee_axes); the participant needs x, y, z
    end_effector_axes: tuple[str, ...] = EE_AXES
    end_effector_debounce: float = 0.25  # s between mode presses (the controller's ee_debounce)
    robot: str = "sim"
    source: str = ""
    # where a value came from, for messages: "file:line" of its key, or the command-line flag
    origin: dict[str, str] = field(default_factory=dict)

    def digest(self) -> str:
        # robot "sim" is left out: study folders made before the key existed resume as they were
        d = {k: v for k, v in self.__dict__.items() if k not in ("source", "participants", "origin")
             and not (k == "robot" and v == "sim")}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


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


def _line(node) -> int:
    return node.start_mark.line + 1


def _scalar(node):
    return yaml.safe_load(yaml.serialize(node)) if node is not None else None


def parse_participants(text: str) -> list[str]:
    """`sim:9` -> sim:1..sim:9; `P01,P02` -> real participants."""
    text = str(text).strip()
    if text.startswith("sim:"):
        n = int(text[4:])
        if not 1 <= n <= 1000:
            raise ValueError("sim:N needs 1 <= N <= 1000")
        return [f"sim:{i}" for i in range(1, n + 1)]
    ids = [p.strip() for p in text.split(",") if p.strip()]
    if not ids or any(not p.replace("_", "").replace("-", "").isalnum() for p in ids):
        raise ValueError("participants are sim:N or comma-separated ids of letters, digits, - and _")
    return ids


def load_protocol(path: str | Path, catalogue=None, model_exists=None) -> Protocol:
    """Read and validate a protocol file; ProtocolError with every problem as file:line: message."""
    path = Path(path)
    where = str(path)
    try:
        root = yaml.compose(path.read_text())
    except OSError as e:
        raise ProtocolError([f"{where}:0: cannot read ({e.strerror})"]) from None
    except yaml.YAMLError as e:
        line = e.problem_mark.line + 1 if getattr(e, "problem_mark", None) else 0
        raise ProtocolError([f"{where}:{line}: not valid YAML ({getattr(e, 'problem', 'syntax')})"]) from None
    if not isinstance(root, yaml.MappingNode):
        raise ProtocolError([f"{where}:1: the protocol must be a mapping of keys to values"])
    errors: list[str] = []
    nodes: dict[str, yaml.Node] = {}
    for k, v in root.value:
        key = _scalar(k)
        if key not in KEYS:
            errors.append(f"{where}:{_line(k)}: unknown key {key!r} (known: {', '.join(sorted(KEYS))})")
        elif key in nodes:
            errors.append(f"{where}:{_line(k)}: duplicate key {key!r}")
        else:
            nodes[key] = v

    def err(key_or_node, msg):
        node = nodes.get(key_or_node) if isinstance(key_or_node, str) else key_or_node
        errors.append(f"{where}:{_line(node) if node is not None else _line(root)}: {msg}")

    def get(key, default, kind, check=None):
        if key not in nodes:
            return default
        v = _scalar(nodes[key])
        if not isinstance(v, kind) or isinstance(v, bool) and kind is not bool:
            err(key, f"{key} must be {getattr(kind, '__name__', kind)}, got {v!r}")
            return default
        if check and (why := check(v)):
            err(key, f"{key}: {why}")
            return default
        return v

    for req in ("participants", "strategies", "settings"):
        if req not in nodes:
            errors.append(f"{where}:{_line(root)}: missing required key {req!r}")
    participants = []
    if "participants" in nodes:
        try:
            participants = parse_participants(_scalar(nodes["participants"]))
        except ValueError as e:
            err("participants", f"participants: {e}")
    strategies = get("strategies", [], list)
    for i, s in enumerate(strategies):
        if s not in STRATEGIES:
            err(nodes["strategies"].value[i], f"unknown strategy {s!r} (known: {', '.join(STRATEGIES)})")
    if len(set(strategies)) != len(strategies):
        err("strategies", "a strategy is listed twice")
    try:
        cat = catalogue or load_catalogue("")
    except CatalogueError as e:
        cat = None
        errors.append(f"{where}:0: cannot load the object catalogue ({e.reason})")
    settings: dict[str, list[str]] = {}
    if "settings" in nodes:
        sn = nodes["settings"]
        if not isinstance(sn, yaml.MappingNode) or not sn.value:
            err("settings", "settings must map a setting name to a task or a list of tasks")
        else:
            for k, v in sn.value:
                name, tasks = _scalar(k), _scalar(v)
                tasks = [tasks] if isinstance(tasks, str) else tasks
                if not isinstance(tasks, list) or not tasks:
                    err(v, f"setting {name!r}: a task or a non-empty list of tasks")
                    continue
                for t in tasks:
                    try:
                        spec = parse_task(str(t), cat) if cat is not None else None
                        if spec is not None and spec.kind not in ("push", "circle"):
                            err(v, f"setting {name!r}: task {t!r} is a {spec.kind} task; the study has "
                                   "push and circle tasks")
                    except (ValueError, KeyError) as e:
                        err(v, f"setting {name!r}: {e}")
                settings[str(name)] = [str(t) for t in tasks]
    trials = get("trials", 2, int, lambda v: None if 1 <= v <= 50 else "must be 1..50")
    practice = {"trials": 1, "reset_seed": 7}
    if "practice" in nodes:
        pv = _scalar(nodes["practice"])
        if not isinstance(pv, dict) or set(pv) - set(practice):
            err("practice", "practice must be a mapping with trials and reset_seed")
        else:
            practice.update(pv)
            if not (isinstance(practice["trials"], int) and 0 <= practice["trials"] <= 10):
                err("practice", "practice trials must be 0..10")
    cb = get("counterbalance", "latin_square", str,
             lambda v: None if v in ("latin_square", "none") else "latin_square or none")
    tl = get("time_limit", 30.0, (int, float), lambda v: None if 1 <= v <= 600 else "must be 1..600 s")
    rate = get("rate", 20.0, (int, float), lambda v: None if 5 <= v <= 200 else "must be 5..200 Hz")
    backend = get("backend", "graph", str,
                  lambda v: None if v in BACKENDS else f"one of {', '.join(BACKENDS)}")
    robot = get("robot", "sim", str, lambda v: None if v in ROBOTS else f"one of {', '.join(ROBOTS)}")
    ee_axes = EE_AXES
    if "end_effector_axes" in nodes:
        av = _scalar(nodes["end_effector_axes"])
        if (not isinstance(av, list) or not all(isinstance(a, str) for a in av) or len(set(av)) != len(av)
                or not set(av) <= set(EE_AXES) or not {"x", "y", "z"} <= set(av)):
            err("end_effector_axes", f"end_effector_axes must list distinct axes of {list(EE_AXES)} "
                f"including x, y and z, got {av!r}")
        else:
            ee_axes = tuple(av)
    ee_debounce = get("end_effector_debounce", 0.25, (int, float),
                      lambda v: None if 0.0 <= v <= 5.0 else "must be 0..5 s")
    models = {k: dict(v) for k, v in DEFAULT_MODELS.items()}
    if "models" in nodes:
        mv = _scalar(nodes["models"])
        if not isinstance(mv, dict) or not all(isinstance(v, dict) for v in mv.values()):
            err("models", "models must map a strategy to {setting: model directory name}")
        else:
            for k, v in mv.items():
                models.setdefault(k, {}).update({str(a): str(b) for a, b in v.items()})
    for s in strategies:
        if STRATEGIES.get(s) != "latent":
            continue
        for setting in settings:
            m = models.get(s, {}).get(setting)
            line_key = "models" if "models" in nodes else "strategies"
            if m is None:
                err(line_key, f"strategy {s!r} has no model for setting {setting!r} (give it under models)")
            elif model_exists is not None and not model_exists(m):
                err(line_key, f"strategy {s!r}, setting {setting!r}: model {m!r} is not installed")
    # robot_refusal() is asked after the command line's overrides (--participants may replace sim:N)
    origin = {k: f"{where}:{_line(nodes[k])}" for k in ("participants", "robot", "backend") if k in nodes}
    if errors:
        raise ProtocolError(errors)
    return Protocol(name=str(_scalar(nodes.get("study")) or path.stem), participants=participants,
                    population_seed=int(get("population_seed", 2026, int)), strategies=list(strategies),
                    settings=settings, trials=int(trials), practice_trials=int(practice["trials"]),
                    practice_seed=int(practice["reset_seed"]), counterbalance=cb, time_limit=float(tl),
                    rate=float(rate), models=models, backend=backend, end_effector_axes=ee_axes,
                    end_effector_debounce=float(ee_debounce), robot=robot, source=where, origin=origin)


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

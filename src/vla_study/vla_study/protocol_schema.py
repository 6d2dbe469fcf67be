"""The protocol file's schema (pydantic): every key, its type and range, and messages that say file:line.

`ProtocolFile` checks what one key alone can be; protocol.load_protocol adds what needs several keys
(tasks in the catalogue, a model for each latent strategy and setting, the development files). Every
error is turned into `file:line: where: what` by `describe`, with the line of the key or item it is
about (vla_common.safe_yaml.load_yaml_lines), never more of the file than a name of at most 40
characters.
"""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from vla_common.catalogue import Catalogue
from vla_common.safe_yaml import Lines, key_name
from vla_common.tasks import parse_task
from vla_latent_controller.assistance import LEVELS

OFF = LEVELS[0]   # the controller's default: no assistance

# hybrid: hybrid control on tasks with the hand (the latent, then end-effector mode to finish each
# phase; hand_participant): the controller starts a trial in latent mode with the strategy's model
HYBRID = "hybrid"
BASE_STRATEGIES = {"latent-YOLO": "latent", "latent-localization": "latent", "end-effector": "end_effector",
                   HYBRID: "latent"}
# A latent strategy with the controller's assistance on (its `assistance` parameter; off in every other
# condition) is a condition of its own, `<strategy>+assist-<level>`, so that one protocol holds the
# assisted and unassisted conditions side by side, on the same layouts and participants; it drives its
# strategy's model. The end effector has no assistance (the controller's is latent mode's).
ASSIST = "+assist-"
ASSISTED = {f"{s}{ASSIST}{level}": s for s, mode in BASE_STRATEGIES.items() if mode == "latent"
            for level in LEVELS if level != OFF}
STRATEGIES = {**BASE_STRATEGIES, **{name: BASE_STRATEGIES[s] for name, s in ASSISTED.items()}}
Strategy = Literal[tuple(STRATEGIES)]          # type: ignore[valid-type]
BaseStrategy = Literal[tuple(BASE_STRATEGIES)]  # type: ignore[valid-type]
EE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")  # the controller's (vla_latent_controller.ee_baseline)
EeAxis = Literal["x", "y", "z", "roll", "pitch", "yaw"]
# graph: the shipped launch file, the participant's stick as sensor_msgs/Joy (the study's backend);
# physics: the graph's loop copied into one process; gone (issue 33). Old protocols that name it still
# load (their rows are records); the runner refuses to run it (vla_study.backends.GONE says why)
Backend = Literal["graph", "physics"]
# sim: the runner launches the simulated Panda and resets its scene by ~/reset; real: it attaches to the
# graph the lab started (the robot's launch) and the experimenter places the object and scores the trial
Robot = Literal["sim", "real"]
# test: the study's record; development: trials used to tune a participant, a policy or a parameter,
# whose layouts and operator seeds a test protocol must not reuse (its `development` list names them)
Role = Literal["test", "development"]
LAYOUT_SEEDS = 200_000  # the default base of the test trials' layout seeds (the seeds of the first runs)
NAME = r"^[A-Za-z0-9_.\-]+$"


def base_strategy(strategy: str) -> str:
    """The strategy a condition drives (its model, its participant): `latent-YOLO+assist-high` ->
    `latent-YOLO`."""
    return ASSISTED.get(strategy, strategy)


def assistance_of(strategy: str) -> str:
    """The controller's assistance level in a condition: off unless it names one."""
    return strategy.rpartition(ASSIST)[2] if strategy in ASSISTED else OFF


def strategy_label(strategy: str) -> str:
    """A condition as the tables name it: `latent-YOLO, assistance high`; a strategy alone as itself."""
    level = assistance_of(strategy)
    return strategy if level == OFF else f"{base_strategy(strategy)}, assistance {level}"


def _study_task(task: str, info: ValidationInfo) -> str:
    """A push, circle or pick-and-place task of the catalogue in the validation's context (none: not
    checked here)."""
    cat: Catalogue | None = (info.context or {}).get("catalogue")
    if cat is None:
        return task
    try:
        spec = parse_task(task, cat)
    except (ValueError, KeyError) as e:
        raise ValueError(str(e)) from None
    if spec.kind not in ("push", "circle", "pick_place"):
        raise ValueError(f"task {key_name(task)} is a {spec.kind} task; the study has push, circle and "
                         "pick_place tasks")
    return task


Task = Annotated[str, Field(max_length=200), AfterValidator(_study_task)]
ModelName = Annotated[str, Field(min_length=1, max_length=200)]


def _distinct_models(names: list[str]) -> list[str]:
    if len(set(names)) != len(names):
        raise ValueError("a model is listed twice for one setting")
    return names


ModelNames = ModelName | Annotated[list[ModelName], Field(min_length=1, max_length=20),
                                   AfterValidator(_distinct_models)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


class Practice(Strict):
    trials: int = Field(1, ge=0, le=10)
    reset_seed: int = Field(7, ge=0, le=2**31 - 1)


class Seeds(Strict):
    """Where a protocol's test trials come from: layout seeds from `layouts` on, operator seeds from the
    trial's key salted with `operators` ("": the key alone, as the first runs)."""

    layouts: int = Field(LAYOUT_SEEDS, ge=0, le=2**30)
    operators: str = Field("", max_length=64, pattern=r"^[A-Za-z0-9_.\-]*$")


class ProtocolFile(Strict):
    """One protocol file as written; the keys' meanings are in docs/study.md ('The protocol file')."""

    study: str | None = Field(None, max_length=100)
    participants: str = Field(max_length=4000)
    population_seed: int = Field(2026, ge=0, le=2**32 - 1)
    strategies: list[Strategy] = Field(min_length=1)
    settings: dict[str, list[Task]] = Field(min_length=1)
    trials: int = Field(2, ge=1, le=50)
    practice: Practice = Practice()
    counterbalance: Literal["latin_square", "none"] = "latin_square"
    time_limit: float = Field(30.0, ge=1, le=600)
    rate: float = Field(20.0, ge=5, le=200)
    # per latent strategy and setting a model, or a list of models (one per training seed): participant
    # i (0-based, in the order of participants) drives the model at i mod the list's length
    # (keyed by the strategy: an assisted condition drives its strategy's models)
    models: dict[BaseStrategy, dict[str, ModelNames]] = {}
    backend: Backend = "graph"
    robot: Robot = "sim"
    end_effector_axes: list[EeAxis] = list(EE_AXES)
    end_effector_debounce: float = Field(0.25, ge=0, le=5)
    role: Role = "test"
    seeds: Seeds = Seeds()
    development: list[str] = Field([], max_length=20)

    @field_validator("settings", mode="before")
    @classmethod
    def _one_task_is_a_list(cls, v):
        """`Seen: cereal_box/push_south` is a list of one task."""
        return {k: [t] if isinstance(t, str) else t for k, t in v.items()} if isinstance(v, dict) else v

    @field_validator("settings")
    @classmethod
    def _tasks_listed(cls, v: dict[str, list[str]]) -> dict[str, list[str]]:
        for name, tasks in v.items():
            if not tasks:
                raise ValueError(f"setting {key_name(name)} needs a task or a list of tasks")
        return v

    @field_validator("strategies", mode="before")
    @classmethod
    def _assisted_latent_only(cls, v):
        """`end-effector+assist-high` is refused with the reason (not only as an unknown name)."""
        for name in v if isinstance(v, list) else []:
            base, _, level = str(name).partition(ASSIST)
            if level and BASE_STRATEGIES.get(base) == "end_effector":
                raise ValueError(f"strategy {key_name(str(name))}: the end effector has no assistance (the "
                                 "controller's assistance is latent mode's)")
        return v

    @field_validator("strategies")
    @classmethod
    def _distinct(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError("a strategy is listed twice")
        return v

    @field_validator("end_effector_axes")
    @classmethod
    def _xyz(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v) or not {"x", "y", "z"} <= set(v):
            raise ValueError(f"end_effector_axes must list distinct axes of {list(EE_AXES)} including x, y "
                             "and z")
        return v


KNOWN = tuple(ProtocolFile.model_fields)


def line_of(lines: Lines, loc: tuple) -> int:
    """The line of the deepest key or item of `loc` that the file has (1: the document)."""
    path = tuple(str(x) for x in loc)
    while path and path not in lines:
        path = path[:-1]
    return lines.get(path, 1)


def dotted(loc: tuple) -> str:
    """`('settings', 'Seen')` -> `settings.Seen`; `('strategies', 1)` -> `strategies[1]`."""
    out = ""
    for x in loc:
        out += f"[{x}]" if isinstance(x, int) else (f".{x}" if out else str(x))
    return out


def describe(err: ValidationError, where: str, lines: Lines) -> list[str]:
    """Each of pydantic's errors as `file:line: key: what`, one per place (a union's alternatives
    give one line)."""
    out: dict[tuple, str] = {}
    for e in err.errors(include_url=False):
        loc = tuple(x for x in e["loc"] if x not in ("str", "int", "[key]") and "[" not in str(x))
        if loc in out:
            continue
        if e["type"] == "extra_forbidden":
            msg = f"unknown key {key_name(loc[-1])} (known: {', '.join(KNOWN)})"
        else:
            value = e.get("input")
            named = f" ({key_name(value)})" if isinstance(value, str) and e["type"] == "literal_error" else ""
            msg = f"{dotted(loc)}{named}: {e['msg'].removeprefix('Value error, ')}"
        out[loc] = f"{where}:{line_of(lines, e['loc'])}: {msg}"
    return list(out.values())

"""One trial, the same way on every backend: the skeleton the backends share, and the one scorer.

A trial is: the strategy set and the object at its start (`prepare`), a participant made for it
(`participant`: the simulated operator from its parameters, or the tally of a person's inputs), the
participant driving until it is done or the time limit, then the arm at rest (`drive`), and one row
scored from what was measured (`trial_row`). `TrialBackend.run` is that sequence; a backend
(graph_backend, robot_backend; chosen by the table in backends.py) supplies the steps.
Nothing here imports a backend: the backends import this module.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np
from vla_common.catalogue import Catalogue, TaskSpec
from vla_common.objects import ObjectPose
from vla_common.tasks import parse_task

from vla_study.hand_participant import PickPlaceOperator
from vla_study.outcome import thrown, trial_time
from vla_study.participant import HumanOperator, HumanParams, Lesson, TaskGoal
from vla_study.person import InputTally
from vla_study.protocol import STRATEGIES, Protocol
from vla_study.protocol_schema import HYBRID, assistance_of, base_strategy
from vla_study.smoothness import log_dimensionless_jerk, path_length, sparc, speed_profile

PATH_DT = 0.05  # s between the path samples that smoothness is measured on


@dataclass(frozen=True)
class Trial:
    participant: str
    strategy: str
    setting: str
    task: str
    trial: int  # 0-based; practice trials have phase "practice"
    phase: str  # "practice" or "test"
    layout_seed: int
    order: int  # position in the participant's session

    @property
    def key(self) -> str:
        return (f"{self.participant}|{self.strategy}|{self.setting}|{self.task}|{self.phase}|{self.trial}")

    @property
    def file_stem(self) -> str:
        return file_stem(self.key)


def file_stem(key: str) -> str:
    """A trial's file name in trials/ from its key."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in key)


def hash_seed(text: str) -> int:
    """A stable seed from a string (Python's hash() is salted per process)."""
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def task_goal(task: str, catalogue: Catalogue) -> TaskGoal:
    """The goal as the person is told it, and the object's size as the person sees it."""
    spec = parse_task(task, catalogue)
    shape = catalogue.spec(spec.object_class)
    d = tuple(float(v) for v in spec.direction_vector) if spec.kind in ("push", "pick_place") else None
    return TaskGoal(spec.kind, d, float(spec.distance), float(shape.height), float(shape.footprint_radius))


@dataclass
class Scene:
    """A trial set up and ready to drive: the controller's mode, the task, the object's start pose and
    why nothing will move, if so ("no context: ..." when the controller latched no detection).
    Backends extend it with what their `drive` needs."""

    mode: str  # "latent" or "end_effector"
    spec: TaskSpec
    start: ObjectPose
    note: str = ""


@dataclass
class Measured:
    """What a backend measured of a driven trial: the TCP path (T, 3) and its times (s since the trial
    began), the stick, the outcome, and fields of its own for the row (`extra`)."""

    path: np.ndarray
    times: np.ndarray
    sticks: np.ndarray
    ok: bool
    disp: float
    t_success: float | None
    t_done: float | None
    t_end: float
    fse: float
    interventions: int
    extra: dict = field(default_factory=dict)


Participant = HumanOperator | InputTally


def simulated_participant(params: HumanParams, goal: TaskGoal, strategy: str, seed: int,
                          cycle: tuple[str, ...], lesson: Lesson | None) -> HumanOperator:
    """The simulated operator for a trial: the pick-and-place one (hand_participant) for a task with
    the hand, in the strategy's way of driving (hybrid control: the latent, then end-effector mode),
    told the condition's assistance (the station shows it)."""
    if goal.kind == "pick_place":
        mode = "hybrid" if base_strategy(strategy) == HYBRID else STRATEGIES[strategy]
        return PickPlaceOperator(params, goal, mode, seed=seed, cycle=cycle, lesson=lesson,
                                 assistance=assistance_of(strategy))
    if base_strategy(strategy) == HYBRID:
        raise ValueError(f"{HYBRID} control is for tasks with the hand, not a {goal.kind} task")
    return HumanOperator(params, goal, STRATEGIES[strategy], seed=seed, cycle=cycle, lesson=lesson)


def lesson_key(trial: Trial) -> tuple[str, str, str]:
    """Whose practice a lesson is, and where it applies: the participant, the strategy, the setting."""
    return trial.participant, trial.strategy, trial.setting


class TrialBackend:
    """The skeleton of a trial (`run`); a backend implements `prepare` and `drive` (and `close`).
    A simulated participant's practice trial teaches the trials after it of the same strategy and
    setting (participant.Lesson): the row keeps it (`lesson`), `lessons` carries it on."""

    protocol: Protocol
    catalogue: Catalogue

    @property
    def lessons(self) -> dict[tuple[str, str, str], Lesson]:
        """What each participant's practice taught, by `lesson_key` (the runner restores it on resume)."""
        return self.__dict__.setdefault("_lessons", {})

    def run(self, trial: Trial, params: HumanParams | None, operator_seed: int) -> tuple[dict, dict]:
        """One trial: `params` of a simulated participant, None for a person."""
        scene = self.prepare(trial)
        op = self.participant(trial, scene, params, operator_seed)
        m = self.drive(trial, scene, op)
        row, arrays = trial_row(op, m.path, m.times, m.sticks, ok=m.ok, disp=m.disp, t_success=m.t_success,
                                t_done=m.t_done, t_end=m.t_end, fse=m.fse, interventions=m.interventions,
                                start=scene.start, note=scene.note, time_limit=self.protocol.time_limit)
        row.update(m.extra)
        if isinstance(op, PickPlaceOperator):
            row.update(op.hand_row())
        if isinstance(op, HumanOperator):
            row["taught"] = op.taught.to_dict()   # what the participant knew going in
            if trial.phase == "practice":
                self.lessons[lesson_key(trial)] = op.lesson()
                row["lesson"] = self.lessons[lesson_key(trial)].to_dict()
        return row, arrays

    def prepare(self, trial: Trial) -> Scene:
        raise NotImplementedError

    def drive(self, trial: Trial, scene: Scene, op: Participant) -> Measured:
        raise NotImplementedError

    def participant(self, trial: Trial, scene: Scene, params: HumanParams | None, seed: int) -> Participant:
        """The simulated operator, told the trial's goal; a backend that takes persons overrides this for
        `params` None."""
        if params is None:
            raise ValueError(f"{trial.participant}: this backend has no input for a person")
        taught = self.lessons.get(lesson_key(trial))
        return simulated_participant(params, task_goal(trial.task, self.catalogue), trial.strategy, seed,
                                     self.protocol.end_effector_axes, taught)

    def close(self) -> None:
        """Let go of what the backend started."""


def strategy_mode(strategy: str) -> str:
    """The controller's mode for a strategy: latent or end_effector."""
    return STRATEGIES[strategy]


def controller_parameters(strategy: str) -> dict[str, str]:
    """The controller's parameters a trial of this condition sets, every trial (nothing carries over from
    the trial before): its mode and its assistance level (off but in an assisted condition)."""
    return {"mode": strategy_mode(strategy), "assistance": assistance_of(strategy)}


def trial_row(op: Participant, path: np.ndarray, times: np.ndarray, sticks: np.ndarray, *,
              ok: bool, disp: float, t_success: float | None, t_done: float | None, t_end: float, fse: float,
              interventions: int, start, note: str, time_limit: float) -> tuple[dict, dict]:
    """One trial's row and arrays from what any backend measured: the TCP path (T, 3) and its times
    (s since the trial began), the stick, the outcome; the participant's counts from the operator.
    Every backend scores a trial with this one function. `time_s` is the time to success, the time
    limit for a failure (outcome.py); `duration_s` how long the participant drove."""
    path = np.asarray(path, float).reshape(-1, 3)
    times = np.asarray(times, float)
    dt = float(np.median(np.diff(times))) if len(times) > 1 else PATH_DT
    every = max(1, int(round(PATH_DT / dt)))
    speed = speed_profile(path[::every], times[::every])
    row = {
        "success": bool(ok),
        "time_s": round(trial_time(ok, next((t for t in (t_success, t_done, t_end) if t is not None), None),
                                   time_limit), 3),
        "time_limit_s": float(time_limit),
        "duration_s": round(float(t_end), 3),
        "final_state_error": round(float(fse), 4),
        "object_displacement_m": round(float(disp), 4),
        "thrown": thrown(disp),
        "path_length_m": round(path_length(path), 4),
        "n_inputs": int(op.n_inputs),
        "mode_switches": int(op.n_switches),
        "mode_switch_s": None if op.switch_s is None else round(float(op.switch_s), 3),
        "reversals": int(op.reversals),
        "lapses": None if op.lapses is None else int(op.lapses),   # None: a person's are not seen
        "sparc": round(sparc(speed, 1.0 / (every * dt)), 4) if len(speed) > 2 else None,
        "ldlj": (round(log_dimensionless_jerk(path[::every], times[::every]), 4)
                 if len(path) > 5 * every else None),
        "participant_done": t_done is not None,
        "safety_interventions": int(interventions),
        "object_start": start.to_dict(),
        "note": note,
    }
    return row, {"tcp": path.astype(np.float32), "t": times.astype(np.float32),
                 "stick": np.asarray(sticks, np.float32)}

"""The study runner: one trial at a time, each recorded at once, resumable, never overwriting.

Each trial resets the scene (a fixed reset point for practice, then the object moved to a new,
seeded start), lets the participant drive until they are done or the time limit, and appends one row
to `trials.jsonl` (fsynced) plus the trial's TCP path and inputs to `trials/<key>.npz`. On start the
runner reads `trials.jsonl` and skips every trial already in it, so a study killed at any moment
resumes where it stopped without losing or duplicating a trial; a partial last line (a kill during the
write) is set aside in `trials.jsonl.partial`, never deleted. An output directory made for another
protocol is refused.

Backends, one participant model and one scorer (`trial_row`), two transports:
- `graph` (the default, and what CI's reduced study runs): the shipped launch file through the one
  graph runner, the participant's stick as sensor_msgs/Joy, each trial a bag (vla_study/graph_backend.py);
  A real participant (an id without `sim:`) drives the same graph from the operator station or a
  joystick, the experimenter starting and ending each trial at the terminal (vla_study/person.py);
- `physics`: the graph's computations in one process (MuJoCo PandaSim, the bridge's SafetyFilter, the
  controller's StickToCommand / EndEffectorBaseline; vla_evaluation.physics), several times faster:
  for the sensitivity sweep and the oracle comparison, not for the study's record.
"""
from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vla_study.participant import (
    HumanOperator,
    HumanParams,
    Observation,
    TaskGoal,
    population,
)
from vla_study.person import Experimenter, InputTally, TerminalExperimenter
from vla_study.protocol import STRATEGIES, Protocol, latin_square, robot_refusal
from vla_study.questionnaire import LABELS, SCALE
from vla_study.smoothness import log_dimensionless_jerk, path_length, sparc, speed_profile

LIKERT = ("The strategy was easy to use", "The strategy was helpful", "The strategy was intuitive",
          "I felt in control of the robot", "The robot did what I wanted", "I would use it again")
PATH_DT = 0.05


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


def trial_plan(p: Protocol) -> list[Trial]:
    """Every trial in session order: per participant the strategies in their Latin-square row, per
    strategy practice on each setting's first task from the fixed reset point, then the test trials
    with the object moved to a new seeded start."""
    rows = latin_square(len(p.strategies)) if p.counterbalance == "latin_square" else [
        list(range(len(p.strategies)))]
    out: list[Trial] = []
    for pi, who in enumerate(p.participants):
        order = [p.strategies[i] for i in rows[pi % len(rows)]]
        n = 0
        for strategy in order:
            for setting, tasks in p.settings.items():
                for k in range(p.practice_trials):
                    out.append(Trial(who, strategy, setting, tasks[0], k, "practice", p.practice_seed, n))
                    n += 1
            for setting, tasks in p.settings.items():
                for ti, task in enumerate(tasks):
                    for k in range(p.trials):
                        seed = 200_000 + 1000 * pi + 100 * ti + 10 * k + sum(map(ord, setting)) % 10
                        out.append(Trial(who, strategy, setting, task, k, "test", seed, n))
                        n += 1
    return out


def participant_params(p: Protocol) -> dict[str, HumanParams]:
    sims = [w for w in p.participants if w.startswith("sim:")]
    pop = population(max((int(w[4:]) for w in sims), default=0), p.population_seed)
    return {w: pop[int(w[4:]) - 1] for w in sims}


class StudyStore:
    """trials.jsonl (append-only, one fsynced line per trial) + trials/*.npz; resumable."""

    def __init__(self, out: Path, protocol: Protocol) -> None:
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "trials").mkdir(exist_ok=True)
        self.rows_path = self.out / "trials.jsonl"
        meta = self.out / "study.json"
        digest = protocol.digest()
        if meta.exists():
            old = json.loads(meta.read_text())
            if old.get("protocol_digest") != digest:
                raise SystemExit(f"{self.out} holds a study of another protocol ({old.get('protocol')}); "
                                 "choose a new --out (earlier results are never overwritten)")
        else:
            meta.write_text(json.dumps({"protocol": protocol.source, "protocol_digest": digest,
                                        "name": protocol.name, "simulated": any(
                                            w.startswith("sim:") for w in protocol.participants),
                                        "backend": protocol.backend, "robot": protocol.robot},
                                       indent=1) + "\n")
        self.done = self._read()

    def _read(self) -> dict[str, dict]:
        done: dict[str, dict] = {}
        if not self.rows_path.exists():
            return done
        raw = self.rows_path.read_bytes()
        good, _, tail = raw.rpartition(b"\n")
        if tail.strip():  # a kill during the write: keep the fragment aside, truncate to whole lines
            with open(self.rows_path.with_suffix(".jsonl.partial"), "ab") as f:
                f.write(tail + b"\n")
            with open(self.rows_path, "r+b") as f:
                f.truncate(len(good) + 1 if good else 0)
        for line in (good.decode().splitlines() if good else []):
            if line.strip():
                row = json.loads(line)
                done[row["key"]] = row
        return done

    def record(self, row: dict, arrays: dict[str, np.ndarray]) -> None:
        stem = row["file"]
        tmp = self.out / "trials" / f".{stem}.tmp.npz"
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, self.out / "trials" / f"{stem}.npz")
        line = (json.dumps(row, sort_keys=True) + "\n").encode()
        with open(self.rows_path, "ab") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        self.done[row["key"]] = row

    def record_likert(self, row: dict) -> None:
        with open(self.out / "likert.jsonl", "a") as f:
            f.write(json.dumps(row, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())


def ask_likert(participant: str, strategy: str, ask: Callable[[str], str] = input) -> dict:
    """The questionnaire on the terminal: one whole number on the scale per statement (the scale and
    its words are the station's, :mod:`.questionnaire`)."""
    lo, hi = SCALE
    answers = {}
    print(f"\nQuestionnaire for {participant}, strategy {strategy} "
          f"({lo} = {LABELS[0]}, {hi} = {LABELS[1]})")
    for q in LIKERT:
        while True:
            a = ask(f"  {q}: ").strip()
            if a.isdigit() and lo <= int(a) <= hi:
                answers[q] = int(a)
                break
            print(f"  please answer with a whole number from {lo} to {hi}")
    return {"participant": participant, "strategy": strategy, "answers": answers}


def task_goal(task: str, catalogue) -> TaskGoal:
    """The goal as the person is told it, and the object's size as the person sees it."""
    from vla_common.tasks import parse_task

    spec = parse_task(task, catalogue)
    shape = catalogue.spec(spec.object_class)
    d = tuple(float(v) for v in spec.direction_vector) if spec.kind == "push" else None
    return TaskGoal(spec.kind, d, float(spec.distance), float(shape.height), float(shape.footprint_radius))


class PhysicsBackend:
    """Runs one trial on a PandaSim with the bridge's safety filter (vla_evaluation.physics's loop)."""

    def __init__(self, protocol: Protocol) -> None:
        from vla_common.catalogue import load_catalogue
        from vla_common.kinematics import PandaKinematics
        from vla_detector.inference import Detector
        from vla_evaluation.resources import detector_model_path
        from vla_sim.sim import PandaSim

        self.p = protocol
        self.catalogue = load_catalogue("")
        self.kin = PandaKinematics()
        self.sim = PandaSim(render=True, catalogue=self.catalogue)
        self.detector = Detector(detector_model_path())
        self._models: dict[str, object] = {}

    def model(self, name: str):
        from vla_evaluation.resources import latent_model_dir
        from vla_latent_controller.model import LatentModel

        if name not in self._models:
            self._models[name] = LatentModel.load(latent_model_dir(name))
        return self._models[name]

    def reset_scene(self, trial: Trial):
        from vla_evaluation.kinematic import make_layouts

        return make_layouts([trial.task], [trial.layout_seed], sim=self.sim, detector=self.detector,
                            kin=self.kin, catalogue=self.catalogue)[0]

    def run(self, trial: Trial, params: HumanParams, operator_seed: int) -> tuple[dict, dict]:
        from vla_evaluation.kinematic import TeleopSettings, layout_command
        from vla_evaluation.metrics import SuccessTracker, final_state_error, judge_task
        from vla_evaluation.physics import _goal_pose, _servo
        from vla_latent_controller.ee_baseline import EndEffectorBaseline
        from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

        sim, p = self.sim, self.p
        layout = self.reset_scene(trial)  # ~/reset: the seeded layout, settled, detected
        cls = layout.goal.class_id
        start = _goal_pose(sim, cls)
        mode = STRATEGIES[trial.strategy]
        settings = TeleopSettings(rate=p.rate, time_limit=p.time_limit)
        ee = None
        note = ""
        command = None
        if mode == "latent":
            try:
                model = self.model(p.models[trial.strategy][trial.setting])
                command, _ = layout_command(model, layout, settings)
            except ValueError as e:  # no context latched: the controller waits, nothing moves
                note = f"no context: {e}"
        else:
            ee = EndEffectorBaseline(self.kin, debounce=p.end_effector_debounce, axes=p.end_effector_axes)
        op = HumanOperator(params, task_goal(trial.task, self.catalogue), mode, seed=operator_seed,
                           cycle=p.end_effector_axes)
        safety = SafetyFilter(SafetyConfig(dt=sim.physics_dt))
        safety.reset(sim.q)
        tracker = SuccessTracker(trial.task, start)
        per = max(1, int(round(1.0 / (p.rate * sim.physics_dt))))
        dt = per * sim.physics_dt
        t0 = sim.time
        path, times, sticks = [], [], []
        judge_every = max(1, int(round(0.1 / dt)))
        steps = int(round(p.time_limit / dt))
        t_done = None
        for i in range(steps):
            t = sim.time - t0
            tcp = sim.tcp_pose()[0]
            obj = _goal_pose(sim, cls)
            act = op.act(Observation(t, tcp, np.array([obj.x, obj.y]), 0, ee.axis if ee else "x"))
            if act.done:
                t_done = t
                break
            if ee is not None:
                if act.press:
                    ee.press(t)
                cmd = ee.command(sim.q, act.axis)
            elif command is not None:
                cmd = command(np.array([act.axis]), sim.q)[0]
            else:
                cmd = np.zeros(7)
            safety.submit(cmd, sim.time)
            _servo(sim, safety, per)
            path.append(sim.tcp_pose()[0])
            times.append(sim.time - t0)
            sticks.append(act.axis)
            if i % judge_every == judge_every - 1:
                tracker.update(sim.time - t0, _goal_pose(sim, cls))
        t_end = sim.time - t0
        _servo(sim, safety, int(round(0.5 / sim.physics_dt)))  # the arm comes to rest, the object settles
        end = _goal_pose(sim, cls)
        path_a = np.asarray(path) if path else np.zeros((0, 3))
        ok, disp, _ang = judge_task(trial.task, start, end, path_a[:, :2])
        t_success = tracker.time_to_success
        return trial_row(op, path_a, np.asarray(times), np.asarray(sticks), ok=ok, disp=disp,
                         t_success=t_success, t_done=t_done, t_end=t_end,
                         fse=final_state_error(sim.q, layout.waypoints[-1]),
                         interventions=safety.interventions, start=start, note=note)


def trial_row(op: HumanOperator | InputTally, path: np.ndarray, times: np.ndarray, sticks: np.ndarray, *,
              ok: bool, disp: float, t_success: float | None, t_done: float | None, t_end: float, fse: float,
              interventions: int, start, note: str) -> tuple[dict, dict]:
    """One trial's row and arrays from what any backend measured: the TCP path (T, 3) and its times
    (s since the trial began), the stick, the outcome; the participant's counts from the operator.
    Both backends (the launched graph, the in-process physics) score a trial with this one function."""
    path = np.asarray(path, float).reshape(-1, 3)
    times = np.asarray(times, float)
    dt = float(np.median(np.diff(times))) if len(times) > 1 else PATH_DT
    every = max(1, int(round(PATH_DT / dt)))
    speed = speed_profile(path[::every], times[::every])
    row = {
        "success": bool(ok),
        "time_s": round(float(t_success if ok and t_success is not None
                              else (t_done if ok and t_done is not None else t_end)), 3),
        "duration_s": round(float(t_end), 3),
        "final_state_error": round(float(fse), 4),
        "object_displacement_m": round(float(disp), 4),
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


def run_study(protocol: Protocol, out: Path, backend=None, log: Callable[[str], None] = print,
              ask: Callable[[str], str] = input, limit: int | None = None,
              experimenter: Experimenter | None = None, use_sim_time: bool = False) -> StudyStore:
    """Run every trial of the protocol not yet in `out`; `limit`: stop after this many new trials.
    Real participants (ids without `sim:`) drive the launched graph themselves, with the experimenter at
    this terminal (`experimenter`: another front end, or a test's). With `robot: real` the runner
    attaches to the lab's running graph instead (vla_study/robot_backend.py; `use_sim_time`: that graph is
    a simulated one, for a rehearsal or a test)."""
    if why := robot_refusal(protocol):  # before anything is made or run
        raise SystemExit(f"protocol refused: {why}")
    real = [w for w in protocol.participants if not w.startswith("sim:")]
    if real and protocol.backend != "graph" and backend is None:  # refused before anything is made or run
        raise SystemExit(f"real participants ({', '.join(real)}) drive the launched graph: the "
                         f"{protocol.backend} backend has no input for a person (use --backend graph)")
    store = StudyStore(out, protocol)
    plan = trial_plan(protocol)
    todo = [t for t in plan if t.key not in store.done]
    log(f"[study] {len(plan)} trials in the protocol, {len(plan) - len(todo)} already recorded in {out}, "
        f"{len(todo)} to run")
    if not todo:
        _ask_left_over(store, todo, backend, log, ask, out)   # on the terminal: nothing is launched
        return store
    own = backend is None
    if own:
        if real and experimenter is None:
            experimenter = TerminalExperimenter()
        if protocol.robot == "real":
            from vla_study.robot_backend import RobotBackend

            backend = RobotBackend(protocol, out, log, experimenter=experimenter, use_sim_time=use_sim_time)
        else:
            backend = (PhysicsBackend(protocol) if protocol.backend == "physics" else
                       _graph_backend(protocol, out, log, experimenter if real else None))
    try:
        _run_trials(protocol, store, todo, backend, log, ask, limit, out)
    finally:
        if own and hasattr(backend, "close"):
            backend.close()
    return store


def _graph_backend(protocol: Protocol, out: Path, log, experimenter: Experimenter | None):
    from vla_study.graph_backend import GraphBackend

    return GraphBackend(protocol, out, log, experimenter=experimenter)


def _run_trials(protocol: Protocol, store: StudyStore, todo: list[Trial], backend, log, ask, limit,
                out: Path) -> None:
    params = participant_params(protocol)
    asked = {(r["participant"], r["strategy"]) for r in _likert_rows(out)}
    _ask_left_over(store, todo, backend, log, ask, out)
    for n, trial in enumerate(todo):
        if limit is not None and n >= limit:
            break
        who = trial.participant
        wall0 = time.monotonic()
        row, arrays = backend.run(trial, params.get(who), operator_seed=hash_seed(trial.key))
        row.update({"key": trial.key, "file": trial.file_stem, "participant": who,
                    "strategy": trial.strategy, "setting": trial.setting, "task": trial.task,
                    "trial": trial.trial, "phase": trial.phase, "layout_seed": trial.layout_seed,
                    "order": trial.order, "simulated": who.startswith("sim:"), "backend": protocol.backend,
                    "wall_s": round(time.monotonic() - wall0, 2)})
        store.record(row, arrays)
        log(f"[study] {trial.key}: success {row['success']}, time {row['time_s']:.1f} s, "
            f"path {row['path_length_m']:.2f} m, switches {row['mode_switches']}, SPARC {row['sparc']} "
            f"({row['wall_s']:.1f} s wall)")
        last_of_strategy = not any(t.participant == who and t.strategy == trial.strategy
                                   for t in todo[n + 1:])
        if last_of_strategy and not who.startswith("sim:") and (who, trial.strategy) not in asked:
            _likert(store, who, trial.strategy, backend, log, ask)


def _likert(store: StudyStore, who: str, strategy: str, backend, log, ask) -> None:
    """The questionnaire after a strategy: on the operator station's page when the study runs with it,
    else (or when it does not answer) on the terminal: the same row (vla_study/questionnaire.py)."""
    from functools import partial

    from vla_study.questionnaire import likert_row, station_for

    terminal, station = partial(ask_likert, who, strategy, ask), station_for(backend, log)
    store.record_likert(likert_row(who, strategy, LIKERT, terminal, station, log))


def _ask_left_over(store: StudyStore, todo: list[Trial], backend, log, ask, out: Path) -> None:
    """A questionnaire that a stop left unanswered (the study stopped after a strategy's last trial,
    before or while it was asked: Ctrl-C while the page waited) is asked when the study resumes."""
    asked = {(r["participant"], r["strategy"]) for r in _likert_rows(out)}
    left = {(t.participant, t.strategy) for t in todo}
    done = dict.fromkeys((r["participant"], r["strategy"]) for r in store.done.values()
                         if not r["participant"].startswith("sim:"))
    for who, strategy in (k for k in done if k not in asked and k not in left):
        log(f"[study] the questionnaire for {who}, strategy {strategy} was not answered before the study "
            "stopped: asking it now")
        _likert(store, who, strategy, backend, log, ask)


def _likert_rows(out: Path) -> list[dict]:
    p = Path(out) / "likert.jsonl"
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()] if p.exists() else []


def hash_seed(text: str) -> int:
    """A stable seed from a string (Python's hash() is salted per process)."""
    import hashlib

    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def _flush() -> None:
    sys.stdout.flush()

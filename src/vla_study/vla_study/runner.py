"""The study runner: one trial at a time, each recorded at once, resumable, never overwriting.

Each trial resets the scene (a fixed reset point for practice, then the object moved to a new,
seeded start), lets the participant drive until they are done or the time limit, and appends one row
to `trials.jsonl` (fsynced) plus the trial's TCP path and inputs to `trials/<key>.npz`. On start the
runner reads `trials.jsonl` and skips every trial already in it, so a study killed at any moment
resumes where it stopped without losing or duplicating a trial; a partial last line (a kill during the
write) is set aside in `trials.jsonl.partial`, never deleted. An output directory made for another
protocol is refused.

Where trials run is the backend table's (backends.py): the launched graph (the default, and what CI's
reduced study runs; simulated participants in lockstep, deterministic at any load; real participants
drive it too, in real time, the experimenter at the terminal), or the lab's robot.
Every backend runs the same trial skeleton and scorer (trial.py).
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
from vla_evaluation.sweep import Engine

from vla_study.backends import BACKENDS, Where, backend_name, backend_refusal, make_backend
from vla_study.participant import HumanParams, Lesson, population
from vla_study.person import Experimenter, TerminalExperimenter
from vla_study.protocol import STRATEGIES, Protocol, latin_square, load_protocol, model_for, robot_refusal
from vla_study.protocol_schema import assistance_of
from vla_study.questionnaire import LABELS, SCALE, likert_row, station_for
from vla_study.trial import Trial, TrialBackend, hash_seed

LIKERT = ("The strategy was easy to use", "The strategy was helpful", "The strategy was intuitive",
          "I felt in control of the robot", "The robot did what I wanted", "I would use it again")


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
                        seed = p.layout_seeds + 1000 * pi + 100 * ti + 10 * k + sum(map(ord, setting)) % 10
                        out.append(Trial(who, strategy, setting, task, k, "test", seed, n))
                        n += 1
    return out


def operator_seed(p: Protocol, trial: Trial) -> int:
    """The seed of the simulated participant's noise in a trial: from its key, salted by the protocol's
    `seeds: operators` (none: the key alone, as the first runs)."""
    return hash_seed(f"{p.operator_seeds}|{trial.key}" if p.operator_seeds else trial.key)


def reused_seeds(p: Protocol) -> list[str]:
    """Why a test protocol may not run: its test trials reuse a layout (the task and its layout seed) or
    an operator seed of a trial in a development file it names. Empty: the test set is disjoint."""
    if p.role != "test" or not p.development:
        return []
    mine = [t for t in trial_plan(p) if t.phase == "test"]
    at = p.origin.get("development", p.source)
    out = []
    for path in p.development:
        dev = load_protocol(path)
        theirs = trial_plan(dev)
        layouts = {(t.task, t.layout_seed) for t in theirs}
        operators = {operator_seed(dev, t) for t in theirs}
        hits = [t for t in mine if (t.task, t.layout_seed) in layouts or operator_seed(p, t) in operators]
        if hits:
            out.append(f"{at}: {len(hits)} of the {len(mine)} test trials reuse the layouts or operator "
                       f"seeds of the development file {path} (the first: {hits[0].key}, layout seed "
                       f"{hits[0].layout_seed}); give the test protocol its own seeds (seeds: layouts, "
                       "operators)")
    return out


def participant_params(p: Protocol) -> dict[str, HumanParams]:
    sims = [w for w in p.participants if w.startswith("sim:")]
    pop = population(max((int(w[4:]) for w in sims), default=0), p.population_seed)
    return {w: pop[int(w[4:]) - 1] for w in sims}


class StudyStore:
    """trials.jsonl (append-only, one fsynced line per trial) + trials/*.npz; resumable."""

    def __init__(self, out: Path, protocol: Protocol) -> None:
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "trials").mkdir(exist_ok=True)
        except OSError as e:
            raise SystemExit(f"--out {self.out}: {e.strerror}: a study folder is a directory") from None
        self.rows_path = self.out / "trials.jsonl"
        self.failed: list[str] = []  # this run's units that failed (on Ray): missing, retried on a resume
        meta = self.out / "study.json"
        digest = protocol.digest()
        if meta.exists():
            try:
                old = json.loads(meta.read_text())
            except (OSError, UnicodeDecodeError, ValueError):
                raise SystemExit(f"{meta} is not a study's record: choose a new --out") from None
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
        for n, line in enumerate(good.decode(errors="replace").splitlines() if good else [], 1):
            if line.strip():
                try:
                    row = json.loads(line)
                    done[row["key"]] = row
                except (ValueError, TypeError, KeyError):
                    raise SystemExit(f"{self.rows_path}:{n}: not a trial's row: choose a new --out") from None
        return done

    def record(self, row: dict, arrays: dict[str, np.ndarray]) -> None:
        save_arrays(self.out, row["file"], arrays)
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


def save_arrays(out: Path, stem: str, arrays: dict[str, np.ndarray]) -> Path:
    """A trial's TCP path, times and stick as `<out>/trials/<stem>.npz`, written whole or not at all."""
    dest = Path(out) / "trials" / f"{stem}.npz"
    tmp = dest.with_name(f".{stem}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, dest)
    return dest


def run_study(protocol: Protocol, out: Path, backend: TrialBackend | None = None,
              log: Callable[[str], None] = print, ask: Callable[[str], str] = input, limit: int | None = None,
              experimenter: Experimenter | None = None, use_sim_time: bool = False,
              engine: Engine | None = None, only: tuple[str, ...] = ()) -> StudyStore:
    """Run every trial of the protocol not yet in `out`; `limit`: stop after this many new trials;
    `only`: of these conditions (strategies) only, the others left for a later run of the same folder.
    `backend`: one already made (a test's), else the table's for the protocol (backends.py). Real
    participants (ids without `sim:`) drive themselves, with the experimenter at this terminal
    (`experimenter`: another front end, or a test's). `use_sim_time`: with `robot: real`, the attached
    graph is a simulated one (a rehearsal or a test). `engine`: simulated participants' trials as units
    of a sweep on Ray (vla_study.on_ray; None or serial: here, one after another)."""
    if why := backend_refusal(protocol) or robot_refusal(protocol):  # before anything is made or run
        raise SystemExit(f"protocol refused: {why}")
    if why := reused_seeds(protocol):
        raise SystemExit("protocol refused: " + "\n".join(why))
    real = [w for w in protocol.participants if not w.startswith("sim:")]
    row = BACKENDS[backend_name(protocol)]
    if real and not row.persons and backend is None:  # refused before anything is made or run
        raise SystemExit(f"real participants ({', '.join(real)}) drive the launched graph: the "
                         f"{protocol.backend} backend has no input for a person (use --backend graph)")
    store = StudyStore(out, protocol)
    plan = trial_plan(protocol)
    todo = [t for t in plan if t.key not in store.done]
    left = sum(1 for t in todo if only and t.strategy not in only)
    todo = [t for t in todo if not only or t.strategy in only]
    log(f"[study] {len(plan)} trials in the protocol, {len(plan) - len(todo) - left} already recorded "
        f"in {out}, {len(todo)} to run" + (f", {left} of other conditions left for later" if left else ""))
    if not todo:
        _ask_left_over(store, todo, backend, log, ask, out)   # on the terminal: nothing is launched
        return store
    if engine is not None and not engine.serial and not real and backend is None:
        store.failed = _run_on_ray(protocol, store, todo[:limit], engine, out, log, use_sim_time)
        return store
    own = backend is None
    if own:
        if real and experimenter is None:
            experimenter = TerminalExperimenter()
        backend = make_backend(Where(protocol, Path(out), log, experimenter if real else None, use_sim_time))
    try:
        _run_trials(protocol, store, todo, backend, log, ask, limit, out)
    finally:
        if own:
            backend.close()
    return store


def _run_trials(protocol: Protocol, store: StudyStore, todo: list[Trial], backend, log, ask, limit,
                out: Path) -> None:
    params = participant_params(protocol)
    restore_lessons(backend, store.done.values())
    asked = {(r["participant"], r["strategy"]) for r in _likert_rows(out)}
    _ask_left_over(store, todo, backend, log, ask, out)
    for n, trial in enumerate(todo):
        if limit is not None and n >= limit:
            break
        who = trial.participant
        wall0 = time.monotonic()
        seed = operator_seed(protocol, trial)
        row, arrays = backend.run(trial, params.get(who), operator_seed=seed)
        row["wall_s"] = round(time.monotonic() - wall0, 2)
        _record(protocol, store, trial, row, arrays, seed, log)
        last_of_strategy = not any(t.participant == who and t.strategy == trial.strategy
                                   for t in todo[n + 1:])
        if last_of_strategy and not who.startswith("sim:") and (who, trial.strategy) not in asked:
            _likert(store, who, trial.strategy, backend, log, ask)


def _model(protocol: Protocol, trial: Trial) -> str | None:
    """The latent model a trial drove (its training seed, where the protocol names one per seed)."""
    return model_for(protocol, trial) if STRATEGIES[trial.strategy] == "latent" else None


def recorded_lessons(rows) -> dict:
    """What the recorded practice trials taught, by (participant, strategy, setting), in session order."""
    return {(r["participant"], r["strategy"], r["setting"]): Lesson.from_dict(r["lesson"])
            for r in sorted((r for r in rows if r.get("phase") == "practice" and r.get("lesson")),
                            key=lambda r: (r["participant"], r.get("order", 0)))}


def restore_lessons(backend, rows) -> None:
    """What the recorded practice trials taught, back into the backend (a resumed study's test trials
    get their participant's practice as if the study had not stopped), in session order."""
    lessons = getattr(backend, "lessons", None)
    if lessons is not None:
        lessons.update(recorded_lessons(rows))


def _record(protocol: Protocol, store: StudyStore, trial: Trial, row: dict, arrays: dict, seed: int,
            log) -> None:
    """The trial's row, completed with what the plan says about it, recorded and logged."""
    who = trial.participant
    row.update({"key": trial.key, "file": trial.file_stem, "participant": who,
                "strategy": trial.strategy, "assistance": assistance_of(trial.strategy),
                "setting": trial.setting, "task": trial.task,
                "trial": trial.trial, "phase": trial.phase, "layout_seed": trial.layout_seed,
                "operator_seed": seed, "model": _model(protocol, trial),
                "order": trial.order, "simulated": who.startswith("sim:"), "backend": protocol.backend})
    store.record(row, arrays)
    log(f"[study] {trial.key}: success {row['success']}, time {row['time_s']:.1f} s, "
        f"path {row['path_length_m']:.2f} m, switches {row['mode_switches']}, SPARC {row['sparc']} "
        f"({row['wall_s']:.1f} s wall)")


def _run_on_ray(protocol: Protocol, store: StudyStore, todo: list[Trial], engine: Engine, out: Path, log,
                use_sim_time: bool) -> list[str]:
    from vla_study.on_ray import run_trials_on_ray  # Ray: only for a sweep

    seeds = {t.key: operator_seed(protocol, t) for t in todo}
    failed = run_trials_on_ray(
        protocol, todo, participant_params(protocol), seeds, recorded_lessons(store.done.values()),
        lambda trial, row, arrays: _record(protocol, store, trial, row, arrays, seeds[trial.key], log),
        engine, Path(out), log, use_sim_time)
    if failed:
        log(f"[study] {len(failed)} trials failed and are not recorded (run the study again to retry "
            f"them): {', '.join(failed)}")
    return failed


def _likert(store: StudyStore, who: str, strategy: str, backend, log, ask) -> None:
    """The questionnaire after a strategy: on the operator station's page when the study runs with it,
    else (or when it does not answer) on the terminal: the same row (vla_study/questionnaire.py)."""
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

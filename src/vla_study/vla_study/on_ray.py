"""A study of simulated participants as a sweep (vla_evaluation.sweep) on Ray, on this machine or a
cluster.

A unit is one participant's trials of one strategy in one setting, in session order: the practice
trial teaches the participant (a Lesson) what their test trials of that setting use, so those trials
run one after another on one worker; different units share nothing. A worker makes its backend once
(the launched graph on a ROS domain of its own, in lockstep) and runs the units it gets;
the lessons already recorded (a resumed study) go with the unit. The trials' rows and arrays come back
to the driver, which alone writes them (`StudyStore.record`), as the serial runner does. Real
participants never run here: they drive at the experimenter's terminal (runner.run_study).
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from vla_evaluation.graph import GraphError
from vla_evaluation.graph_sweep import GRAPH_ATTEMPTS
from vla_evaluation.sweep import Engine, run_sweep

from vla_study.backends import Where, backend_name, make_backend
from vla_study.protocol import Protocol
from vla_study.trial import Trial, TrialBackend


def chains(todo: list[Trial]) -> dict[str, list[Trial]]:
    """The trials by (participant, strategy, setting), each chain in session order."""
    out: dict[str, list[Trial]] = {}
    for t in todo:
        out.setdefault(f"{t.participant}|{t.strategy}|{t.setting}", []).append(t)
    return out


class StudyWorker:
    """Makes its backend at the first unit; a graph backend's logs and bags go to a folder of the
    worker's own (`<out>/workers/<pid>`), so that several graphs on one machine never share a file."""

    def __init__(self, shared: tuple[Protocol, Path, bool]) -> None:
        self.protocol, self.out, self.use_sim_time = shared
        self.backend: TrialBackend | None = None
        self.own = Path()  # the worker's own folder in the study's

    def run(self, unit: tuple) -> list[tuple[str, dict, dict]]:
        """The unit's trials in order. A GraphError (the graph did not answer in time on a starved
        machine, a process that ended) is not an outcome: the whole chain runs again on a new graph, up
        to GRAPH_ATTEMPTS times (in lockstep the same trials, step for step); past that the unit fails."""
        for attempt in range(1, GRAPH_ATTEMPTS + 1):
            try:
                return self._chain(*unit)
            except GraphError as e:
                print(f"[study] attempt {attempt} of {GRAPH_ATTEMPTS} ended with a graph error ({e}); "
                      "the graph is closed", flush=True)
                if attempt == GRAPH_ATTEMPTS:
                    raise
        raise AssertionError("unreachable")

    def _chain(self, trials, params, seeds, lessons) -> list[tuple[str, dict, dict]]:
        if self.backend is None:
            graph = backend_name(self.protocol) == "graph"
            self.own = Path("workers", str(os.getpid())) if graph else Path()
            self.backend = make_backend(Where(self.protocol, self.out / self.own, print, None,
                                              self.use_sim_time))
        if getattr(self.backend, "lessons", None) is not None:
            self.backend.lessons.update(lessons)
        done = []
        for trial in trials:
            wall0 = time.monotonic()
            try:
                row, arrays = self.backend.run(trial, params, operator_seed=seeds[trial.key])
            except BaseException:
                # a unit that fails leaves nothing half done for the next: its graph goes (a recorder
                # still holding the failed trial's bag refused every later trial of the worker), the
                # next attempt or unit starts a new one
                self.close()
                raise
            row["wall_s"] = round(time.monotonic() - wall0, 2)
            if row.get("bag"):  # the row names files from the study's folder, as the serial run's do
                row["bag"] = str(self.own / row["bag"])
            done.append((trial.key, row, arrays))
        return done

    def close(self) -> None:
        if self.backend is not None:
            backend, self.backend = self.backend, None
            backend.close()


def run_trials_on_ray(protocol: Protocol, todo: list[Trial], params: dict, seeds: dict[str, int],
                      lessons: dict, record: Callable[[Trial, dict, dict], None], engine: Engine, out: Path,
                      log: Callable[[str], None], use_sim_time: bool = False) -> list[str]:
    """Every chain of `todo` as a unit; `record(trial, row, arrays)` in this process for each trial of a
    unit as it ends. Returns the keys of the units that failed (their trials stay missing: the study
    resumes with them)."""
    by_key = {t.key: t for t in todo}
    units = []
    for key, trials in chains(todo).items():
        t0 = trials[0]
        mine = {k: v for k, v in lessons.items() if k == (t0.participant, t0.strategy, t0.setting)}
        units.append((key, (trials, params.get(t0.participant), {t.key: seeds[t.key] for t in trials}, mine)))

    def on_result(key: str, done: list) -> None:
        for trial_key, row, arrays in done:
            record(by_key[trial_key], row, arrays)

    return run_sweep(units, StudyWorker, engine=engine, shared=(protocol, Path(out), use_sim_time),
                     on_result=on_result, name="study", log=log)

"""Holding the stick (issue 20 item 5): a person holds the stick at one value from the ready pose
with the object latched, for a few seconds, on fresh layouts, through the whole graph on MuJoCo.

A hold must finish the task or stop short of the object gently: no reflex. The episodes run on the
one graph runner (`vla_evaluation.graph`) with the simulated teleoperator told to hold (its `hold`
parameter) instead of steering to waypoints. `bench/bench_holds.py` prints the figures.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from vla_evaluation.graph import EpisodeRecord, GraphConfig, GraphError, GraphEvaluator
from vla_evaluation.kinematic import TeleopSettings
from vla_interfaces.msg import SafetyStatus

FRESH_SEED = 300_000  # layouts from here on were never used for demonstrations or other evaluations
# Stops no person chose that a loaded machine causes: a command late to the bridge's watchdog, then the
# wait for neutral (the simulated person lets go and holds again). A hold with one lost time to it.
MACHINE_STOPS = (int(SafetyStatus.COMMAND_TIMEOUT), int(SafetyStatus.AWAITING_ZERO))


@dataclass
class HoldTally:
    """One task's holds: how many ran, ended in a reflex, did the task, and the worst speed."""

    task: str
    holds: int = 0
    reflexes: int = 0
    successes: int = 0
    max_speed_ratio: float = 0.0
    stick_range: tuple[float, float] = (float("inf"), float("-inf"))  # the stick values the arm saw
    reflex_seeds: list[int] = field(default_factory=list)
    stopped: int = 0  # holds the bridge stopped (MACHINE_STOPS) at least once
    # holds the graph did not finish (a timeout on a loaded machine, a process that ended): counted as
    # failed holds, with what happened; their reflexes are unknown
    graph_errors: list[tuple[int, str]] = field(default_factory=list)

    def add(self, rec: EpisodeRecord) -> None:
        r = rec.result
        self.holds += 1
        by_code = r.extra.get("interventions_by_code", {})
        if by_code.get(int(SafetyStatus.REFLEX), 0) > 0:
            self.reflexes += 1
            self.reflex_seeds.append(int(r.layout_seed))
        self.stopped += any(by_code.get(c, 0) > 0 for c in MACHINE_STOPS)
        self.successes += bool(r.success)
        self.max_speed_ratio = max(self.max_speed_ratio, float(r.extra.get("max_speed_ratio", 0.0)))
        if rec.trace is not None and len(rec.trace):
            stick = rec.trace[:, 8]
            self.stick_range = (min(self.stick_range[0], float(stick.min())),
                                max(self.stick_range[1], float(stick.max())))

    def add_graph_error(self, seed: int, reason: str) -> None:
        self.holds += 1
        self.graph_errors.append((int(seed), reason))

    def line(self) -> str:
        seeds = f"  reflex seeds {self.reflex_seeds}" if self.reflex_seeds else ""
        if self.graph_errors:
            seeds += (f"  graph errors (failed holds, reflex unknown) in {len(self.graph_errors)}: seeds "
                      f"{[s for s, _ in self.graph_errors]}")
        return (f"{self.task:28s} holds {self.holds:3d}  reflexes {self.reflexes:3d}  "
                f"task done {self.successes:3d}/{self.holds}  stopped by a late command {self.stopped:3d}  "
                f"max |dq|/dq_max {self.max_speed_ratio:.2f}{seeds}")


def hold_config(model_path: str, detector_model: str, seconds: float = 6.0, stick: float = 1.0,
                path_fraction: float = TeleopSettings.path_fraction, **kw) -> GraphConfig:
    """The graph's configuration for holds of `seconds` at `stick` (the controller's `path_fraction`)."""
    return GraphConfig(model_path=model_path, detector_model=detector_model,
                       settings=TeleopSettings(rate=100.0, time_limit=float(seconds), switch_time=0.0,
                                               hold=float(stick), path_fraction=float(path_fraction)),
                       **kw)


def run_holds(config: GraphConfig, tasks: Sequence[str], n: int, first_seed: int = FRESH_SEED,
              log: Callable[[str], None] = print,
              evaluator: Callable[..., GraphEvaluator] = GraphEvaluator) -> dict[str, HoldTally]:
    """`n` holds per task on fresh layouts (seeds first_seed, first_seed + 1, ...); tallies by task.

    A hold the graph does not finish (GraphError: a timeout under load, a process that ended) is
    counted as a failed hold and said so; the graph is restarted for the next one, so one slow
    moment does not end the whole run. A graph that does not start ends it."""
    tallies = {t: HoldTally(t) for t in tasks}
    ev: GraphEvaluator | None = None
    try:
        for task in tasks:
            for seed in range(first_seed, first_seed + int(n)):
                tally = tallies[task]
                if ev is None:  # a graph that does not start ends the run
                    ev = evaluator(config, log)
                    ev.start()
                try:
                    rec = ev.run_episode(task, seed, "holds")
                except GraphError as e:
                    tally.add_graph_error(seed, str(e))
                    log(f"[holds] {task} seed {seed}: graph error ({e}): counted as a failed hold, "
                        "restarting the graph")
                    ev.close()
                    ev = None
                    continue
                tally.add(rec)
                log(f"[holds] seed {seed}: task done {bool(rec.result.success)}; {tally.line()}")
    finally:
        if ev is not None:
            ev.close()
    return tallies

"""Holding the stick (issue 20 item 5): a person holds the stick at one value from the ready pose
with the object latched, for a few seconds, on fresh layouts, through the whole graph on MuJoCo.

A hold must finish the task or stop short of the object gently: no reflex. The episodes run on the
one graph runner (`vla_evaluation.graph`) with the simulated teleoperator told to hold (its `hold`
parameter) instead of steering to waypoints. Each hold is a unit of a sweep (`vla_evaluation.sweep`):
a worker keeps one graph, on a ROS domain of its own, for the holds it gets. `bench/bench_holds.py`
prints the figures.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from vla_evaluation.graph import EpisodeRecord, GraphConfig, GraphEvaluator
from vla_evaluation.graph_sweep import EpisodeJob, EpisodeWorker, for_workers
from vla_evaluation.kinematic import TeleopSettings
from vla_evaluation.sweep import SERIAL, Engine, run_sweep
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
    rows: list[dict] = field(default_factory=list)  # each hold's summary, in seed order

    def add(self, h: dict) -> None:
        """One hold's summary (`hold_summary`)."""
        self.holds += 1
        self.rows.append(dict(h, task=self.task))
        if h["reflex"]:
            self.reflexes += 1
            self.reflex_seeds.append(int(h["seed"]))
        self.stopped += h["stopped"]
        self.successes += h["success"]
        self.max_speed_ratio = max(self.max_speed_ratio, h["max_speed_ratio"])
        if h["stick"] is not None:
            lo, hi = h["stick"]
            self.stick_range = (min(self.stick_range[0], lo), max(self.stick_range[1], hi))

    def add_graph_error(self, seed: int, reason: str) -> None:
        self.holds += 1
        self.graph_errors.append((int(seed), reason))
        self.rows.append({"task": self.task, "seed": int(seed), "success": False, "graph_error": reason})

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


def hold_summary(rec: EpisodeRecord) -> dict:
    """What a hold's tally needs, small enough to send back from a worker."""
    r = rec.result
    by_code = r.extra.get("interventions_by_code", {})
    stick = rec.trace[:, 8] if rec.trace is not None and len(rec.trace) else None
    return {"seed": int(r.layout_seed), "success": bool(r.success), "time_to_success": r.time_to_success,
            "displacement_m": _number(r.displacement_m), "angle_err_deg": _number(r.angle_err_deg),
            "reflex": by_code.get(int(SafetyStatus.REFLEX), 0) > 0,
            "stopped": any(by_code.get(c, 0) > 0 for c in MACHINE_STOPS),
            "max_speed_ratio": float(r.extra.get("max_speed_ratio", 0.0)),
            "stick": None if stick is None else (float(stick.min()), float(stick.max()))}


def _number(x) -> float | None:
    return None if x is None else float(x)


def run_holds(config: GraphConfig, tasks: Sequence[str], n: int, first_seed: int = FRESH_SEED,
              log: Callable[[str], None] = print,
              evaluator: Callable[..., GraphEvaluator] = GraphEvaluator,
              engine: Engine = SERIAL) -> dict[str, HoldTally]:
    """`n` holds per task on fresh layouts (seeds first_seed, first_seed + 1, ...); tallies by task.

    A hold the graph does not finish (GraphError: a timeout under load, a process that ended) runs
    again on a new graph (graph_sweep.EpisodeWorker); if that fails too it is counted as a failed hold
    and said so, and the run goes on, so one slow moment does not end the whole run. On Ray
    (`engine`) each worker has its graph on a ROS domain of its own."""
    if not engine.serial and config is not None:
        config = for_workers(config)  # each worker's graph on a domain of its own
    seeds = range(first_seed, first_seed + int(n))
    units = [(f"{task}/{seed}", (task, seed)) for task in tasks for seed in seeds]
    got: dict[str, dict] = {}

    def on_result(key: str, h: dict) -> None:
        got[key] = h
        if "graph_error" in h:
            log(f"[holds] {key}: graph error ({h['graph_error']}): counted as a failed hold, restarting "
                "the graph")
        else:
            log(f"[holds] {key}: task done {h['success']}")

    job = EpisodeJob(config, "holds", summarise=hold_summary, graph_errors_are_results=True,
                     own_logs=not engine.serial, evaluator=evaluator)
    failed = run_sweep(units, EpisodeWorker, engine=engine, on_result=on_result, shared=job,
                       name="holds", log=log)
    tallies = {t: HoldTally(t) for t in tasks}
    for key, (task, seed) in units:  # in the plan's order, whatever finished first
        h = got.get(key, {"graph_error": "the unit failed"} if key in failed else None)
        if "graph_error" in h:
            tallies[task].add_graph_error(seed, h["graph_error"])
        else:
            tallies[task].add(h)
    return tallies

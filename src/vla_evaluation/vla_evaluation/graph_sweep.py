"""Graph episodes as units of a sweep (vla_evaluation.sweep): the held-stick bench's holds and
`evaluate --mode graph`'s episodes.

A worker keeps one graph (GraphEvaluator) for the episodes it gets, started at the first, on a ROS
domain of its own (the sweep's worker drops the driver's ROS_DOMAIN_ID; GraphRunner then takes one
from vla_common.ros.domain) and, beside other workers, a log folder of its own.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from vla_evaluation.graph import EpisodeRecord, GraphConfig, GraphError, GraphEvaluator

# Runs of a unit that ends in a GraphError, each on a new graph (a graph error is not an outcome)
GRAPH_ATTEMPTS = 2
T = TypeVar("T")


@dataclass(frozen=True)
class EpisodeJob:
    """What every episode of a sweep shares: the graph's configuration and what to send back."""

    config: GraphConfig
    label: str = ""
    n_objects: int = 1
    summarise: Callable[[EpisodeRecord], Any] | None = None  # None: the whole record
    graph_errors_are_results: bool = False  # a hold's timeout is a failed hold; an evaluation's fails
    own_logs: bool = False  # several workers: a log folder each
    evaluator: Callable[..., GraphEvaluator] = GraphEvaluator
    attempts: int = GRAPH_ATTEMPTS


def for_workers(config: GraphConfig) -> GraphConfig:
    """A configuration for graphs on several workers: each picks its own ROS domain."""
    return replace(config, domain_id=None)


def on_a_new_graph_after_errors(episode: Callable[[], T], close: Callable[[], None], what: str,
                                attempts: int = GRAPH_ATTEMPTS) -> T:
    """`episode()` on the worker's graph; a GraphError closes the graph (an episode that timed out is
    still running on it, and the graph would refuse the next unit's model or task) and `episode()` runs
    again on a new one, up to `attempts` times in all; the last error is raised."""
    for attempt in range(1, attempts + 1):
        try:
            return episode()
        except GraphError as e:
            close()
            print(f"[graph] {what}: attempt {attempt} of {attempts} ended with a graph error ({e}); the "
                  "graph is closed", flush=True)
            if attempt == attempts:
                raise
    raise AssertionError("unreachable")


class EpisodeWorker:
    """Runs (task, seed) episodes on one graph. A GraphError (the graph did not answer in time: a
    starved machine, a process that ended) is not an outcome: the graph is closed and the episode runs
    again on a new one, up to `job.attempts` times (in lockstep the same episode, step for step). Past
    that, with `graph_errors_are_results` the error comes back as {"seed", "graph_error"}; otherwise
    the unit fails (reported by the sweep)."""

    def __init__(self, job: EpisodeJob) -> None:
        self.job, self.config = job, job.config
        if job.own_logs and self.config is not None and self.config.log_dir:
            self.config = replace(self.config, log_dir=Path(self.config.log_dir) / f"worker-{os.getpid()}")
        self.ev: GraphEvaluator | None = None

    def run(self, unit: tuple[str, int]) -> Any:
        task, seed = unit
        try:
            rec = on_a_new_graph_after_errors(lambda: self._episode(task, seed), self.close,
                                              f"{task} seed {seed}", self.job.attempts)
        except GraphError as e:
            if self.job.graph_errors_are_results:
                return {"seed": seed, "graph_error": str(e)}
            raise
        return self.job.summarise(rec) if self.job.summarise else rec

    def _episode(self, task: str, seed: int) -> EpisodeRecord:
        if self.ev is None:
            self.ev = self.job.evaluator(self.config, print)
            self.ev.start()
        return self.ev.run_episode(task, seed, self.job.label, self.job.n_objects)

    def close(self) -> None:
        if self.ev is not None:
            ev, self.ev = self.ev, None
            ev.close()

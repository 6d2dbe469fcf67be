"""The held-stick bench's loop (`vla_evaluation.holds.run_holds`) without a graph: a fake evaluator."""

import numpy as np
from vla_evaluation.graph import EpisodeRecord, GraphError
from vla_evaluation.holds import hold_summary, run_holds
from vla_evaluation.metrics import EpisodeResult

from vla_interfaces.msg import SafetyStatus


class FakeGraph:
    """Each hold succeeds, except seed 301 which times out every time, seed 304 which times out once
    (the new graph's run of it succeeds); seed 302 ends in a reflex."""

    started = 0
    closed = 0
    timed_out: set = set()

    def __init__(self, config, log):
        self.open = False

    def start(self):
        FakeGraph.started += 1
        self.open = True

    def close(self):
        if self.open:
            FakeGraph.closed += 1
        self.open = False

    def run_episode(self, task, seed, label, n_objects=1):
        assert self.open, "a hold on a closed graph"
        if seed == 301 or (seed == 304 and (task, seed) not in FakeGraph.timed_out):
            FakeGraph.timed_out.add((task, seed))
            raise GraphError("timed out after 72 s waiting for the end of the episode")
        r = EpisodeResult(task=task, layout_seed=seed, mode="graph", success=seed != 302)
        r.extra = {"interventions_by_code": {int(SafetyStatus.REFLEX): 1} if seed == 302 else {},
                   "max_speed_ratio": 0.5}
        return EpisodeRecord(r, np.zeros((0, 3)), np.zeros(0))


def test_a_graph_timeout_runs_the_hold_again_on_a_new_graph_then_is_a_failed_hold():
    lines = []
    tallies = run_holds(None, ["bread/push_east", "soda_can/push_south"], 5, first_seed=300,
                        log=lines.append, evaluator=FakeGraph)
    for task, t in tallies.items():
        assert t.holds == 5, task
        assert t.successes == 3, task  # 300, 303 and 304 (its second run); 301 timed out twice, 302 a reflex
        assert t.reflexes == 1 and t.reflex_seeds == [302]
        assert [s for s, _ in t.graph_errors] == [301]
        assert "graph errors" in t.line() and "[301]" in t.line()
        # each hold's row for --json, in seed order, the graph error a failed row
        assert [(r["task"], r["seed"], r["success"]) for r in t.rows] == \
            [(task, 300, True), (task, 301, False), (task, 302, False), (task, 303, True), (task, 304, True)]
        assert "graph_error" in t.rows[1] and t.rows[2]["reflex"]
    # the first graph, then a new one after each of 301's two timeouts and 304's one, per task
    assert FakeGraph.started == 7 and FakeGraph.closed == 7
    assert sum("counted as a failed hold" in line for line in lines) == 2


def test_a_hold_the_watchdog_stopped_is_counted_and_said():
    from vla_evaluation.holds import HoldTally

    tally = HoldTally("bread/push_east")
    for seed, by_code in ((1, {}), (2, {int(SafetyStatus.COMMAND_TIMEOUT): 2}),
                          (3, {int(SafetyStatus.AWAITING_ZERO): 1}), (4, {int(SafetyStatus.CONTACT): 3})):
        r = EpisodeResult(task="bread/push_east", layout_seed=seed, mode="graph", success=True)
        r.extra = {"interventions_by_code": by_code}
        tally.add(hold_summary(EpisodeRecord(r, np.zeros((0, 3)), np.zeros(0))))
    assert tally.stopped == 2  # the watchdog's stop and the wait for neutral; contact slowing is not one
    assert "stopped by a late command   2" in tally.line()

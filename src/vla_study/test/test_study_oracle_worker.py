"""The oracle's sweep worker after a graph error: the graph is closed and the episode runs again on a
new one. A graph whose episode timed out still runs that episode and refuses the next model ("an
episode is running; stop it first"): kept, it failed every later unit of its worker (16 of 252 in a
run beside a clean clone's CI, on one worker)."""
from types import SimpleNamespace

import pytest
import vla_evaluation.graph as graph
from vla_evaluation.graph import GraphError
from vla_study.oracle import OracleUnit, OracleWorker


class FakeGraph:
    """A graph whose first episode overall times out and keeps running, as the launched one does."""

    made: list["FakeGraph"] = []
    timeouts = 1

    def __init__(self, config, log) -> None:
        self.running, self.closed, self.episodes = "", False, []
        FakeGraph.made.append(self)

    def start(self) -> None:
        pass

    def set_model(self, path: str) -> None:
        if self.running:
            raise GraphError(f"sim_teleoperator refused parameters: model_path: an episode ({self.running}) "
                             "is running; stop it first")

    def run_episode(self, task: str, seed: int, label: str = "") -> SimpleNamespace:
        if FakeGraph.timeouts:
            FakeGraph.timeouts -= 1
            self.running = task
            raise GraphError(f"the {task} episode: the simulation did not reach step 18502 within 720 s")
        self.episodes.append((task, seed))
        done = SimpleNamespace(success=True, final_state_error=0.1, time_to_success=4.0, extra={}, note="")
        return SimpleNamespace(result=done)

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def fake_graph(monkeypatch):
    FakeGraph.made, FakeGraph.timeouts = [], 1
    monkeypatch.setattr(graph, "GraphEvaluator", FakeGraph)
    return FakeGraph


def _unit(task: str, seed: int) -> OracleUnit:
    return OracleUnit("latent-YOLO", "base", "default", 0, task, seed, "graph", "test")


def test_a_timed_out_episode_runs_again_on_a_new_graph_and_the_next_unit_too(fake_graph):
    worker = OracleWorker({"time_limit": 30.0, "rate": 20.0})
    first = worker.run(_unit("soda_can/push_south", 600111))
    second = worker.run(_unit("bread/push_east", 600001))
    assert first["success"] and second["success"]
    old, new = fake_graph.made
    assert old.closed and not old.episodes                       # the stuck graph is gone
    assert new.episodes == [("soda_can/push_south", 600111), ("bread/push_east", 600001)]
    worker.close()
    assert new.closed


def test_a_graph_that_keeps_failing_fails_the_unit(fake_graph):
    fake_graph.timeouts = 2
    worker = OracleWorker({"time_limit": 30.0, "rate": 20.0})
    with pytest.raises(GraphError, match="did not reach"):
        worker.run(_unit("soda_can/push_south", 600111))
    assert len(fake_graph.made) == 2 and all(g.closed for g in fake_graph.made)

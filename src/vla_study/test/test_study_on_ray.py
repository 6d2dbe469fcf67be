"""The study's Ray worker and what a failed unit means to the person running the study: a unit that
ends in a graph error runs again on a new graph, and a study with units still missing exits non-zero."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from vla_evaluation.graph import GraphError
from vla_evaluation.graph_sweep import GRAPH_ATTEMPTS

from vla_study import cli, on_ray


class Backend:
    """A graph that answers, or one that never does (every trial a GraphError)."""

    def __init__(self, fails: bool) -> None:
        self.fails, self.closed, self.lessons, self.ran = fails, False, {}, []

    def run(self, trial, params, operator_seed: int):
        if self.fails:
            raise GraphError("the graph did not answer in time")
        self.ran.append(trial.key)
        return {"success": True, "seed": operator_seed}, {}

    def close(self) -> None:
        self.closed = True


def worker(monkeypatch, tmp_path: Path, failing: int) -> tuple[on_ray.StudyWorker, list[Backend]]:
    made: list[Backend] = []

    def make_backend(where):
        made.append(Backend(fails=len(made) < failing))
        return made[-1]

    monkeypatch.setattr(on_ray, "make_backend", make_backend)
    monkeypatch.setattr(on_ray, "backend_name", lambda protocol: "graph")
    return on_ray.StudyWorker((None, tmp_path, False)), made


UNIT = ([SimpleNamespace(key="practice"), SimpleNamespace(key="test")], {}, {"practice": 1, "test": 2}, {})


def test_a_unit_that_ends_in_a_graph_error_runs_again_whole_on_a_new_graph(monkeypatch, tmp_path):
    w, made = worker(monkeypatch, tmp_path, failing=GRAPH_ATTEMPTS - 1)
    done = w.run(UNIT)
    assert [(k, row["seed"]) for k, row, _ in done] == [("practice", 1), ("test", 2)]
    assert len(made) == GRAPH_ATTEMPTS and all(b.closed for b in made[:-1])
    assert made[-1].ran == ["practice", "test"]


def test_a_unit_whose_every_attempt_fails_fails(monkeypatch, tmp_path):
    w, made = worker(monkeypatch, tmp_path, failing=GRAPH_ATTEMPTS)
    with pytest.raises(GraphError):
        w.run(UNIT)
    assert len(made) == GRAPH_ATTEMPTS and all(b.closed for b in made)


def test_a_study_with_failed_units_says_so_and_exits_non_zero(monkeypatch, tmp_path, capsys):
    proto = tmp_path / "p.yaml"
    proto.write_text("study: s\nparticipants: sim:1\nstrategies: [end-effector]\nsettings:\n"
                     "  Seen: [bread/push_east]\ntrials: 1\ntime_limit: 4\n")
    monkeypatch.setattr(cli, "run_study", lambda *a, **k: SimpleNamespace(failed=["sim:1|end-effector|Seen"]))
    assert cli.main(["--protocol", str(proto), "--out", str(tmp_path / "out")]) == 1
    assert "incomplete: 1 units of trials failed" in capsys.readouterr().err

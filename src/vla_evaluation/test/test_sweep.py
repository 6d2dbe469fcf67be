"""The sweep engine (vla_evaluation.sweep) and its store (unit_store): units run serially or on a local
Ray give the same results, a worker that dies mid-unit costs a rerun and no duplicate, a failing unit
is reported and the rest go on, and the store resumes and refuses another plan's file."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from vla_evaluation.sweep import Engine, Needs, Progress, run_sweep, slots
from vla_evaluation.unit_store import UnitStore, digest


class Squares:
    """A worker: squares numbers; unit -1 raises; a unit ("die", path) kills its own process the first
    time (the path marks that it did), as a worker killed mid-unit; unit "nice" gives its niceness."""

    made = 0

    def __init__(self, shared) -> None:
        self.offset = shared or 0

    def run(self, unit):
        if unit == "nice":
            return os.nice(0)
        if unit == -1:
            raise ValueError("unit -1 always fails")
        if isinstance(unit, tuple):
            marker = Path(unit[1])
            if not marker.exists():
                marker.write_text(str(os.getpid()))
                os._exit(9)  # the worker's process dies mid-unit
            return "survived"
        return unit * unit + self.offset

    def close(self) -> None:
        pass


def collect(units, engine, shared=None):
    got: dict = {}

    def on_result(key, result):
        assert key not in got, f"{key} delivered twice"
        got[key] = result

    failed = run_sweep(units, Squares, engine=engine, on_result=on_result, shared=shared, name="t",
                       log=lambda s: None)
    return got, failed


def test_serial_sweep_runs_every_unit_and_reports_the_failed_one():
    got, failed = collect([("a", 2), ("b", -1), ("c", 3)], Engine(serial=True), shared=10)
    assert got == {"a": 14, "c": 19}
    assert failed == ["b"]


@pytest.mark.slow
def test_a_local_ray_gives_the_serial_results_and_survives_a_worker_that_dies(tmp_path):
    units = [(f"u{i}", i) for i in range(6)] + [("bad", -1), ("dies", ("die", str(tmp_path / "died"))),
                                                  ("niceness", "nice")]
    got, failed = collect(units, Engine(cpus=2), shared=1)
    assert failed == ["bad"]
    # the workers run at the driver's niceness (Ray's default: 15 nicer, starved beside other work)
    assert got == {**{f"u{i}": i * i + 1 for i in range(6)}, "dies": "survived", "niceness": os.nice(0)}
    assert (tmp_path / "died").exists()  # the worker did die once, and the unit ran again


def test_slots_follow_the_cpus_and_ask_for_a_gpu_only_where_there_is_one():
    assert slots({"CPU": 2.0}, Needs(cpus=1.0, gpu=1.0), 10) == (2, 0.0)
    assert slots({"CPU": 16.0, "GPU": 1.0}, Needs(cpus=1.0, gpu=1.0), 10) == (1, 1.0)
    assert slots({"CPU": 16.0, "GPU": 1.0}, Needs(cpus=1.0, gpu=0.25), 10) == (4, 0.25)
    assert slots({"CPU": 128.0}, Needs(cpus=1.0), 3) == (3, 0.0)  # never more workers than units
    assert slots({"CPU": 0.5}, Needs(cpus=1.0), 3) == (1, 0.0)


def test_progress_gives_an_eta_over_the_whole_sweep():
    lines = []
    p = Progress("x", total=10, done_before=4, log=lines.append)
    p.t0 -= 60.0  # as if the first unit of this run took a minute
    p.update("k")
    assert lines[0].startswith("[x] 5/10 k: done;") and "ETA 5m00s" in lines[0]


def test_the_store_resumes_keeps_each_unit_once_and_sets_a_partial_line_aside(tmp_path):
    path = tmp_path / "models.jsonl"
    s = UnitStore(path, digest({"plan": 1}))
    s.record("a", [{"x": 1.5}])
    s.record("a", [{"x": 99}])  # a second delivery of the same unit is ignored
    with open(path, "ab") as f:
        f.write(b'{"key": "b", "resu')  # a stop during the write
    again = UnitStore(path, digest({"plan": 1}))
    assert again.done == {"a": [{"x": 1.5}]}
    assert (tmp_path / "models.jsonl.partial").read_text().startswith('{"key": "b"')
    assert [json.loads(x)["key"] for x in path.read_text().splitlines()[1:]] == ["a"]
    with pytest.raises(SystemExit, match="another plan"):
        UnitStore(path, digest({"plan": 2}))


def test_a_local_ray_that_is_another_drivers_is_told_apart_by_its_job_number():
    """The first job of a cluster is its own starter's; a later one joined someone else's Ray."""
    from vla_evaluation.sweep import joined_another

    class Ray:
        def __init__(self, job):
            self.job = job

        def get_runtime_context(self):
            return self

        def get_job_id(self):
            return self.job

    assert joined_another(Ray("01000000")) == ""
    assert "another driver's" in joined_another(Ray("02000000"))

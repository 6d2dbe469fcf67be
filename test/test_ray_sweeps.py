"""Sweeps on a Ray cluster of two nodes on this machine (each its own processes, one CPU): a slice of the
paper's experiments and a slice of the user study give the rows of a serial run of the same slice, their
units spread over both nodes; and a worker killed in the middle of a unit costs a rerun, never a lost
or duplicated model."""
from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from ray_cluster import RayCluster

# 4 models (detector encoder, 1 and 2 demos per object, 2 runs), each evaluated on 4 layouts per task
SLICE = ["experiments", "--quick", "--only", "2a", "--encoders", "detector", "--counts", "1,2", "--runs", "2",
         "--layouts", "4", "--epochs", "5", "--min-steps", "5"]
TIME_FIELDS = ("train_s", "eval_s", "train_cpu_s", "eval_cpu_s")
STARTED = re.compile(r"\[experiments\] (\S+) started in pid (\d+) on node (\w+)")
STUDY_STARTED = re.compile(r"\[study\] (\S+) started in pid (\d+) on node (\w+)")
# 2 simulated participants x 2 strategies: a practice trial (what it teaches, the test trials of its
# setting use: one unit each) and one 4 s trial on each of 2 tasks; 12 trials through the graph, in
# lockstep (a graph per worker: the same rows however the work is spread)
STUDY = """study: ray-slice
participants: sim:2
strategies: [latent-YOLO, end-effector]
settings:
  Seen: [cereal_box/push_south, bread/push_east]
trials: 1
practice: {trials: 1, reset_seed: 7}
time_limit: 4
rate: 20
"""
# A graph trial's row fields that name wall time (how long, where it went, the pace, the dated bag folder)
STUDY_WALL_FIELDS = ("wall_s", "wall_phases", "trial_rtf", "bag")
RUN_TIMEOUT_S = 900.0


def rows(out: Path) -> list[dict]:
    with open(out / "episodes.csv") as f:
        return [{k: v for k, v in r.items() if k not in TIME_FIELDS} for r in csv.DictReader(f)]


def store_keys(work: Path) -> list[str]:
    [store] = work.glob("*/models.jsonl")
    return [json.loads(x)["key"] for x in store.read_text().splitlines()[1:]]


class Driver:
    """A command in a process of its own, its output read line by line as it comes."""

    def __init__(self, args: list[str], env: dict) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, pattern: re.Pattern, timeout: float) -> re.Match:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if m := pattern.search(line):
                    return m
            assert self.proc.poll() is None, "the driver ended first:\n" + "\n".join(self.lines[-40:])
            time.sleep(0.05)  # polling the lines the reader thread collects
        raise AssertionError(f"no line matching {pattern.pattern} in {timeout} s")

    def finish(self, timeout: float) -> int:
        rc = self.proc.wait(timeout)
        self._reader.join(10)
        return rc

    def text(self) -> str:
        return "\n".join(self.lines)


def study_rows(out: Path) -> dict[str, dict]:
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines() if x.strip()]
    return {r["key"]: {k: v for k, v in r.items() if k not in STUDY_WALL_FIELDS} for r in rows}


@pytest.fixture(scope="module")
def serial_slice(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("serial")
    d = Driver(["vla_evaluation", *SLICE, "--serial", "--out", str(tmp / "out"), "--work", str(tmp / "work")],
               dict(os.environ))
    assert d.finish(RUN_TIMEOUT_S) == 0, d.text()[-4000:]
    return rows(tmp / "out")


@pytest.fixture(scope="module")
def cluster():
    with RayCluster(nodes=2, cpus=1) as c:
        yield c
    assert not c.leftover(), c.leftover()


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_an_experiment_slice_on_two_nodes_gives_the_serial_rows(cluster, serial_slice, tmp_path):
    d = Driver(["vla_evaluation", *SLICE, "--ray-address", cluster.address, "--out", str(tmp_path / "out"),
                "--work", str(tmp_path / "work")], cluster.env)
    assert d.finish(RUN_TIMEOUT_S) == 0, d.text()[-4000:]
    assert "2 CPUs, 0 GPUs, 2 nodes" in d.text()
    nodes = {m[3] for m in STARTED.finditer(d.text())}
    assert len(nodes) == 2, f"the models ran on {nodes}, not on both nodes\n{d.text()[-3000:]}"
    assert rows(tmp_path / "out") == serial_slice
    assert sorted(store_keys(tmp_path / "work")) == sorted(set(store_keys(tmp_path / "work")))


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_worker_killed_mid_model_costs_a_rerun_and_no_duplicate(cluster, serial_slice, tmp_path):
    d = Driver(["vla_evaluation", *SLICE, "--ray-address", cluster.address, "--out", str(tmp_path / "out"),
                "--work", str(tmp_path / "work")], cluster.env)
    first = d.wait_for(STARTED, RUN_TIMEOUT_S)
    os.kill(int(first[2]), signal.SIGKILL)  # the worker's process, in the middle of its model
    assert d.finish(RUN_TIMEOUT_S) == 0, d.text()[-4000:]
    starts = [m[1] for m in STARTED.finditer(d.text())]
    assert starts.count(first[1]) == 2, f"{first[1]} was not run again after the kill:\n{d.text()[-3000:]}"
    keys = store_keys(tmp_path / "work")
    assert len(keys) == len(set(keys)) == 4, keys
    assert rows(tmp_path / "out") == serial_slice


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_study_slice_on_two_nodes_gives_the_serial_rows(cluster, tmp_path):
    proto = tmp_path / "slice.yaml"
    proto.write_text(STUDY)
    runs = {}
    for name, extra, env in (("serial", ["--serial"], dict(os.environ)),
                             ("ray", ["--ray-address", cluster.address], cluster.env)):
        d = Driver(["vla_study", "--protocol", str(proto), "--out", str(tmp_path / name), *extra], env)
        assert d.finish(RUN_TIMEOUT_S) == 0, d.text()[-4000:]
        runs[name] = (study_rows(tmp_path / name), d.text())
    (serial, _), (on_ray, text) = runs["serial"], runs["ray"]
    assert len(serial) == 12 and sum(r["phase"] == "practice" for r in serial.values()) == 4
    differ = {k: {f: (on_ray.get(k, {}).get(f), v) for f, v in row.items() if on_ray.get(k, {}).get(f) != v}
              for k, row in serial.items()}
    assert on_ray.keys() == serial.keys() and not any(differ.values()), differ   # (on Ray, serial)
    assert len({m[3] for m in STUDY_STARTED.finditer(text)}) == 2, text[-3000:]
    for key in serial:  # each trial's arrays, written by the driver
        assert (tmp_path / "ray" / "trials" / f"{serial[key]['file']}.npz").is_file()

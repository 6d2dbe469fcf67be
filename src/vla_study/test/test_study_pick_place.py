"""The study's pick-and-place (issue 33): the human-like participant does it in three conditions, the
latent alone, the end effector alone and hybrid control, with what a person sees and nothing more; the
protocol keeps its development and test seeds apart; a trial runs through the graph and its row names
the condition."""
from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from study_files import bag_joy, bag_messages, study_rows
from vla_common.catalogue import load_catalogue
from vla_study.hand_participant import BUSY, EMPTY, HOLDING, OPEN, PickPlaceOperator
from vla_study.participant import HumanParams, Observation
from vla_study.protocol import STRATEGIES, ProtocolError, load_protocol
from vla_study.runner import reused_seeds
from vla_study.trial import simulated_participant, task_goal

from vla_study import hand_participant

PROTOCOLS = Path(hand_participant.__file__).with_name("protocols")
TASK = "glass_bottle/pick_place_west"
DT, SPEED, DEADBAND = 0.05, 0.2, 0.1   # s per step; m/s at full stick; the controller's deadband
BOTTLE = np.array([0.45, 0.0])
MISS = np.array([-0.03, 0.0, 0.0])     # the toy latent's path passes 3 cm short of the bottle's neck


class ToyWorld:
    """A kinematic stand-in for the graph: end-effector mode moves the hand along the selected axis at
    SPEED x stick; latent mode moves it along a fixed path (stick > 0 forward: down to 3 cm short of the
    neck, then over the place and down); the grasp button toggles the hand (busy 0.5 s), which holds the
    bottle when the fingers are within 1 cm across and 2 cm in height of its neck; a held bottle moves
    with the hand and stands where it is let go."""

    def __init__(self, goal) -> None:
        self.goal = goal
        self.neck = np.array([*BOTTLE, goal.object_height - 0.035])
        target = BOTTLE + np.asarray(goal.direction) * goal.distance
        self.path = [np.array([0.31, 0.0, 0.49]), self.neck + MISS + [0, 0, 0.1], self.neck + MISS,
                     self.neck + MISS + [0, 0, 0.08], np.array([*target, self.neck[2] + 0.08]) + MISS]
        self.s, self.hand = 0.0, self.path[0].copy()
        self.bottle = np.array([*BOTTLE, goal.object_height / 2])
        self.mode, self.axis, self.state, self.busy_until, self.held = "latent", "x", EMPTY, 0.0, False
        self.modes_seen = []

    def _path_at(self, s: float) -> np.ndarray:
        i = min(int(s), len(self.path) - 2)
        return self.path[i] + (self.path[i + 1] - self.path[i]) * (s - i)

    def step(self, t: float, a) -> None:
        if a.switch_mode:
            self.mode = a.switch_mode
            self.modes_seen.append(a.switch_mode)
        if a.press:
            self.axis = {"x": "y", "y": "z", "z": "x"}[self.axis]
        if a.grasp:
            self.busy_until = t + 0.5
            closing = self.state == OPEN
            err = self.hand - self.neck
            self.held = closing and abs(err[0]) <= 0.01 and abs(err[1]) <= 0.01 and abs(err[2]) <= 0.02
            self.state = BUSY
            self._after = (HOLDING if self.held else EMPTY) if closing else OPEN
        if self.state == BUSY and t >= self.busy_until:
            self.state = self._after
        u = float(np.sign(a.axis)) * max(0.0, abs(a.axis) - DEADBAND) / (1 - DEADBAND)
        before = self.hand.copy()
        if self.mode == "end_effector":
            self.hand["xyz".index(self.axis)] += u * SPEED * DT
        else:
            s = float(np.clip(self.s + u * DT / 1.5, 0.0, len(self.path) - 1.0))
            self.hand += self._path_at(s) - self._path_at(self.s)
            self.s = s
        if self.held:
            self.bottle += self.hand - before
            self.neck += self.hand - before
        elif self.state == OPEN and self.bottle[2] > self.goal.object_height / 2:
            self.bottle[2] = self.goal.object_height / 2   # let go low: it stands

    def seen(self, t: float) -> Observation:
        return Observation(t, self.hand.copy(), self.bottle[:2].copy(), 0, self.axis,
                           obj_z=float(self.bottle[2]), hand_state=self.state, mode=self.mode)


def drive(strategy: str, seed: int = 3, limit: float = 90.0):
    goal = task_goal(TASK, load_catalogue(""))
    op = simulated_participant(HumanParams(), goal, strategy, seed, ("x", "y", "z"), None)
    world = ToyWorld(goal)
    world.mode = STRATEGIES[strategy]   # as the backend sets the controller for the strategy
    t = 0.0
    while t < limit:
        a = op.act(world.seen(t))
        if a.done:
            break
        world.step(t, a)
        t += DT
    target = BOTTLE + np.asarray(goal.direction) * goal.distance
    placed = not world.held and np.linalg.norm(world.bottle[:2] - target) <= 0.05
    return op, world, placed, t


def test_the_hand_participant_reads_only_what_a_person_sees():
    """It imports the participant model and nothing that knows the decoder, the planner or the graph."""
    tree = ast.parse(Path(hand_participant.__file__).read_text())
    imported = {(n.module or "") for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert imported <= {"__future__", "math", "collections", "numpy", "vla_study.participant"}, imported


def test_the_end_effector_alone_grasps_carries_and_places():
    op, world, placed, t = drive("end-effector")
    assert op.done and placed, (op.phase, world.bottle, t)
    assert world.modes_seen == [] and world.mode == "end_effector"   # never switched
    row = op.hand_row()
    assert row["condition"] == "end-effector alone" and row["grasp_presses"] >= 3   # open, grasp, let go


def test_the_latent_alone_never_switches_and_presses_where_its_path_stops():
    """The toy latent's path passes 3 cm short of the neck: the latent alone presses where it stops
    getting nearer and the fingers close on nothing; it never uses end-effector mode."""
    op, world, placed, _t = drive("latent-YOLO")
    assert world.modes_seen == [] and op.hand_row()["condition"] == "latent alone"
    assert op.failed_grasps >= 1 and not placed


def test_hybrid_control_finishes_with_the_end_effector_and_goes_back_to_the_latent():
    op, world, placed, t = drive("hybrid")
    assert op.done and placed, (op.phase, world.bottle, t)
    assert world.modes_seen[:2] == ["end_effector", "latent"]   # the grasp finished in end-effector mode
    assert op.hand_row()["condition"] == "hybrid control" and op.hand_row()["control_switches"] >= 2


def test_hybrid_is_only_for_tasks_with_the_hand():
    goal = task_goal("bread/push_east", load_catalogue(""))
    with pytest.raises(ValueError, match="tasks with the hand"):
        simulated_participant(HumanParams(), goal, "hybrid", 1, ("x", "y", "z"), None)
    assert isinstance(simulated_participant(HumanParams(), task_goal(TASK, load_catalogue("")), "hybrid", 1,
                                            ("x", "y", "z"), None), PickPlaceOperator)


def test_the_protocol_keeps_development_and_test_apart_and_refuses_what_cannot_run(tmp_path):
    p = load_protocol(PROTOCOLS / "pick_place.yaml")
    assert p.strategies == ["latent-YOLO", "end-effector", "hybrid", "latent-YOLO+assist-high"]
    assert p.backend == "graph"
    assert p.layout_seeds >= 600000 and p.development and reused_seeds(p) == []
    dev = load_protocol(PROTOCOLS / "development" / "pick_place.yaml")
    assert dev.role == "development" and dev.layout_seeds < 600000
    dev_file = PROTOCOLS / "development" / "pick_place.yaml"
    text = (PROTOCOLS / "pick_place.yaml").read_text().replace(
        "development: [development/pick_place.yaml]", f"development: [{dev_file}]")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("hand: glass_bottle/pick_place_west", "hand: bread/push_east", 1))
    with pytest.raises(ProtocolError, match="hybrid.*pick_place tasks only"):
        load_protocol(bad)
    bad.write_text(text + "backend: physics\n")
    with pytest.raises(ProtocolError, match="needs backend: graph"):
        load_protocol(bad)
    reuse = tmp_path / "reuse.yaml"   # the development layouts as a test: refused by the runner's check
    reuse.write_text(text.replace("layouts: 600000, operators: test",
                                  "layouts: 300000, operators: development"))
    assert reused_seeds(load_protocol(reuse))


_rows, _bag_joy = study_rows, bag_joy  # test/study_files.py: one home for both study tests


GRAPH_PROTOCOL = """
study: pick-place-ci
participants: sim:1
strategies: [hybrid, end-effector, latent-YOLO+assist-high]
settings:
  hand: glass_bottle/pick_place_west
models:
  hybrid: {hand: glass_bottle_pick_place_west}
  latent-YOLO: {hand: glass_bottle_pick_place_west}
trials: 1
practice: {trials: 0, reset_seed: 7}
counterbalance: none
time_limit: 12
rate: 20
end_effector_axes: ["x", "y", "z"]
end_effector_debounce: 0.15
role: development
seeds: {layouts: 300000, operators: development}
"""


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(900)
def test_a_pick_and_place_trial_runs_through_the_graph_and_its_row_names_the_condition(tmp_path):
    """Three short trials (hybrid control, the end effector, the latent with assistance high) through the
    launched graph in lockstep: each row names its condition, its assistance and the hand's presses, the
    bag holds the grasp button as the controller received it (the reset leaves the hand closed: every
    participant opens it first) and the controller's status shows the condition's assistance level."""
    proto = tmp_path / "pick_place_ci.yaml"
    proto.write_text(GRAPH_PROTOCOL)
    out = tmp_path / "study"
    res = subprocess.run([sys.executable, "-m", "vla_study.cli", "--protocol", str(proto), "--out", str(out),
                          "--serial"], capture_output=True, text=True, timeout=800)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    rows = _rows(out)
    assert [(r["strategy"], r["condition"], r["assistance"]) for r in rows] == [
        ("hybrid", "hybrid control", "off"), ("end-effector", "end-effector alone", "off"),
        ("latent-YOLO+assist-high", "latent with assistance high", "high")]
    for r in rows:
        levels = {m.assistance for m in bag_messages(out / r["bag"], "/controller_node/status")}
        assert levels == {r["assistance"]}, r["key"]
        assert r["backend"] == "graph" and r["simulated"] and r["grasp_presses"] >= 1
        assert "placement_error_m" in r and r["hand_phase"] in ("reach", "close", "carry", "release")
        joy = _bag_joy(out / r["bag"])
        assert any(len(m.buttons) > 2 and m.buttons[2] for m in joy), f"{r['key']}: no grasp press in the bag"
    assert json.loads((out / "study.json").read_text())["simulated"]


def test_the_table_has_a_row_per_condition_on_the_same_layouts():
    """A layout that not every condition ran (a study stopped early) is left out, and the table says so."""
    from vla_study.pick_place import table

    def row(c, seed, ok, err, t):
        return {"condition": c, "participant": "sim:1", "layout_seed": seed, "success": ok, "phase": "test",
                "placement_error_m": err, "time_s": t, "time_limit_s": 60.0, "grasp_presses": 3,
                "failed_grasps": 0, "control_switches": 2 if c == "hybrid control" else 0, "thrown": False}

    rows = [row("latent alone", s, False, 0.15, 60.0) for s in (1, 2)]
    rows += [row("hybrid control", 1, True, 0.01, 20.0), row("hybrid control", 2, False, 0.12, 60.0)]
    rows += [row("end-effector alone", s, True, 0.02, 30.0) for s in (1, 2)]
    text = table(rows)
    body = [x for x in text.splitlines() if x.startswith("| ") and "condition" not in x]
    assert [x.split(" | ")[0] for x in body] == ["| latent alone", "| end-effector alone", "| hybrid control"]
    assert "| 0/2 (0.00) | 15.0 | 60.0 |" in body[0] and "| 1/2 (0.50) | 6.5 | 40.0 | 20.0 |" in body[2]
    assert text.startswith("Simulated participants") and "2 test layouts per condition" in text
    assert "left out" not in text and "the same layouts in each; through" in text
    assert table(rows + [row("latent alone", 3, False, 0.1, 60.0)]) == text.replace(
        "in each;", "in each (1 row on layouts not run in every condition left out);")


def test_a_study_unit_that_fails_leaves_no_graph_for_the_next():
    """On Ray a worker keeps its backend between units: one whose trial failed (the recorder did not
    answer in time on a starved machine) is closed, so the next unit starts a new graph (the old one's
    recorder, still holding the failed trial's bag, refused every later trial of the worker)."""
    from vla_study.on_ray import StudyWorker
    from vla_study.trial import Trial

    class Failing:
        lessons: dict = {}
        closed = False

        def run(self, trial, params, operator_seed):
            raise RuntimeError("timed out waiting for the recorder")

        def close(self):
            Failing.closed = True

    worker = StudyWorker((load_protocol(PROTOCOLS / "pick_place.yaml"), Path("."), False))
    worker.backend = Failing()
    trial = Trial("sim:1", "hybrid", "hand", TASK, 0, "test", 600000, 0)
    with pytest.raises(RuntimeError, match="recorder"):
        worker.run(([trial], HumanParams(), {trial.key: 1}, {}))
    assert Failing.closed and worker.backend is None

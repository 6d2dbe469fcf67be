"""The user study (issue 24): the operator model sees only what a person sees, protocol errors come
with file:line, a killed study resumes without losing or duplicating a trial, and a reduced study
runs end to end (CI) with its figures labelled as simulated."""
from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from study_files import bag_joy, study_rows
from vla_study.protocol import ProtocolError, latin_square, load_protocol
from vla_study.runner import trial_plan
from vla_study.smoothness import sparc, speed_profile
from vla_study.trial import task_goal

from vla_study import participant as part

# what a person sees: the hand, the object, the controller's status; with the hand also the object's
# height, what the fingers show and the controller's mode (hand_participant)
ALLOWED_OBS = {"t", "hand", "obj", "controller_code", "ee_axis", "obj_z", "hand_state", "mode"}


def test_operator_model_imports_nothing_that_knows_the_decoder_or_the_plan():
    tree = ast.parse(Path(part.__file__).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add((node.module or "").split(".")[0])
    assert imported <= {"__future__", "math", "collections", "dataclasses", "numpy"}, imported
    code = ("import sys; import vla_study.participant; "
            "bad = [m for m in sys.modules if m.startswith(('vla_latent_controller', 'vla_sim', "
            "'vla_evaluation.sim_teleoperator', 'vla_evaluation.kinematic'))]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


class GuardedObservation:
    """An observation that fails the test on any attribute but what a person sees."""

    def __init__(self, **kw):
        object.__setattr__(self, "_d", kw)

    def __getattr__(self, name):
        if name not in ALLOWED_OBS:
            raise AssertionError(f"the operator read {name!r}")
        return self._d[name]


def test_operator_reads_only_the_hand_the_object_and_the_status():
    from vla_common.catalogue import load_catalogue

    goal = task_goal("cereal_box/push_south", load_catalogue(""))
    assert set(vars(goal)) == {"kind", "direction", "distance", "object_height", "object_radius"}
    # all the runner can hand it: the goal, its own parameters, a seed, and observations of these fields
    assert {f.name for f in dataclasses.fields(part.Observation)} == ALLOWED_OBS
    # the cycle is what the operator station shows: the names of the end-effector modes, in order; the
    # lesson is what the participant's own practice trial showed it (participant.Lesson: two numbers)
    assert list(inspect.signature(part.HumanOperator).parameters) == ["params", "goal", "mode", "seed",
                                                                      "reach_tol", "cycle", "lesson"]
    assert all(isinstance(v, float) for v in vars(part.Lesson()).values())
    assert all(isinstance(v, (int, float)) for v in vars(part.HumanParams()).values())
    for mode in ("latent", "end_effector"):
        op = part.HumanOperator(part.HumanParams(), goal, mode, seed=1)
        hand = np.array([0.3, 0.0, 0.5])
        for i in range(200):
            a = op.act(GuardedObservation(t=i * 0.05, hand=hand, obj=np.array([0.45, 0.0]),
                                          controller_code=0, ee_axis="x"))
            assert -1.0 <= a.axis <= 1.0
            hand = hand + np.array([0.0, 0.0, -0.002]) * a.axis


@pytest.mark.parametrize("cycle, presses", [(("x", "y", "z"), 1), (part.EE_CYCLE, 4)])
def test_a_mode_switch_costs_the_presses_of_the_cycle_in_use(cycle, presses):
    """From z to x: one press when the button cycles x, y, z (the study's ee_axes), four through roll,
    pitch and yaw with all six; the participant counts them off the cycle the station shows."""
    from vla_common.catalogue import load_catalogue

    goal = task_goal("bread/push_east", load_catalogue(""))
    params = dataclasses.replace(part.HumanParams(), perception_sd_m=1e-5, lapse_p=0.0)
    op = part.HumanOperator(params, goal, "end_effector", seed=3, cycle=cycle)
    obj = np.array([0.5, 0.0])
    first = part.plan_hand_points(goal, np.zeros(3), obj)[0]
    hand = first + np.array([0.25, 0.0, 0.0])  # only x is off: the person wants x
    axis, pressed = "z", 0
    for i in range(100):
        a = op.act(part.Observation(t=i * 0.05, hand=hand, obj=obj, controller_code=0, ee_axis=axis))
        if a.press:  # the controller's cycle moves on
            pressed += 1
            axis = cycle[(cycle.index(axis) + 1) % len(cycle)]
        if a.axis:
            break
    assert axis == "x" and pressed == presses and op.n_switches == 1
    assert op.switch_s == pytest.approx(params.switch_time + presses * params.press_time)


def test_operator_releases_the_stick_when_the_controller_awaits_neutral():
    goal = part.TaskGoal("push", (1.0, 0.0), 0.15, 0.1, 0.05)
    steady = part.HumanParams(lapse_p=0.0, motor_floor=0.0, motor_k=0.0)
    op = part.HumanOperator(steady, goal, "latent", seed=0)
    hand, obj = np.array([0.3, 0.0, 0.5]), np.array([0.5, 0.0])
    axes = [op.act(part.Observation(i * 0.05, hand, obj)).axis for i in range(20)]
    assert any(a != 0 for a in axes)
    a = op.act(part.Observation(1.0, hand, obj, controller_code=part.AWAITING_NEUTRAL))
    assert a.axis == 0.0


def _toy_push(sign: float, params: part.HumanParams, seconds: float = 30.0):
    """A latent axis the person does not know: stick `sign` * u moves the hand along a learned-looking
    path (up over the object, down behind it, then through, pushing it 15 cm south), -u back along
    it, and further back away from the object. The path passes through none of the points a person
    would plan. Returns (operator, pushed m, reported done, how far back it went)."""
    obj0 = np.array([0.5, 0.0])
    knots = np.array([[0.10, 0.0, 0.60], [0.30, 0.0, 0.45], [0.50, 0.0, 0.30], [0.62, 0.02, 0.20],
                      [0.58, 0.0, 0.05], [0.36, 0.0, 0.05]])
    s_knots = np.array([-1.0, 0.0, 0.3, 0.6, 1.0, 2.0])
    goal = part.TaskGoal("push", (-1.0, 0.0), 0.15, 0.10, 0.05)
    op = part.HumanOperator(params, goal, "latent", seed=3)
    s, obj, dt, back = 0.0, obj0.copy(), 0.05, 0.0
    for i in range(int(seconds / dt)):
        hand = np.array([np.interp(s, s_knots, knots[:, k]) for k in range(3)])
        obj[0] = min(obj[0], hand[0] - 0.07) if hand[2] < 0.10 and s > 1.0 else obj[0]
        a = op.act(GuardedObservation(t=i * dt, hand=hand, obj=obj.copy(), controller_code=0, ee_axis="x"))
        if a.done:
            return op, float(obj0[0] - obj[0]), True, back
        s = float(np.clip(s + sign * a.axis * 0.25 * dt, -1.0, 2.0))
        back = min(back, s)
    return op, float(obj0[0] - obj[0]), False, back


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_latent_participant_finds_the_way_by_watching_the_task(sign):
    """Push, watch, reverse: whichever way the learned axis runs, the person pushes the object the
    told distance along a path it never planned, and reverses when the task gets further away."""
    params = part.HumanParams(lapse_p=0.0)
    op, pushed, done, back = _toy_push(sign, params)
    assert done and pushed >= 0.15, (pushed, op.reversals)
    if sign < 0:  # it went the wrong way first, saw it within a second or two and turned
        assert op.reversals >= 1 and back > -0.5, (op.reversals, back)


def test_population_is_seeded_and_varied():
    a, b = part.population(9, 5), part.population(9, 5)
    assert a == b and len({p.reaction_s for p in a}) == 9
    assert all(0.15 <= p.reaction_s <= 0.5 for p in a)


def test_sparc_ranks_a_jerky_profile_below_a_smooth_one():
    t = np.linspace(0, 2, 200)
    smooth = np.sin(np.pi * t / 2) ** 2
    jerky = smooth * (1 + 0.8 * (np.sin(2 * np.pi * 3 * t) > 0))
    assert sparc(jerky, 100.0) < sparc(smooth, 100.0) < 0


def test_a_repeated_stamp_gives_a_finite_speed_and_a_non_finite_speed_no_sparc():
    """A repeated stamp would divide by zero in np.gradient; a NaN or a resting arm's noise (1e-18 m/s,
    a person's trial where the arm never moved) raised an IndexError in SPARC and lost the row."""
    t = np.array([0.0, 0.1, 0.1, 0.2, 0.3, 0.4])
    path = np.stack([t, 0 * t, 0 * t], axis=1)
    speed = speed_profile(path, t)
    assert len(speed) == 5 and np.allclose(speed, 1.0)
    assert np.isnan(sparc(np.array([0.1, np.nan, 0.2, 0.3]), 20.0))
    assert np.isnan(sparc(np.full(81, 3e-18), 20.0))   # a resting arm's noise (it raised IndexError)


def test_latin_square_puts_each_strategy_once_in_each_position():
    for n in (2, 3, 4):
        rows = latin_square(n)
        for r in rows:
            assert sorted(r) == list(range(n))
        for pos in range(n):
            assert sorted(r[pos] for r in rows[:n]) == list(range(n))


def test_protocol_errors_are_refused_with_file_and_line(tmp_path, capsys):
    f = tmp_path / "bad.yaml"
    f.write_text("participants: sim:3\n"
                 "strategies: [latent-YOLO, teleport]\n"
                 "settings:\n"
                 "  Seen: cereal_box/push_sideways\n"
                 "trials: 0\n"
                 "colour: blue\n")
    with pytest.raises(ProtocolError) as e:
        load_protocol(f)
    msgs = e.value.errors
    assert any(m.startswith(f"{f}:2:") and "teleport" in m for m in msgs), msgs
    assert any(m.startswith(f"{f}:4:") and "Seen" in m for m in msgs), msgs
    assert any(m.startswith(f"{f}:5:") and "trials" in m for m in msgs), msgs
    assert any(m.startswith(f"{f}:6:") and "colour" in m for m in msgs), msgs
    # the command refuses it with the same lines and makes nothing
    out = tmp_path / "study"
    res = subprocess.run([sys.executable, "-m", "vla_study.cli", "--protocol", str(f),
                          "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"{f}:2:" in res.stderr and f"{f}:6:" in res.stderr
    assert not out.exists()
    # a valid protocol: --check prints each participant's session and writes nothing
    import argparse

    from vla_study import cli

    f.write_text(REDUCED)
    ap = argparse.ArgumentParser()
    cli.add_arguments(ap)
    assert cli.run(ap.parse_args(["--protocol", str(f), "--participants", "P01,P02", "--out", str(out),
                                  "--check"])) == 0
    printed = capsys.readouterr().out
    assert "2 participants, 4 trials" in printed and "P02:" in printed and not out.exists()
    # the physics backend (gone, issue 33) is refused with why before anything is made, whoever drives
    from vla_study.runner import run_study

    for who in (["P01"], ["sim:1"]):
        with pytest.raises(SystemExit, match="physics backend is gone.*lockstep.*backend: graph"):
            run_study(dataclasses.replace(load_protocol(f), participants=who, backend="physics"), out)
    assert not out.exists()
    f.write_text("participants: sim:3\nstrategies: [latent-YOLO\nsettings: {}\n")  # not YAML
    with pytest.raises(ProtocolError) as e:
        load_protocol(f)
    assert e.value.errors[0].startswith(f"{f}:3:") and "YAML" in e.value.errors[0], e.value.errors


def test_end_effector_axes_without_x_y_z_are_refused_at_their_line(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("participants: sim:1\nstrategies: [end-effector]\nsettings: {Seen: cereal_box/push_south}\n"
                 "end_effector_axes: [x, y, yaw]\n")
    with pytest.raises(ProtocolError) as e:
        load_protocol(f)
    assert e.value.errors[0].startswith(f"{f}:4:") and "including x, y and z" in e.value.errors[0]
    f.write_text(f.read_text().replace("[x, y, yaw]", "[x, y, z]") + "end_effector_debounce: 0.15\n")
    p = load_protocol(f)
    assert p.end_effector_axes == ("x", "y", "z") and p.end_effector_debounce == 0.15
    assert p.backend == "graph"  # the study's default: the launched graph


def test_the_paper_protocol_plans_the_papers_trials():
    from vla_study.protocol import PAPER

    p = load_protocol(PAPER)
    plan = trial_plan(p)
    test = [t for t in plan if t.phase == "test"]
    assert len(test) == 9 * 3 * (4 + 1 + 1 + 1) * 2
    assert len({t.key for t in plan}) == len(plan)
    firsts = {next(t.strategy for t in plan if t.participant == w) for w in p.participants}
    assert firsts == set(p.strategies)  # counterbalanced
    practice = [t for t in plan if t.phase == "practice"]
    assert {t.layout_seed for t in practice} == {p.practice_seed}  # the fixed reset point


REDUCED = """study: ci-reduced
participants: sim:2
strategies: [latent-YOLO, end-effector]
settings:
  Seen: cereal_box/push_south
trials: 1
practice: {trials: 0, reset_seed: 7}
time_limit: 4
rate: 20
"""


_rows, _bag_joy = study_rows, bag_joy  # test/study_files.py: one home for both study tests


def test_the_study_graph_leaves_the_idle_oracle_out(tmp_path):
    """The participant drives: the study's launch starts no sim_teleoperator (an idle one followed
    joint_states and loaded each model change), only the controller is given the models, and the
    camera renders only as often as the latch after a reset needs."""
    from vla_evaluation.graph import CONTROLLER, LAUNCH_FILE, TELEOP, GraphConfig
    from vla_launch.plan import find_launch_file
    from vla_launch.plan import load as load_launch
    from vla_launch.session import argument_text
    from vla_study.graph_backend import study_graph_config
    from vla_study.protocol import SHIPPED

    cfg = study_graph_config(load_protocol(SHIPPED), tmp_path)
    assert TELEOP not in cfg.node_parameters() and cfg.model_nodes() == (CONTROLLER,)
    # the camera only serves the latch after a reset: slower than the evaluation's (rendering is CPU)
    evaluation = GraphConfig(model_path="", detector_model="")
    assert 0 < cfg.launch_arguments()["camera_rate"] < evaluation.camera_rate
    args = {k: argument_text(v) for k, v in cfg.launch_arguments().items()}
    _plan, specs = load_launch(find_launch_file(*LAUNCH_FILE), args, str(tmp_path))
    labels = " ".join(s.label for s in specs)
    assert "controller_node" in labels and "recorder" in labels and "sim_teleoperator" not in labels
    _plan, specs = load_launch(find_launch_file(*LAUNCH_FILE), {}, str(tmp_path))  # the demo keeps it
    assert "sim_teleoperator" in " ".join(s.label for s in specs)


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(1500)
def test_a_killed_study_resumes_without_losing_or_duplicating_a_trial(tmp_path):
    """A reduced study (2 simulated participants x 2 strategies, 4 s trials) through the launched graph
    (the protocol's default backend): killed after its first recorded trial, with half a line left
    behind, then resumed to the end; each trial is a bag holding the participant's stick as the
    controller received it (the end-effector mode button among it when the participant switched), and
    the figures are labelled."""
    proto = tmp_path / "reduced.yaml"
    proto.write_text(REDUCED)
    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "vla_study.cli", "--protocol", str(proto), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 600
    try:
        while not _rows(out) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # waiting on a condition (a row in the file), bounded by the deadline
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    first = _rows(out)
    assert 1 <= len(first) < 4
    with open(out / "trials.jsonl", "a") as f:
        f.write('{"key": "half a li')  # a kill in the middle of a write
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    rows = _rows(out)
    keys = [r["key"] for r in rows]
    assert len(keys) == len(set(keys)) == 4
    # none lost, none twice (on Ray, the default, units finish in any order: rows are written as they end)
    assert sorted(keys) == sorted(t.key for t in trial_plan(load_protocol(proto)))
    assert [r["key"] for r in rows[: len(first)]] == [r["key"] for r in first]  # earlier rows kept
    assert (out / "trials.jsonl.partial").read_text().startswith('{"key": "half')
    for r in rows:
        assert (out / "trials" / f"{r['file']}.npz").is_file()
        assert r["simulated"] and r["n_inputs"] >= 0 and r["path_length_m"] >= 0
        assert r["backend"] == "graph"
        joy = _bag_joy(out / r["bag"])
        assert len(joy) >= 20, f"{r['key']}: {len(joy)} joy messages in {r['bag']}"  # 4 s at 20 Hz
        sticks = [m.axes[0] for m in joy]
        assert any(abs(a) > 0.1 for a in sticks), f"{r['key']}: the stick never moved"
        if r["mode_switches"]:
            assert any(m.buttons[0] for m in joy), f"{r['key']}: no mode button press in the bag"
    assert len({r["bag"] for r in rows}) == 4
    tables = (out / "study_tables.md").read_text()
    assert "simulated participants" in tables
    assert (out / "figure4_success.png").is_file() and (out / "figure3_paths.png").is_file()
    # another protocol in the same folder is refused: earlier results are never overwritten
    proto.write_text(REDUCED.replace("trials: 1", "trials: 2"))
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode != 0 and "another protocol" in (res.stdout + res.stderr)
    assert len(_rows(out)) == 4


def test_anonymise_leaves_no_participant_id_in_the_shared_copy(tmp_path):
    from vla_study.anonymise import anonymise
    from vla_study.trial import file_stem

    src, dest, key = tmp_path / "study", tmp_path / "shared", tmp_path / "private" / "key.csv"
    (src / "trials").mkdir(parents=True)
    rows = []
    for who in ("alice_smith", "sim:1", "bob-jones", "alice_smith"):
        k = f"{who}|latent-YOLO|Seen|cereal_box/push_south|test|{len(rows)}"
        rows.append({"key": k, "file": file_stem(k), "participant": who, "success": True})
        np.savez(src / "trials" / f"{file_stem(k)}.npz", tcp=np.zeros((3, 3)))
    (src / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (src / "likert.jsonl").write_text(json.dumps({"participant": "bob-jones", "strategy": "latent-YOLO",
                                                  "answers": {"easy": 6}}) + "\n")
    (src / "study.json").write_text(json.dumps({"protocol": "/home/alice_smith/lab/p.yaml"}))
    before = {p: p.read_bytes() for p in src.rglob("*") if p.is_file()}
    assert anonymise(src, dest, key) == {"alice_smith": "P01", "sim:1": "sim:1", "bob-jones": "P02"}
    for p in dest.rglob("*"):
        assert "alice" not in p.name and "bob" not in p.name
        if p.suffix in (".jsonl", ".json"):
            assert "alice" not in p.read_text() and "bob" not in p.read_text(), p
    out = [json.loads(x) for x in (dest / "trials.jsonl").read_text().splitlines()]
    assert [r["participant"] for r in out] == ["P01", "sim:1", "P02", "P01"]
    assert len({r["key"] for r in out}) == 4 and all((dest / "trials" / f"{r['file']}.npz").is_file()
                                                     for r in out)
    assert key.read_text().splitlines()[1:] == ["P01,alice_smith", "P02,bob-jones"]
    assert {p: p.read_bytes() for p in src.rglob("*") if p.is_file()} == before  # source untouched
    with pytest.raises(ValueError, match="exists"):
        anonymise(src, dest, tmp_path / "key2.csv")
    with pytest.raises(ValueError, match="outside"):
        anonymise(src, tmp_path / "shared2", tmp_path / "shared2" / "key.csv")


def test_sensitivity_resumes_from_its_rows_and_writes_the_table(tmp_path):
    """Every cell already recorded: nothing runs (no simulator is made) and the tables are written: the
    reaction delay × stick noise grid, and the decision policy varied one parameter at a time beside the
    mean participant (issue 33: the policy parameters varied too)."""
    from vla_study import sensitivity

    rows = []
    for s in ("latent-YOLO", "end-effector"):
        for d in (0.1, 0.5):   # rows of the first version (no `varied`): grid rows
            rows.append({"key": f"{s}|cereal_box/push_south|{d}|0.05|0", "strategy": s, "reaction_s": d,
                         "motor_k": 0.05, "success": d < 0.3})
        rows.append({"key": f"{s}|cereal_box/push_south|mean|0", "strategy": s, "varied": "mean",
                     "value": None, "reaction_s": 0.24, "motor_k": 0.1, "success": True})
        for v in (1, 8):
            rows.append({"key": f"{s}|cereal_box/push_south|stall_turn={v}|0", "strategy": s,
                         "varied": "stall_turn", "value": v, "reaction_s": 0.24, "motor_k": 0.1,
                         "success": v == 1 or s == "end-effector"})
    (tmp_path / "sensitivity.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert sensitivity.main(["--out", str(tmp_path), "--delays", "0.1,0.5", "--noise", "0.05",
                             "--policy", "stall_turn=1,8", "--tasks", "cereal_box/push_south",
                             "--layouts", "1"]) == 0
    table = (tmp_path / "sensitivity.md").read_text()
    assert "**simulated participant**" in table
    assert "| 0.1 | 0.05 | 1/1 | 1/1 |" in table and "| 0.5 | 0.05 | 0/1 | 0/1 |" in table
    assert "| (the mean participant) | – | 1/1 | 1/1 |" in table
    assert "| stall_turn (mean 4) | 1 | 1/1 | 1/1 |" in table
    assert "| stall_turn (mean 4) | 8 | 0/1 | 1/1 |" in table
    assert len((tmp_path / "sensitivity.jsonl").read_text().splitlines()) == len(rows)


def test_the_policy_parameters_change_what_the_participant_does():
    """The sweep's policy parameters are the participant's: a latent participant who turns after one
    unchanged judgement turns sooner than the mean one (4)."""
    goal = part.TaskGoal("push", (1.0, 0.0), 0.15, 0.08, 0.05)

    def reversals(stall_turn: int) -> int:
        p = dataclasses.replace(part.HumanParams(), stall_turn=stall_turn, lapse_p=0.0)
        op = part.HumanOperator(p, goal, "latent", seed=3)
        for i in range(200):   # nothing ever moves: every judgement sees no change
            op.act(part.Observation(i * 0.05, np.array([0.3, 0.0, 0.3]), np.array([0.5, 0.0])))
        return op.reversals

    assert reversals(1) > reversals(4) > 0

"""Honest participants (issue 33): the end-effector participant plans no better than a person told the
goal, and both strategies' participants learn the same kind of thing from their practice trial, carried
to the test trials of the same strategy and setting (and across a resume)."""
from __future__ import annotations

import json
import math

import numpy as np
from vla_common.catalogue import load_catalogue
from vla_common.objects import ObjectPose
from vla_study.protocol import load_protocol
from vla_study.runner import run_study, trial_plan
from vla_study.trial import Measured, Scene, TrialBackend, task_goal

from vla_study import participant as part

CAT = load_catalogue("")


def _behind(goal, plan):
    return float(np.linalg.norm(plan[0][:2] - np.array([0.5, 0.0])))


def test_the_end_effector_plan_has_no_practised_tricks():
    """A push towards the robot (-x) starts as far behind the object as any other (the wrist's extra
    10 cm was practised knowledge); a circle goes round the object's four corners, one axis at a time,
    not a ring of ten points; what practice taught (clearance) adds room."""
    hand, obj = np.array([0.3, 0.0, 0.4]), np.array([0.5, 0.0])
    south = task_goal("soda_can/push_south", CAT)
    north = part.TaskGoal("push", (1.0, 0.0), south.distance, south.object_height, south.object_radius)
    assert south.direction[0] < -0.9
    d_south = _behind(south, part.plan_hand_points(south, hand, obj))
    assert math.isclose(d_south, _behind(north, part.plan_hand_points(north, hand, obj)))
    assert math.isclose(d_south, south.object_radius + 0.04)
    roomier = part.plan_hand_points(south, hand, obj, clearance=0.05)
    assert math.isclose(_behind(south, roomier), d_south + 0.05)
    circle = task_goal("cereal_box/circle", CAT)
    ring = part.plan_hand_points(circle, hand, obj)
    assert len(ring) == 6 and all(np.allclose(ring[i], ring[i + 4]) for i in range(2))
    for a, b in zip(ring, ring[1:]):   # each leg is one axis
        assert int(np.sum(np.abs(a - b) > 1e-9)) == 1
    r = circle.object_radius + 0.04
    assert all(np.allclose(np.abs(p[:2] - obj), r) for p in ring)


def test_both_participants_aim_the_hand_as_low_behind_a_tall_object():
    """The latent participant watches the hand come down behind the cereal box (0.27 m) to the push
    height the end-effector plan goes to (PUSH_LOW_M): lower looks nearer done all the way down. It
    counted the height only to the object's top and reversed during the descent (issue 34)."""
    goal = task_goal("cereal_box/push_south", CAT)
    obj = np.array([0.5, 0.0])
    op = part.HumanOperator(part.HumanParams(), goal, "latent")
    op.start_obj = obj
    behind = obj - np.asarray(goal.direction) * (goal.object_radius + 0.02)
    costs = [op._task_cost(np.array([*behind, z]), obj) for z in (0.30, 0.2, 0.1, part.PUSH_LOW_M)]
    assert all(a > b for a, b in zip(costs, costs[1:]))
    plan = part.plan_hand_points(goal, np.array([0.3, 0.0, 0.4]), obj)
    assert plan[1][2] == part.PUSH_LOW_M and goal.object_height > 0.25


def _observe(op, frames):
    for i, (hand, obj) in enumerate(frames):
        op.act(part.Observation(i * 0.05, np.asarray(hand, float), np.asarray(obj, float)))


def test_an_end_effector_participant_learns_to_give_the_object_room():
    """The object seen to move before the hand got behind and low: the lesson is 5 cm more room (up to
    15 cm); a practice in which it stayed put teaches nothing."""
    goal = task_goal("soda_can/push_south", CAT)
    params = part.HumanParams(perception_sd_m=0.005, lapse_p=0.0)
    op = part.HumanOperator(params, goal, "end_effector", seed=1)
    _observe(op, [((0.3, 0.0, 0.4), (0.5, 0.0))] * 20 + [((0.3, 0.0, 0.4), (0.42, 0.0))] * 20)
    assert op.moved_early and op.lesson().clearance_m == 0.05
    taught = part.HumanOperator(params, goal, "end_effector", seed=1, lesson=part.Lesson(clearance_m=0.15))
    _observe(taught, [((0.3, 0.0, 0.4), (0.5, 0.0))] * 20 + [((0.3, 0.0, 0.4), (0.42, 0.0))] * 20)
    assert taught.lesson().clearance_m == 0.15
    still = part.HumanOperator(params, goal, "end_effector", seed=1)
    _observe(still, [((0.3, 0.0, 0.4), (0.5, 0.0))] * 40)
    assert not still.moved_early and still.lesson() == part.Lesson()


def test_a_latent_participant_learns_which_way_brings_the_task_nearer():
    """Only the stick's negative side brought the hand nearer in practice: the lesson is -1, and a
    participant taught it starts that way (one taught nothing starts at +1)."""
    goal = part.TaskGoal("push", (1.0, 0.0), 0.15, 0.08, 0.05)
    params = part.HumanParams(perception_sd_m=0.002, lapse_p=0.0, motor_k=0.0, motor_floor=0.0)
    op = part.HumanOperator(params, goal, "latent", seed=2)
    hand = np.array([0.1, 0.3, 0.3])
    for i in range(400):   # the hand moves towards the contact point only when the stick is negative
        a = op.act(part.Observation(i * 0.05, hand, np.array([0.5, 0.0])))
        if a.axis < 0:
            hand = hand + 0.004 * (np.array([0.43, 0.0, 0.05]) - hand) / max(1e-9, np.linalg.norm(
                np.array([0.43, 0.0, 0.05]) - hand))
    # (the +1 side gets a little credit: what it sees lags the stick by the reaction delay)
    assert op.progress[-1.0] > 10 * op.progress[1.0] and op.lesson().direction == -1.0
    taught = part.HumanOperator(params, goal, "latent", seed=2, lesson=op.lesson())
    first = next(a.axis for i in range(40) if (a := taught.act(part.Observation(
        i * 0.05, np.array([0.1, 0.3, 0.3]), np.array([0.5, 0.0])))).axis != 0)
    assert first < 0
    assert part.HumanOperator(params, goal, "latent").direction == 1.0


class _Practising(TrialBackend):
    """The skeleton with a made-up drive: every participant's practice teaches 'give it 5 cm'."""

    def __init__(self, protocol):
        self.protocol, self.catalogue, self.seen = protocol, CAT, []

    def prepare(self, trial):
        mode = "latent" if trial.strategy.startswith("latent") else "end_effector"
        return Scene(mode, None, ObjectPose("bread", 0.5, 0.0, 0.0))

    def drive(self, trial, scene, op):
        self.seen.append((trial.key, op.taught))
        op.moved_early = trial.phase == "practice"
        op.progress[-1.0] = 1.0 if trial.phase == "practice" else 0.0
        t = np.linspace(0, 1, 21)
        return Measured(np.zeros((21, 3)), t, np.zeros(21), ok=True, disp=0.15, t_success=1.0, t_done=1.0,
                        t_end=1.0, fse=0.0, interventions=0)


def test_the_practice_lesson_reaches_the_test_trials_and_survives_a_resume(tmp_path):
    """The runner runs each participant's practice first; its lesson is in the practice row, and the
    test trials of the same participant, strategy and setting are run with it, after a stop too."""
    f = tmp_path / "p.yaml"
    f.write_text("participants: sim:2\nstrategies: [latent-YOLO, end-effector]\n"
                 "settings: {base: bread/push_east, Seen: cereal_box/push_south}\ntrials: 1\n"
                 "practice: {trials: 1, reset_seed: 7}\nend_effector_axes: [x, y, z]\n")
    p = load_protocol(f)
    out = tmp_path / "study"
    first = _Practising(p)
    run_study(p, out, backend=first, log=lambda s: None, limit=3)   # sim:1: both practices, one test
    again = _Practising(p)
    run_study(p, out, backend=again, log=lambda s: None)
    rows = {json.loads(x)["key"]: json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()}
    assert len(rows) == len(trial_plan(p))
    for key, r in rows.items():
        if r["phase"] == "practice":
            assert r["taught"] == part.Lesson().to_dict()
            want = {"direction": -1.0, "clearance_m": 0.0} if r["strategy"] == "latent-YOLO" else \
                {"direction": 1.0, "clearance_m": 0.05}
            assert r["lesson"] == want, key
        else:
            practice = next(x for x in rows.values() if x["phase"] == "practice" and all(
                x[k] == r[k] for k in ("participant", "strategy", "setting")))
            assert r["taught"] == practice["lesson"], key   # the resumed ones too
    assert any(key.startswith("sim:1") and taught != part.Lesson() for key, taught in again.seen)

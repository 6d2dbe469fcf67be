"""Assistance as a condition of the study (issue 34): `<strategy>+assist-<level>` in a protocol's
strategies runs that strategy's model with the controller's assistance at that level, beside the
unassisted condition on the same layouts and participants; the level reaches the controller of the graph
each trial, every row and table names it, and the participant's grasp button reaches the assistance."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from vla_common.catalogue import load_catalogue
from vla_common.objects import ObjectPose
from vla_latent_controller.teleop import TeleopCore, TeleopParams
from vla_study.graph_backend import GraphBackend, joy_fields, study_graph_config
from vla_study.hand_participant import PickPlaceOperator
from vla_study.participant import HumanParams
from vla_study.protocol import ProtocolError, load_protocol, model_for
from vla_study.runner import run_study, trial_plan
from vla_study.trial import Measured, Scene, TrialBackend, simulated_participant, task_goal

from vla_study import hand_participant

CAT = load_catalogue("")
PROTOCOLS = Path(hand_participant.__file__).with_name("protocols")
TASK = "glass_bottle/pick_place_west"
AB = (f"participants: sim:2\nstrategies: [latent-YOLO, latent-YOLO+assist-high, end-effector]\n"
      f"settings: {{hand: {TASK}}}\nmodels: {{latent-YOLO: {{hand: glass_bottle_pick_place_west}}}}\n"
      "trials: 2\npractice: {trials: 1, reset_seed: 7}\nend_effector_axes: [x, y, z]\n")


def _protocol(tmp_path, text: str = AB):
    f = tmp_path / "p.yaml"
    f.write_text(text)
    return load_protocol(f)


def test_an_assisted_condition_stands_beside_its_strategy_on_the_same_layouts_and_model(tmp_path):
    p = _protocol(tmp_path)
    plan = [t for t in trial_plan(p) if t.phase == "test"]
    by = {s: [(t.participant, t.layout_seed) for t in plan if t.strategy == s] for s in p.strategies}
    assert by["latent-YOLO+assist-high"] == by["latent-YOLO"] == by["end-effector"]
    assisted = next(t for t in plan if t.strategy == "latent-YOLO+assist-high")
    assert model_for(p, assisted) == "glass_bottle_pick_place_west"
    shipped = load_protocol(PROTOCOLS / "development" / "pick_place.yaml")
    assert "latent-YOLO+assist-high" in shipped.strategies


@pytest.mark.parametrize("strategies, said", [
    ("[end-effector+assist-high]", "end effector has no assistance"),
    ("[latent-YOLO+assist-medium]", "strategies[0]"),
    ("[latent-YOLO+assist-off]", "strategies[0]"),
])
def test_an_assistance_the_controller_has_not_or_the_end_effector_is_refused(tmp_path, strategies, said):
    with pytest.raises(ProtocolError, match=said.replace("[", r"\[").replace("]", r"\]")):
        _protocol(tmp_path, AB.replace("[latent-YOLO, latent-YOLO+assist-high, end-effector]", strategies))


def test_an_assisted_condition_drives_its_strategys_models_not_its_own(tmp_path):
    """One home for the models: `models` is keyed by the strategy; an assisted name there is refused."""
    text = AB.replace("models: {latent-YOLO:", "models: {latent-YOLO+assist-high:")
    with pytest.raises(ProtocolError, match="models"):
        _protocol(tmp_path, text)


class _Fake(TrialBackend):
    """The skeleton with a made-up drive (no graph)."""

    def __init__(self, protocol):
        self.protocol, self.catalogue = protocol, CAT

    def prepare(self, trial):
        return Scene("latent", None, ObjectPose("glass_bottle", 0.5, 0.0, 0.0))

    def drive(self, trial, scene, op):
        t = np.linspace(0, 1, 21)
        return Measured(np.zeros((21, 3)), t, np.zeros(21), ok=True, disp=0.0, t_success=1.0, t_done=1.0,
                        t_end=1.0, fse=0.0, interventions=0, extra={"placement_error_m": 0.01})


def test_every_row_and_table_names_the_assistance(tmp_path):
    from vla_study.analysis import analyse
    from vla_study.pick_place import table, test_rows

    p = _protocol(tmp_path)
    out = tmp_path / "study"
    run_study(p, out, backend=_Fake(p), log=lambda s: None)
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert len(rows) == len(trial_plan(p))
    for r in rows:
        want = "high" if r["strategy"] == "latent-YOLO+assist-high" else "off"
        assert r["assistance"] == want, r["key"]
        assert r["condition"] == {"high": "latent with assistance high"}.get(want, r["condition"])
    text = table(test_rows(out / "trials.jsonl"))
    body = [x.split(" | ")[0] for x in text.splitlines() if x.startswith("| ")]
    assert body[1:] == ["| latent alone", "| end-effector alone", "| latent with assistance high"]
    tables = "\n".join(analyse(out, tmp_path / "figures", 60.0))
    assert "| latent-YOLO, assistance high | " in tables and "| latent-YOLO | " in tables
    assert "Assisted conditions (latent-YOLO, assistance high)" in tables


class _Obs:
    def __init__(self):
        self.sent = []

    def set_parameters(self, node, values):
        self.sent.append((node, dict(values)))


class _Ev:
    def __init__(self):
        self.obs, self.models = _Obs(), []

    def set_model(self, path):
        self.models.append(path)


@pytest.mark.parametrize("strategy, mode, level", [("latent-YOLO+assist-high", "latent", "high"),
                                                    ("latent-YOLO", "latent", "off"),
                                                    ("end-effector", "end_effector", "off")])
def test_the_level_reaches_the_graphs_controller_every_trial(tmp_path, strategy, mode, level):
    """Set with the mode each trial, so that no trial inherits the one before's (a Ray worker runs any)."""
    p = _protocol(tmp_path)
    backend = object.__new__(GraphBackend)
    backend.protocol, backend.ev = p, _Ev()
    trial = next(t for t in trial_plan(p) if t.strategy == strategy)
    assert backend._set_strategy(trial) == mode
    assert backend.ev.obs.sent == [("controller_node", {"mode": mode, "assistance": level})]
    assert bool(backend.ev.models) == (mode == "latent")


def test_the_participants_grasp_button_reaches_the_controllers_assistance(tmp_path):
    """The study's Joy (graph_backend.joy_fields) on the controller as the study's graph sets it up:
    the participant's grasp press is the press the assistance waits for at the grasp pose."""
    p = _protocol(tmp_path)
    extra = study_graph_config(p, tmp_path).extra_params["controller_node"]
    params = TeleopParams(**{k: v for k, v in extra.items() if k in TeleopParams.__dataclass_fields__},
                          assistance="high")
    core = TeleopCore(params)
    core.on_joy(*joy_fields(0.4), 0.0)
    core.on_joy(*joy_fields(0.0, grasp=True), 0.05)
    core.on_joy(*joy_fields(0.0, grasp=True), 0.10)   # held: one press
    core.on_joy(*joy_fields(0.0), 0.15)
    assert core.grasp_presses == 1 and core.assist._presses == 1
    op = simulated_participant(HumanParams(), task_goal(TASK, CAT), "latent-YOLO+assist-high", 1,
                               ("x", "y", "z"), None)
    assert isinstance(op, PickPlaceOperator) and op.assistance == "high" and op.mode == "latent"


def test_one_condition_runs_alone_and_the_folder_keeps_the_rest_for_later(tmp_path):
    """`--only`: the assisted condition beside conditions already run elsewhere, the protocol unchanged."""
    p = _protocol(tmp_path)
    out = tmp_path / "study"
    run_study(p, out, backend=_Fake(p), log=lambda s: None, only=("latent-YOLO+assist-high",))
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert {r["strategy"] for r in rows} == {"latent-YOLO+assist-high"}
    assert len(rows) == sum(t.strategy == "latent-YOLO+assist-high" for t in trial_plan(p))
    run_study(p, out, backend=_Fake(p), log=lambda s: None)
    assert len((out / "trials.jsonl").read_text().splitlines()) == len(trial_plan(p))


def test_the_pick_and_place_table_puts_a_condition_run_alone_beside_the_others(tmp_path):
    """`python -m vla_study.pick_place --also`: the assisted condition's rows (a folder of its own) beside
    the three conditions' rows of an earlier run on the same layouts."""
    from vla_study.pick_place import main

    def row(c, seed, ok):
        return {"condition": c, "participant": "sim:1", "layout_seed": seed, "success": ok, "phase": "test",
                "placement_error_m": 0.01 if ok else 0.2, "time_s": 20.0 if ok else 60.0,
                "time_limit_s": 60.0, "grasp_presses": 3, "failed_grasps": 0, "control_switches": 0,
                "thrown": False}

    earlier = tmp_path / "earlier.jsonl"
    earlier.write_text("".join(json.dumps(row(c, s, False)) + "\n" for c in ("latent alone", "hybrid control")
                               for s in (1, 2)))
    out = tmp_path / "assisted"
    out.mkdir()
    (out / "trials.jsonl").write_text("".join(json.dumps(row("latent with assistance high", s, True)) + "\n"
                                              for s in (1, 2)))
    assert main(["--out", str(out), "--also", str(earlier)]) == 0
    body = [x for x in (out / "pick_place.md").read_text().splitlines() if x.startswith("| ")][1:]
    assert [x.split(" | ")[:2] for x in body] == [["| latent alone", "0/2 (0.00)"],
                                                 ["| hybrid control", "0/2 (0.00)"],
                                                 ["| latent with assistance high", "2/2 (1.00)"]]


def test_the_prepared_paper_protocol_puts_assisted_latent_yolo_beside_the_paper_conditions():
    from vla_study.runner import reused_seeds

    paper, assisted = load_protocol(PROTOCOLS / "paper.yaml"), load_protocol(PROTOCOLS / "paper_assist.yaml")
    assert assisted.strategies == ["latent-YOLO", "latent-YOLO+assist-high", "end-effector"]
    assert reused_seeds(assisted) == [] and assisted.settings == paper.settings

    def layouts(p, s):
        return [(t.participant, t.task, t.layout_seed) for t in trial_plan(p) if t.strategy == s]

    assert layouts(assisted, "latent-YOLO+assist-high") == layouts(paper, "latent-YOLO")
    assert layouts(assisted, "end-effector") == layouts(paper, "end-effector")

    def models(p, s):   # the A/B differs only in the assistance: both drive paper.yaml's matched set
        return [(t.participant, t.task, model_for(p, t)) for t in trial_plan(p) if t.strategy == s]

    assert models(assisted, "latent-YOLO+assist-high") == models(assisted, "latent-YOLO") \
        == models(paper, "latent-YOLO")

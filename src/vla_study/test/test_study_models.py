"""The study's matched models (issue 33, fair comparisons): a protocol names one model per training seed,
each participant drives one seed's models; every strategy's models are made from the same
demonstrations with the same recipe; what is tuned (the path fraction) is tuned on development layouts
only; the oracle runs every model on every study layout."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from vla_study.layouts import development_layouts, trial_layouts
from vla_study.protocol import PAPER, STRATEGIES, ProtocolError, load_protocol, model_for, model_names
from vla_study.runner import _model, trial_plan

from vla_study import model_set, oracle

SEEDED = """participants: sim:6
strategies: [latent-YOLO, latent-localization, end-effector]
settings:
  base: [bread/push_east, soda_can/push_south]
  Far: cereal_box/circle
trials: 2
models:
  latent-YOLO: {base: [y0, y1, y2], Far: [yf0, yf1, yf2]}
  latent-localization: {base: [l0, l1, l2], Far: lf}
"""


def _write(tmp_path, text: str, name: str = "p.yaml"):
    f = tmp_path / name
    f.write_text(text)
    return f


def test_each_participant_drives_one_seed_of_every_setting_in_every_trial(tmp_path):
    p = load_protocol(_write(tmp_path, SEEDED))
    assert model_names(p, "latent-YOLO", "base") == ["y0", "y1", "y2"]
    assert model_names(p, "latent-localization", "Far") == ["lf"]   # one name: every participant
    used: dict[str, set[str]] = {}
    for t in trial_plan(p):
        if STRATEGIES[t.strategy] != "latent":
            assert _model(p, t) is None   # the end effector drives no model
            continue
        i = p.participants.index(t.participant)
        names = model_names(p, t.strategy, t.setting)
        assert model_for(p, t) == _model(p, t) == names[i % len(names)]
        used.setdefault(f"{t.participant}|{t.strategy}", set()).add(model_for(p, t)[-1])
    # practice and test trials, base and Far: one seed's models per participant and strategy
    assert used["sim:2|latent-YOLO"] == {"1"} and used["sim:6|latent-YOLO"] == {"2"}
    # the seeds spread evenly: 6 participants, each seed driven by 2
    per_seed = Counter(model_for(p, t) for t in trial_plan(p)
                       if t.strategy == "latent-YOLO" and t.setting == "base" and t.phase == "test")
    assert sorted(per_seed.values()) == [8, 8, 8]


@pytest.mark.parametrize("models, says", [
    ("{base: []}", "at least 1 item"),
    ("{base: [a, a]}", "listed twice"),
    ("{base: [a, 3]}", "valid string"),
])
def test_a_bad_list_of_models_is_refused_with_its_line(tmp_path, models, says):
    text = ("participants: sim:2\nstrategies: [latent-YOLO]\nsettings:\n  base: bread/push_east\n"
            f"models:\n  latent-YOLO: {models}\n")
    with pytest.raises(ProtocolError) as e:
        load_protocol(_write(tmp_path, text))
    assert any(":6:" in x and says in x for x in e.value.errors), e.value.errors


def test_every_listed_model_must_be_installed(tmp_path):
    with pytest.raises(ProtocolError) as e:
        load_protocol(_write(tmp_path, SEEDED), model_exists=lambda name: name != "y1")
    assert len(e.value.errors) == 1 and "'y1' is not installed" in e.value.errors[0]


def test_both_strategies_get_the_same_demonstrations_and_recipe_for_each_seed_and_setting():
    p = load_protocol(PAPER)
    recipe = model_set.Recipe()
    units = model_set.units_of(p, recipe)
    assert len(units) == 2 * len(p.settings) * len(recipe.seeds) == 24
    pairs: dict[tuple, list] = {}
    for u in units:
        pairs.setdefault((u.setting, u.seed), []).append(u)
    for (_setting, seed), (a, b) in pairs.items():
        assert {a.strategy, b.strategy} == {"latent-YOLO", "latent-localization"}
        assert a.tasks == b.tasks and a.seed == b.seed == seed
        ca, cb = recipe.train_config(a.encoder, seed), recipe.train_config(b.encoder, seed)
        assert {k: v for k, v in vars(ca).items() if k != "encoder"} == \
               {k: v for k, v in vars(cb).items() if k != "encoder"}
        assert (ca.epochs, ca.step_size, ca.min_steps) == (100, 40, 1000)
    # the few-shot models add their own task to the very base demonstrations of their seed
    far = next(u for u in units if u.setting == "Far" and u.seed == 1)
    base = next(u for u in units if u.setting == "base" and u.seed == 1)
    assert far.tasks[:-1] == base.tasks and far.tasks[-1] == "cereal_box/circle"
    # each seed its own demonstrations, and no two tasks share a seed within one
    seeds = {model_set.demo_seed(t, s) for s in recipe.seeds for t in far.tasks + ("cereal_box/push_south",)}
    assert len(seeds) == 3 * 6


def test_the_improved_training_is_a_set_of_its_own_on_the_same_demonstrations_and_schedule(tmp_path):
    """Issue 34's A/B of training: `--rest-samples`/`--corrective-copies` make `..._ends_s<seed>` models
    from the very demonstrations, epochs and seeds of the paper's set, the pairs taught where a task
    ends; the paper's set keeps its name and recipe digest (its shipped models stay valid), and a bad
    value is refused before anything is made."""
    p = load_protocol(PAPER)
    paper, ends = model_set.Recipe(), model_set.Recipe(rest_samples=10, corrective_copies=2)
    assert paper.digest() == model_set.read_provenance(
        Path(model_set.SOURCE_MODELS) / "matched_detector_base_s0")["recipe_digest"]
    assert ends.digest() != paper.digest() and (paper.variant, ends.variant) == ("", "ends")
    a, b = model_set.units_of(p, paper), model_set.units_of(p, ends)
    assert [u.name for u in b][:2] == ["matched_detector_base_ends_s0", "matched_localization_base_ends_s0"]
    assert [(u.strategy, u.setting, u.tasks, u.seed) for u in a] == [(u.strategy, u.setting, u.tasks, u.seed)
                                                                  for u in b]
    ca, cb = paper.train_config("detector", 1), ends.train_config("detector", 1)
    assert (cb.rest_samples, cb.corrective_copies) == (10, 2)
    assert (ca.rest_samples, ca.corrective_copies) == (0, 0)
    assert {k: v for k, v in vars(ca).items() if k not in ("rest_samples", "corrective_copies")} == \
           {k: v for k, v in vars(cb).items() if k not in ("rest_samples", "corrective_copies")}
    assert model_set.protocol_models(["latent-YOLO"], ["Seen"], (0, 1), "ends") == {
        "latent-YOLO": {"Seen": ["matched_detector_seen_ends_s0", "matched_detector_seen_ends_s1"]}}
    assert model_set.main(["--out", str(tmp_path), "--corrective-sigma", "0", "--serial"]) == 2
    assert list(tmp_path.iterdir()) == []


def test_development_layouts_are_never_test_layouts():
    p = load_protocol(PAPER)
    for setting in p.settings:
        dev = development_layouts(p, setting)
        assert dev and not set(dev) & set(trial_layouts(p, setting))
        assert {t for t, _ in dev} <= set(p.settings[setting])


def test_a_development_file_that_holds_a_test_layout_is_refused(tmp_path):
    dev = _write(tmp_path, "role: development\n" + SEEDED.replace("trials: 2", "trials: 1"), "dev.yaml")
    test = _write(tmp_path, SEEDED + f"development: [{dev.name}]\n")
    with pytest.raises(ValueError, match="are test layouts of"):
        development_layouts(load_protocol(test), "base")


def test_the_path_fraction_is_chosen_on_the_development_layouts_alone(tmp_path, monkeypatch):
    """model_set renders (and so measures on) exactly the development layouts of each model's setting."""
    p = load_protocol(PAPER)
    seen: list = []
    monkeypatch.setattr(model_set, "render_layouts", lambda dev: seen.extend(dev) or ["layout"])
    monkeypatch.setattr("vla_evaluation.path_fraction.choose_path_fraction", _fake_choice)
    monkeypatch.setattr("vla_evaluation.path_fraction.set_path_fraction", lambda *a: None)
    monkeypatch.setattr("vla_latent_controller.model.LatentModel.load", staticmethod(lambda path: None))
    units = [u for u in model_set.units_of(p, model_set.Recipe(seeds=(0,))) if u.strategy == "latent-YOLO"]
    for u in units:
        (tmp_path / u.name).mkdir()
        (tmp_path / u.name / model_set.PROVENANCE).write_text("{}")
    model_set.choose_fractions(tmp_path, units, p, log=lambda s: None)
    tests = set(trial_layouts(p))
    assert seen and not set(seen) & tests
    assert set(seen) == {x for s in p.settings for x in development_layouts(p, s)}


def _fake_choice(model, layouts, settings, fractions):
    from vla_evaluation.path_fraction import FractionChoice

    return FractionChoice(1.0, {1.0: 0.0}, len(layouts))


def test_the_oracle_runs_every_model_on_every_test_layout_or_each_participants_own():
    p = load_protocol(PAPER)
    latent = [s for s in p.strategies if STRATEGIES[s] == "latent"]
    every = oracle.oracle_units(p)
    n_layouts = sum(len(trial_layouts(p, s)) for s in p.settings)
    names = {s: {k: model_names(p, s, k) for k in p.settings} for s in latent}
    assert len(every) == sum(len(trial_layouts(p, k)) * len(names[s][k]) for s in latent for k in p.settings)
    mine = oracle.oracle_units(p, models="assigned")
    assert len(mine) == len(latent) * n_layouts   # one model per layout: its participant's
    want = {(t.strategy, t.setting, model_for(p, t), t.task, t.layout_seed) for t in trial_plan(p)
            if t.phase == "test" and STRATEGIES[t.strategy] == "latent"}
    assert {(u.strategy, u.setting, u.model, u.task, u.layout_seed) for u in mine} == want
    dev = oracle.oracle_units(p, layouts="development", loop="kinematic", per_task=2)
    assert all(u.loop == "kinematic" for u in dev)
    assert max(Counter((u.model, u.task) for u in dev).values()) == 2


def test_the_oracle_runs_a_chosen_strategy_alone_on_the_same_episodes():
    """`--strategies latent-YOLO`: the method's episodes, keyed as in the whole table (a run resumes)."""
    p = load_protocol(PAPER)
    mine = oracle.oracle_units(p, models="assigned")
    alone = oracle.oracle_units(p, models="assigned", strategies=["latent-YOLO"])
    assert alone == [u for u in mine if u.strategy == "latent-YOLO"] and alone
    with pytest.raises(ValueError, match="end-effector: not among the protocol's latent strategies"):
        oracle.oracle_units(p, strategies=["end-effector"])


def _row(model, seed_index, task, seed, success, strategy="latent-YOLO", setting="base"):
    return {"strategy": strategy, "setting": setting, "model": model, "seed_index": seed_index, "task": task,
            "layout_seed": seed, "loop": "graph", "layouts": "test", "success": success,
            "final_state_error": 0.1, "waypoint_error": 0.1, "note": "", "time_to_success_s": None}


def test_the_oracle_table_gives_each_model_seed_then_the_seeds_together(tmp_path):
    rows = [_row("m0", 0, "bread/push_east", 1, True), _row("m0", 0, "bread/push_east", 2, False),
            _row("m1", 1, "bread/push_east", 1, True), _row("m1", 1, "bread/push_east", 2, True)]
    text = oracle.oracle_tables(rows)
    assert "| latent-YOLO | base | 1/2 (0.10 rad) | 2/2 (0.10 rad) | 3/4 (0.10 rad) |" in text
    assert "simulated" in text


def test_the_participants_are_shown_beside_the_oracle_on_their_own_layouts_and_model(tmp_path):
    p = load_protocol(_write(tmp_path, SEEDED))
    trials = [t for t in trial_plan(p) if t.phase == "test" and t.strategy == "latent-YOLO"
              and t.setting == "base" and t.participant in ("sim:1", "sim:2")]
    study = [{"key": t.key, "success": t.participant == "sim:1", "model": model_for(p, t)} for t in trials]
    rows = [_row(model_for(p, t), 0, t.task, t.layout_seed, True) for t in trials]
    text = oracle.beside_participants(rows, study, p)
    assert "| latent-YOLO | base | y0 | 4/4 | 4/4 |" in text
    assert "| latent-YOLO | base | y1 | 0/4 | 4/4 |" in text


def test_the_graph_backend_drives_each_participants_model(tmp_path):
    """Two participants, two models listed: sim:1's trials set the controller to the first model, sim:2's
    to the second (the graph backend asks the controller for protocol.model_for's model)."""
    from vla_study.graph_backend import GraphBackend
    from vla_study.runner import trial_plan

    f = _write(tmp_path, "participants: sim:2\nstrategies: [latent-YOLO]\nsettings: {base: bread/push_east}\n"
                         "trials: 1\npractice: {trials: 0, reset_seed: 7}\ntime_limit: 1\n"
                         "models:\n  latent-YOLO: {base: [default, cereal_box_push_south]}\n")
    p = load_protocol(f)
    asked = []

    class Graph:   # the evaluator's side the backend talks to: the controller's mode and model
        obs = type("Obs", (), {"set_parameters": lambda self, node, values: None})()

        def set_model(self, path):
            asked.append(Path(path).name)

    backend = object.__new__(GraphBackend)     # its parts, not a launched graph
    backend.protocol, backend.ev, backend.mode = p, Graph(), None
    for t in sorted(trial_plan(p), key=lambda t: t.participant):
        backend._set_strategy(t)
    assert asked == ["default", "cereal_box_push_south"]


def test_the_shipped_matched_models_come_in_pairs_trained_alike():
    """Every shipped matched model (model_set's name) has its other strategy's model for the same setting
    and seed, trained on the same trajectories (the training fingerprint hashes them), counts and seeds,
    with the same epochs and updates, by this recipe; its path fraction was chosen on the development
    layouts of its setting in paper.yaml (the provenance says how many) and is the one the model uses."""
    from vla_evaluation.resources import SOURCE_MODELS
    from vla_latent_controller.model import LatentModel

    p, recipe = load_protocol(PAPER), model_set.Recipe()
    shipped = {u.name: u for u in model_set.units_of(p, recipe) if (SOURCE_MODELS / u.name).is_dir()}
    assert shipped, "no matched model ships"
    pairs: dict[tuple[str, int], list] = {}
    for name, u in shipped.items():
        path = SOURCE_MODELS / name
        prov, cfg = model_set.read_provenance(path), LatentModel.load(path).config
        assert prov["recipe_digest"] == recipe.digest() and prov["training_seed"] == u.seed, name
        assert prov["path_fraction"]["chosen"] == cfg["latent"]["path_fraction"], name
        assert prov["path_fraction"]["layouts"] == len(development_layouts(p, u.setting)), name
        t = cfg["training"]
        want = {k: recipe.base_demos if k in p.settings["base"] else recipe.fewshot_demos for k in u.tasks}
        assert t["demos_per_task"] == want, name
        pairs.setdefault((u.setting, u.seed), []).append(
            (prov["demo_seeds"], t["demos_per_task"], cfg["fingerprint"]["sha256"], t["epochs"],
             t["optimiser_steps"], cfg["hyper_parameters"]["seed"]))
    for key, facts in pairs.items():
        assert len(facts) == len(model_set.ENCODERS) and facts[0] == facts[1], key


def test_the_paper_protocol_gives_both_strategies_the_same_demonstrations_and_training():
    """What ships: paper.yaml names the matched set (model_set's names, one per seed), and for every
    setting and seed the latent-YOLO and the localization-only model were trained on the same
    trajectories (the training fingerprint hashes them), the same counts and seeds, the same epochs and
    optimiser updates; each path fraction was chosen by the one procedure on development layouts."""
    from vla_evaluation.resources import latent_model_dir
    from vla_latent_controller.model import LatentModel

    p = load_protocol(PAPER, model_exists=lambda n: (latent_model_dir(n) / "config.json").is_file())
    latent = [s for s in p.strategies if STRATEGIES[s] == "latent"]
    recipe = model_set.Recipe()
    assert {s: p.models[s] for s in latent} == model_set.protocol_models(latent, p.settings, recipe.seeds)
    for setting in p.settings:
        for i in range(len(recipe.seeds)):
            facts = []
            for s in latent:
                path = latent_model_dir(model_names(p, s, setting)[i])
                prov = model_set.read_provenance(path)
                cfg = LatentModel.load(path).config
                assert prov["recipe_digest"] == recipe.digest() and prov["training_seed"] == recipe.seeds[i]
                assert prov["path_fraction"]["chosen"] == cfg["latent"]["path_fraction"]
                assert prov["path_fraction"]["layouts"] == len(development_layouts(p, setting))
                t = cfg["training"]
                facts.append((prov["demo_seeds"], t["demos_per_task"], cfg["fingerprint"]["sha256"],
                              t["epochs"], t["optimiser_steps"], cfg["hyper_parameters"]["seed"]))
            assert facts[0] == facts[1], (setting, i)
            per_task = facts[0][1]
            assert all(n == (9 if t in p.settings["base"] else 3) for t, n in per_task.items())

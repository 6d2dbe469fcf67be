"""Honest reporting (issue 33): per setting first, then the settings weighed equally; a failure's time is
the limit; thrown objects flagged in the rows and counted apart; simulated results labelled."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
from vla_common.objects import ObjectPose
from vla_study.analysis import analyse, per_participant
from vla_study.outcome import THROWN_M
from vla_study.trial import trial_row


def _row(who, setting, ok, *, strategy="latent-YOLO", time_s=5.0, disp=0.12, k=0, limit=None):
    r = {"key": f"{who}|{strategy}|{setting}|t|test|{k}", "file": f"f{who}{strategy}{setting}{k}",
         "participant": who, "strategy": strategy, "setting": setting, "phase": "test", "success": ok,
         "time_s": time_s, "duration_s": time_s, "object_displacement_m": disp, "simulated": True,
         "backend": "physics", "path_length_m": 1.0, "sparc": -3.0, "ldlj": -15.0, "n_inputs": 3,
         "mode_switches": 0, "mode_switch_s": None, "object_start": {"x": 0.5, "y": 0.0}}
    if limit is not None:
        r["time_limit_s"] = limit
    return r


def _study(tmp_path, rows):
    out = tmp_path / "study"
    out.mkdir(parents=True)
    (out / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return out


def test_the_aggregate_weighs_each_setting_once_not_each_trial(tmp_path):
    """Base has 8 trials per participant, Far 1: 8/8 and 0/1 pool to 0.89 by trial, but each setting
    counts once: 0.50. The table gives each setting first, then that equal-weight aggregate."""
    rows = []
    for who in ("sim:1", "sim:2"):
        rows += [_row(who, "base", True, k=k) for k in range(8)] + [_row(who, "Far", False, time_s=3.0)]
    out = _study(tmp_path, rows)
    assert per_participant(rows, "success", "latent-YOLO") == {"sim:1": 0.5, "sim:2": 0.5}
    text = "\n".join(analyse(out, out, time_limit=30.0))
    table = text.split("## Success per setting")[1].split("##")[0]
    assert "| base | Far | settings, equal weight |" in table
    assert "| latent-YOLO | 16/16 (1.00 ± 0.00) | 0/2 (0.00 ± 0.00) | 0.50 ± 0.00 |" in table
    assert "0.89" not in table


def test_the_tables_follow_the_protocols_order_not_the_order_units_finished(tmp_path):
    """A sweep finishes units in any order (a Far unit first, the end effector before latent-YOLO): the
    tables list strategies and settings as the protocol does, so that two runs read alike."""
    rows = [_row("sim:1", "Far", False, strategy="end-effector"), _row("sim:1", "base", True),
            _row("sim:1", "Far", True), _row("sim:1", "base", True, strategy="end-effector")]
    out = _study(tmp_path, rows)
    text = "\n".join(analyse(out, out, 30.0, ["latent-YOLO", "end-effector"], ["base", "Far"]))
    table = text.split("## Success per setting")[1].split("##")[0]
    assert "| strategy | base | Far | settings, equal weight |" in table
    assert table.index("| latent-YOLO |") < table.index("| end-effector |")
    unordered = "\n".join(analyse(out, out, 30.0)).split("## Success per setting")[1]
    assert "| strategy | Far | base |" in unordered   # without the protocol: as the rows came


def test_a_failures_time_is_the_limit(tmp_path):
    """A participant who gave up after 3 s did not fail faster: the failure counts 30 s (the limit), in the
    scorer's row and, for rows made before, in the analysis."""
    op = SimpleNamespace(n_inputs=1, n_switches=0, switch_s=0.0, reversals=0, lapses=0)
    t = np.linspace(0.0, 3.0, 61)
    path = np.c_[0.4 + 0.01 * t, np.zeros_like(t), 0.2 + 0 * t]
    common = dict(disp=0.02, t_success=None, t_done=3.0, t_end=3.0, fse=0.1, interventions=0,
                  start=ObjectPose("bread", 0.5, 0.0, 0.0), note="", time_limit=30.0)
    row, _ = trial_row(op, path, t, np.zeros(61), ok=False, **common)
    assert row["time_s"] == 30.0 and row["duration_s"] == 3.0 and row["time_limit_s"] == 30.0
    row, _ = trial_row(op, path, t, np.zeros(61), ok=True, **common)
    assert row["time_s"] == 3.0   # a success at the participant's "done" (no tracked success time)
    rows = [_row("sim:1", "base", False, time_s=3.0), _row("sim:1", "base", True, time_s=10.0, k=1)]
    out = _study(tmp_path, rows)
    text = "\n".join(analyse(out, out, time_limit=30.0))
    assert "| latent-YOLO | 20.0 | 20.0 |" in text.split("## Time per setting")[1]   # (30 + 10) / 2


def test_thrown_objects_are_flagged_in_the_rows_and_reported(tmp_path):
    op = SimpleNamespace(n_inputs=1, n_switches=0, switch_s=None, reversals=0, lapses=None)
    t = np.linspace(0.0, 1.0, 21)
    args = dict(t_success=None, t_done=None, t_end=1.0, fse=0.1, interventions=0,
                start=ObjectPose("bread", 0.5, 0.0, 0.0), note="", time_limit=30.0)
    path, stick = np.zeros((21, 3)), np.zeros(21)
    assert trial_row(op, path, t, stick, ok=False, disp=THROWN_M + 0.4, **args)[0]["thrown"]
    assert not trial_row(op, path, t, stick, ok=True, disp=0.15, **args)[0]["thrown"]
    rows = [_row("sim:1", "base", False, disp=2.9), _row("sim:1", "base", True, k=1),
            _row("sim:2", "base", False, disp=0.49)]   # a row made before the flag: from its displacement
    out = _study(tmp_path, rows)
    text = "\n".join(analyse(out, out, time_limit=30.0))
    thrown = text.split("## Thrown objects")[1].split("##")[0]
    assert "| latent-YOLO | 1/3 |" in thrown and "sim:1|latent-YOLO|base|t|test|0: 2.90 m" in thrown
    assert "0.49" not in thrown


def test_simulated_results_are_labelled_and_worded_as_a_models(tmp_path):
    rows = [_row("sim:1", "base", True), _row("sim:1", "base", True, strategy="end-effector")]
    out = _study(tmp_path, rows)
    text = "\n".join(analyse(out, out, time_limit=30.0))
    for heading in (x for x in text.splitlines() if x.startswith("## ")):
        assert "simulated participants" in heading, heading
    assert "not what a person would" in text and "a calibration, not a finding" in text
    assert (out / "figure4_success.png").is_file()
    people = _study(tmp_path / "people", [{**r, "simulated": False, "participant": "P01"} for r in rows])
    text = "\n".join(analyse(people, people, time_limit=30.0))
    assert "simulated" not in text and "Herlant et al. 2016 measured 17.4 %" in text


def test_the_paths_are_regenerated_from_the_rows_and_their_seeds(tmp_path):
    """The .npz files are not kept in git: `vla_study --paths` reruns each trial whose path is missing,
    with its row's layout and operator seeds, writes only the path, and says whether the outcome was the
    row's; a row the protocol does not hold is named, not rerun."""
    from vla_study.paths import regenerate_paths
    from vla_study.protocol import load_protocol
    from vla_study.runner import operator_seed, trial_plan

    f = tmp_path / "p.yaml"
    f.write_text("participants: sim:2\nstrategies: [latent-YOLO]\nsettings: {base: bread/push_east}\n"
                 "trials: 1\npractice: {trials: 0, reset_seed: 7}\n")
    p = load_protocol(f)
    plan = trial_plan(p)
    rows = [{"key": t.key, "file": t.file_stem, "participant": t.participant, "layout_seed": t.layout_seed,
             "success": True, "time_s": 4.0, "simulated": True} for t in plan]
    rows[1]["operator_seed"] = 1234
    rows.append({**rows[0], "key": "sim:9|latent-YOLO|base|x|test|0", "file": "stranger"})
    out = _study(tmp_path, rows)
    (out / "trials").mkdir()
    (out / "trials" / f"{plan[0].file_stem}.npz").write_bytes(b"kept")   # present: not rerun
    ran = []

    class Backend:
        def run(self, trial, params, operator_seed):
            ran.append((trial.key, trial.layout_seed, operator_seed, params is not None))
            return {"success": False, "time_s": 30.0}, {"tcp": np.zeros((3, 3)), "t": np.zeros(3),
                                                       "stick": np.zeros(3)}

    logs = []
    assert regenerate_paths(p, out, backend=Backend(), log=logs.append) == 1
    assert ran == [(plan[1].key, plan[1].layout_seed, 1234, True)]
    assert (out / "trials" / f"{plan[0].file_stem}.npz").read_bytes() == b"kept"
    with np.load(out / "trials" / f"{plan[1].file_stem}.npz") as d:
        assert d["tcp"].shape == (3, 3)
    note = json.loads((out / "paths.jsonl").read_text())
    assert note["key"] == plan[1].key and note["same_outcome"] is False
    assert (out / "trials.jsonl").read_text().count("\n") == 3   # the rows as they were
    assert any("stranger" not in x and "sim:9" in x and "give the protocol" in x for x in logs)
    assert operator_seed(p, plan[0]) != 1234

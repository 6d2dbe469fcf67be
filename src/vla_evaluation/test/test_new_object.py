"""`vla_evaluation new-object`: the order of the steps, what each step hands the next, resuming, the
demonstration-count sweep and the report, with every project command replaced by a fake that writes
what the real one writes (the real commands run in test/test_new_object_walkthrough.py)."""

import json
import sys
from pathlib import Path

import pytest
from vla_common.tasks import BASE_TASKS

from vla_evaluation import new_object as no

CATALOGUE = Path(__file__).resolve().parents[3] / "test" / "data" / "spam_catalogue.yaml"
TASK = "spam/push_south_east"
CLASSES = ["bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box", "spam"]


def _opt(cmd, flag):
    return cmd[cmd.index(flag) + 1]


class FakeProject:
    """Stands in for the project's commands: writes their outputs, records each call."""

    def __init__(self, tmp: Path, success: dict[int, float], failed_first_generate: int = 0):
        self.tmp, self.success, self.failed = tmp, success, failed_first_generate
        self.calls: list[list[str]] = []

    def run_command(self, cmd, log=print, accept=(0,)):
        cmd = [str(c) for c in cmd]
        self.calls.append(cmd)
        prog, sub = cmd[0], cmd[1]
        out = Path(_opt(cmd, "--out")) if "--out" in cmd else None
        if (prog, sub) == ("vla_detector_training", "synth"):
            out.mkdir(parents=True)
            (out / "data.yaml").write_text(f"names: {CLASSES}\n")
        elif (prog, sub) == ("vla_detector_training", "train"):
            out.mkdir(parents=True)
            (out / "detector.onnx").write_bytes(b"onnx")
        elif (prog, sub) == ("vla_detector_training", "evaluate"):
            ap = {c: 0.93 if c == "spam" else 0.99 for c in CLASSES}
            Path(_opt(cmd, "--json")).write_text(json.dumps(
                {"model": _opt(cmd, "--model"), "data": _opt(cmd, "--data"), "split": "test", "images": 100,
                 "map50": 0.98, "map50_95": 0.7, "centre_error_px": 0.9, "precision": 0.95, "recall": 0.96,
                 "per_class_ap50": ap}))
        elif (prog, sub) == ("vla_evaluation", "generate"):
            n = int(_opt(cmd, "--episodes"))
            ok = n - self.failed
            self.failed = 0
            start = len(list(out.glob("ep*"))) if out.is_dir() else 0
            for i in range(ok):
                bag = out / f"ep{start + i + 1:04d}_spam_push_south_east"
                bag.mkdir(parents=True)
                (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
            return 3 if ok < n else 0
        elif (prog, sub) == ("vla_latent_training", "train"):
            out.mkdir(parents=True)
            (out / "config.json").write_text(json.dumps({"classes": CLASSES}))
        elif (prog, sub) == ("vla_evaluation", "evaluate"):
            k = int(Path(_opt(cmd, "--model")).name[1:])
            out.mkdir(parents=True)
            row = {"task": _opt(cmd, "--tasks"), "episodes": int(_opt(cmd, "--layouts")),
                   "success_rate": self.success[k], "final_state_error": 0.3, "final_state_error_sem": 0.02,
                   "time_to_success_median": 11.0, "safety_interventions": 0, "limit_violations": 0}
            episodes = [{"task": row["task"], "detected_class": "spam" if i else "bread",
                         "x_interventions_by_code": {"4": 2, "3": 1}} for i in range(row["episodes"])]
            results = {"meta": {}, "summary": [row], "episodes": episodes}
            (out / "results.json").write_text(json.dumps(results))
        else:
            raise AssertionError(f"unexpected command {cmd}")
        return 0

    def ensure_demos(self, task, episodes, data_dir, seed, log=print):
        self.calls.append(["ensure_demos", task, str(episodes)])
        folder = Path(data_dir) / "demos" / task.replace("/", "_")
        folder.mkdir(parents=True, exist_ok=True)
        return folder

    def programs(self):
        return [tuple(c[:2]) for c in self.calls]


@pytest.fixture
def fake(tmp_path, monkeypatch):
    def make(success, failed_first_generate=0):
        f = FakeProject(tmp_path, success, failed_first_generate)
        monkeypatch.setattr(no, "run_command", f.run_command)
        monkeypatch.setattr(no, "ensure_demos", f.ensure_demos)
        return f
    return make


def _cfg(tmp_path, **kw):
    return no.NewObjectConfig(catalogue=CATALOGUE, task="spam:push_south_east", out=tmp_path / "run",
                              data=tmp_path / "data", **kw)


def test_each_step_takes_what_the_previous_one_wrote(tmp_path, fake):
    f = fake({3: 0.9})
    res = no.run_pipeline(_cfg(tmp_path), log=lambda m: None)
    run = tmp_path / "run"
    synth = [c for c in f.calls if c[:2] == ["vla_detector_training", "synth"]]
    assert [_opt(c, "--out") for c in synth] == [str(run / "renders"), str(run / "renders_test")]
    assert all(_opt(c, "--catalogue") == str(CATALOGUE) and _opt(c, "--include") == "spam" for c in synth)
    assert _opt(synth[1], "--split") == "test" and _opt(synth[0], "--seed") != _opt(synth[1], "--seed")
    train = [c for c in f.calls if c[:2] == ["vla_detector_training", "train"]]
    assert [Path(_opt(c, "--out")).relative_to(run).as_posix() for c in train] == [
        "detector", "detector_mix", "detector_scratch", "detector_scratch_4x",  # fine-tuned, mixed, scratch
        "timing/fine_tuned_1", "timing/scratch_1", "timing/fine_tuned_2", "timing/scratch_2"]
    assert [_opt(c, "--init") if "--init" in c else None for c in train[:3]] == ["shipped", "shipped", None]
    assert _opt(train[1], "--mix-synth") == "100" and _opt(train[1], "--catalogue") == str(CATALOGUE)
    def without_out(c):
        return [w for w in c if w != _opt(c, "--out")]
    assert without_out(train[4]) == without_out(train[0]) and without_out(train[5]) == without_out(train[2])
    assert all(_opt(c, "--data") == str(run / "renders") for c in train)
    assert set(res.detector) == {"fine_tuned", "fine_tuned_mix", "scratch", "scratch_4x_epochs"}
    assert [_opt(c, "--epochs") for c in train[:4]] == ["10", "10", "10", "40"]
    evaluate = [c for c in f.calls if c[:2] == ["vla_detector_training", "evaluate"]]
    assert [Path(_opt(c, "--json")).parent.relative_to(run).as_posix() for c in evaluate] == [
        "detector", "detector_mix", "detector_scratch", "detector_scratch_4x"]  # its figures, as JSON
    assert all(_opt(c, "--data") == str(run / "renders_test") for c in evaluate)
    assert [len(t.runs_s) for t in res.detector_timing.values()] == [3, 3]
    assert all(len(t.cpu_runs_s) == 3 and t.median_cpu_s is not None for t in res.detector_timing.values())
    fine = str(run / "detector" / "detector.onnx")
    gen = next(c for c in f.calls if c[:2] == ["vla_evaluation", "generate"])
    assert _opt(gen, "--task") == TASK and _opt(gen, "--detector-model") == fine
    assert _opt(gen, "--episodes") == "5"  # the sweep's top, generated once
    assert [c[1] for c in f.calls if c[0] == "ensure_demos"] == list(BASE_TASKS)
    lt = next(c for c in f.calls if c[:2] == ["vla_latent_training", "train"])
    bags = lt[lt.index("--bags") + 1: lt.index("--max-per-task")]
    new = [b for b in bags if "spam_push_south_east" in b]
    assert len(bags) == len(BASE_TASKS) + 3 and [Path(b).name for b in new] == [
        f"ep000{i}_spam_push_south_east" for i in (1, 2, 3)]
    assert _opt(lt, "--detector-model") == fine and _opt(lt, "--catalogue") == str(CATALOGUE)
    ev = next(c for c in f.calls if c[:2] == ["vla_evaluation", "evaluate"])
    assert _opt(ev, "--mode") == "graph" and _opt(ev, "--tasks") == TASK and _opt(ev, "--layouts") == "10"
    assert _opt(ev, "--model") == str(run / "models" / "k3") and _opt(ev, "--detector-model") == fine
    assert int(_opt(ev, "--seed")) >= 100_000  # fresh layouts, never a demonstration's
    assert list(res.transfer) == ["3"] and res.smallest_sufficient_demos == 3
    ft = res.detector["fine_tuned"]
    assert isinstance(ft, no.DetectorFigures) and ft.precision == 0.95
    assert ft.new_class_ap50 == pytest.approx(0.93) and ft.old_classes_map50 == pytest.approx(0.99)
    assert set(ft.ap50) == set(CLASSES) and ft.images == 100
    assert res.verdicts["new_class_ap50>=0.9"] and res.verdicts["success_with_3_demos>=80%"]
    saved = json.loads((run / "results.json").read_text())
    assert saved["transfer"]["3"]["success_rate"] == 0.9
    assert saved["detector"]["fine_tuned"]["ap50"]["spam"] == pytest.approx(0.93)
    readme = (run / "README.md").read_text()
    assert "| 3 | 10 | 90 % |" in readme and "spam 0.930" in readme and "| fine_tuned | " in readme
    row = res.transfer["3"]
    assert row.detected_task_object == 9 and "| 9/10 |" in readme and row.model == str(run / "models" / "k3")
    assert row.interventions_by_code == {"ACCELERATION_LIMITED": 20, "VELOCITY_SCALED": 10}


def test_a_rerun_resumes_without_redoing_finished_steps(tmp_path, fake):
    fake({3: 0.9})
    first = no.run_pipeline(_cfg(tmp_path), log=lambda m: None)
    saved = tmp_path / "run" / "results.json"
    earlier = {name: 100.0 + i for i, name in enumerate(first.steps_s)}  # as if they had taken long
    saved.write_text(json.dumps(dict(json.loads(saved.read_text()), steps_s=earlier)))
    f = fake({3: 0.9})
    res = no.run_pipeline(_cfg(tmp_path), log=lambda m: None)
    heavy = {("vla_detector_training", "synth"), ("vla_detector_training", "train"),
             ("vla_evaluation", "generate"), ("vla_latent_training", "train"), ("vla_evaluation", "evaluate")}
    assert not heavy & set(f.programs()) and ("vla_detector_training", "evaluate") not in f.programs()
    assert res.transfer["3"].success_rate == 0.9
    # each reused step keeps the time of the run that did it
    assert res.steps_s == earlier and set(res.steps_reused) == set(earlier)
    assert "(an earlier run)" in (tmp_path / "run" / "README.md").read_text()


def test_three_demonstrations_short_of_the_goal_measure_one_to_five(tmp_path, fake):
    fake({1: 0.1, 2: 0.5, 3: 0.6, 4: 0.8, 5: 1.0})
    res = no.run_pipeline(_cfg(tmp_path), log=lambda m: None)
    assert sorted(res.transfer, key=int) == ["1", "2", "3", "4", "5"]
    assert res.smallest_sufficient_demos == 4
    assert res.verdicts["success_with_3_demos>=80%"] is False
    assert [(tmp_path / "run" / "models" / f"k{k}").is_dir() for k in range(1, 6)] == [True] * 5


def test_sweep_never_and_always(tmp_path, fake):
    fake({1: 0.1, 2: 0.5, 3: 0.6, 4: 0.8, 5: 1.0})
    res = no.run_pipeline(_cfg(tmp_path, sweep="never"), log=lambda m: None)
    assert list(res.transfer) == ["3"] and res.smallest_sufficient_demos is None
    cfg = _cfg(tmp_path, sweep="always", demos=2, max_demos=3)
    cfg.out = tmp_path / "run2"
    res = no.run_pipeline(cfg, log=lambda m: None)
    assert sorted(res.transfer, key=int) == ["1", "2", "3"] and res.smallest_sufficient_demos is None


def test_failed_generated_episodes_are_topped_up_with_new_seeds(tmp_path, fake):
    f = fake({3: 0.9}, failed_first_generate=2)
    res = no.run_pipeline(_cfg(tmp_path, scratch=False), log=lambda m: None)
    gens = [c for c in f.calls if c[:2] == ["vla_evaluation", "generate"]]
    assert [_opt(c, "--episodes") for c in gens] == ["5", "2"]
    assert _opt(gens[0], "--seed") != _opt(gens[1], "--seed")
    assert len(res.new_demos) == 5 and "scratch" not in res.detector
    assert res.detector_time_ratio is None and list(res.detector_timing) == ["fine_tuned"]
    assert not any("detector_scratch" in " ".join(c) for c in f.calls)


def test_unknown_task_is_refused_with_the_known_ones(tmp_path, fake, capsys):
    f = fake({})
    args = no_args(tmp_path, task="spam/circle")
    assert no.run(args) == 2
    err = capsys.readouterr().err
    assert "spam has no task 'circle'" in err and "push_south_east" in err
    assert f.calls == []


def no_args(tmp_path, **kw):
    import argparse

    p = argparse.ArgumentParser()
    no.add_arguments(p)
    argv = ["--catalogue", str(CATALOGUE), "--task", kw.get("task", TASK), "--out", str(tmp_path / "run"),
            "--data", str(tmp_path / "data")]
    return p.parse_args(argv)


def test_publish_copies_the_figures(tmp_path, fake):
    fake({3: 0.9})
    no.run_pipeline(_cfg(tmp_path), log=lambda m: None)
    (tmp_path / "run" / "eval" / "k3" / "summary.csv").write_text("task,success_rate\n")
    (tmp_path / "run" / "eval" / "k3" / "paths_spam_push_south_east.png").write_bytes(b"png")
    copied = no.publish(tmp_path / "run", tmp_path / "docs")
    assert sorted(p.name for p in copied) == ["README.md", "eval_k3_paths_spam_push_south_east.png",
                                              "eval_k3_summary.csv", "results.json"]
    assert (tmp_path / "docs" / "README.md").read_text() == (tmp_path / "run" / "README.md").read_text()


def test_read_evaluation_takes_the_json_figures_and_refuses_none(tmp_path):
    path = tmp_path / "held_out.json"
    path.write_text(json.dumps({"split": "test", "images": 100, "map50": 0.9712, "map50_95": 0.701,
                                "centre_error_px": None, "precision": 0.9, "recall": 0.9,
                                "per_class_ap50": {"bread": 0.99, "spam": 0.92}}))
    fig = no.read_evaluation(path)
    assert fig["map50"] == 0.9712 and fig["map50_95"] == 0.701 and fig["centre_error_px"] is None
    assert fig["ap50"] == {"bread": 0.99, "spam": 0.92}
    assert fig["images"] == 100 and fig["split"] == "test"
    path.write_text('{"map50": 0.5}')
    with pytest.raises(RuntimeError, match="wrote no figures"):
        no.read_evaluation(path)
    with pytest.raises(RuntimeError, match="wrote no figures"):
        no.read_evaluation(tmp_path / "missing.json")


def test_smallest_sufficient_and_the_counts_to_measure():
    assert no.smallest_sufficient({3: 0.7, 4: 0.8, 5: 0.9}, 0.8) == 4
    assert no.smallest_sufficient({3: 0.7, 2: None}, 0.8) is None
    cfg = no.NewObjectConfig(catalogue=CATALOGUE, task=TASK, out=Path("x"))
    assert no.demo_counts(cfg, {}) == [3]
    assert no.demo_counts(cfg, {3: 0.8}) == []
    assert no.demo_counts(cfg, {3: 0.7}) == [1, 2, 4, 5]
    assert no.demo_counts(cfg, {3: None}) == []  # not judged: nothing to sweep on


def test_the_time_goal_is_judged_on_the_median_of_the_runs(tmp_path):
    fine = no.DetectorFigures(model="m", train_wall_s=400.0, train_cpu_s=None, split="test", images=1,
                              map50=0.9, map50_95=0.5, centre_error_px=None, precision=1.0, recall=1.0,
                              ap50={}, new_class_ap50=0.95, old_classes_map50=0.94)
    transfer = no.TransferFigures(task=TASK, episodes=10, success_rate=0.7, final_state_error=None,
                                  final_state_error_sem=None, time_to_success_median=None,
                                  safety_interventions=None, limit_violations=None, detected_task_object=0,
                                  interventions_by_code={})
    res = no.NewObjectResults(command="", date="", machine=no.machine(), config={}, catalogue="",
                              shipped_detector="", detector={"fine_tuned": fine},
                              detector_timing={"fine_tuned": no.TimingRuns([400.0, 120.0, 130.0], 130.0, [],
                                                                           None)},
                              transfer={"3": transfer})
    v = no.verdicts(res, no.NewObjectConfig(catalogue=CATALOGUE, task=TASK, out=tmp_path))
    assert v == {"new_class_ap50>=0.9": True, "old_classes_map50>=0.95": False,
                 "fine_tune_median<=300s": True, "success_with_3_demos>=80%": False}


def test_timed_measures_the_commands_cpu_time():
    cmds = no.Commands(log=lambda m: None)
    t = cmds.timed([sys.executable, "-c", "sum(i * i for i in range(2_000_000))"])
    assert t.cpu_s > 0 and t.wall_s > 0 and cmds.count == 1

"""`vla_evaluation demo`: CLI wiring, model choice per task, video/strip and the results table."""
import numpy as np
import pytest
from vla_evaluation.cli import build_parser
from vla_evaluation.evaluate_cli import task_list
from vla_evaluation.graph import EpisodeRecord
from vla_evaluation.metrics import EpisodeResult

from vla_evaluation import demo


def test_cli_has_the_subcommands_with_defaults():
    p = build_parser()
    a = p.parse_args(["demo"])
    assert str(a.out) == "out/demo" and a.tasks == demo.DEMO_TASKS and a.layouts == 1 and a.rate == 100.0
    assert "glass_bottle/pick_place_west" in task_list(a.tasks)   # the main job has a pick-and-place
    assert a.horizon == demo.DEMO_HORIZON == 2.0  # the demo's look-ahead; the evaluation keeps 1 s
    e = p.parse_args(["evaluate", "--mode", "graph", "--layouts", "20"])
    assert e.mode == "graph" and e.layouts == 20 and e.horizon == 1.0
    x = p.parse_args(["experiments", "--quick"])
    assert x.quick and x.out is None  # --quick writes to out/experiments_quick, never over docs/results
    assert x.position_scale == pytest.approx(0.2887, abs=1e-4)  # the experiments' fixed position scale
    assert p.parse_args(["experiments", "--position-scale", "demos"]).position_scale is None
    with pytest.raises(SystemExit):
        p.parse_args(["evaluate", "--mode", "telepathy"])


def test_each_task_gets_its_model():
    assert demo.model_name_for("bread/push_east") == "default"
    assert demo.model_name_for("glass_bottle/push_west") == "default"
    assert demo.model_name_for("cereal_box/push_south_east") == "cereal_box_push_south_east"
    assert demo.model_name_for("cereal_box/circle") == "cereal_box_circle"


def _record(task, success, frames=4):
    r = EpisodeResult(task=task, layout_seed=1, mode="graph", model="detector", final_state_error=0.12,
                      success=success, time_to_success=12.5 if success else None, duration_s=3.0,
                      safety_interventions=0, limit_violations=0, detected_class="bread")
    t = np.linspace(0, 3.0, 30)
    tcp = np.column_stack([0.45 + 0.05 * t / 3, -0.1 * t / 3, np.full_like(t, 0.05)])
    r.ee_path = tcp
    imgs = [(float(i), np.full((240, 320, 3), 40 * (i + 1), np.uint8)) for i in range(frames)]
    return EpisodeRecord(r, tcp, t, imgs)


def test_video_and_strip_are_written_with_the_path_drawn(tmp_path):
    import cv2
    from vla_evaluation.demo_video import write_video_and_strip

    recs = [_record("bread/push_east", True), _record("soda_can/push_south", False)]
    files = write_video_and_strip(recs, tmp_path, size=(640, 480))
    assert files["video"].stat().st_size > 1000
    cap = cv2.VideoCapture(str(files["video"]))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert n == 8
    strip = cv2.imread(str(files["strip"]))
    assert strip.shape == (240, 640, 3)
    # the path colour appears in the last frame of each tile, the flat background alone would not have it
    tile = cv2.cvtColor(strip[:, :320], cv2.COLOR_BGR2RGB).reshape(-1, 3)
    assert np.any(np.all(np.abs(tile.astype(int) - (255, 200, 0)) < 40, axis=1))


def test_table_lists_every_task_with_success_and_error():
    recs = [_record("bread/push_east", True), _record("bread/push_east", False),
            _record("soda_can/push_south", True)]
    lines = demo.summary_lines([r.result for r in recs])
    assert "final state error" in lines[0]
    bread = next(line for line in lines if line.startswith("bread/push_east"))
    assert "50 %" in bread and "0.120" in bread
    assert any(line.startswith("soda_can/push_south") and "100 %" in line for line in lines)


@pytest.mark.parametrize("outcomes, rc", [((True, True), 0), ((True, False), 3)])
def test_the_demo_fails_when_an_episode_fails(tmp_path, monkeypatch, capsys, outcomes, rc):
    """`make demo` is the main job: CI and a user's shell see a failed task in the exit code."""
    tasks = ["bread/push_east", "cereal_box/push_south"]
    for name in ("default", "cereal_box_push_south"):
        (tmp_path / "models" / name).mkdir(parents=True)
        (tmp_path / "models" / name / "config.json").write_text('{"encoder": "detector"}')
    results = dict(zip(tasks, outcomes))

    class FakeGraph:
        def __init__(self, cfg, log):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def set_model(self, path):
            pass

        def run_episode(self, task, seed, label):
            return _record(task, results[task])

    monkeypatch.setattr(demo, "GraphEvaluator", FakeGraph)
    monkeypatch.setattr(demo, "ensure_detector", lambda path, data, log: tmp_path / "det.onnx")
    args = build_parser().parse_args(["demo", "--tasks", ",".join(tasks), "--no-video", "--out",
                                      str(tmp_path / "out"), "--models", str(tmp_path / "models"),
                                      "--assisted", ""])
    assert demo.run(args) == rc
    err = capsys.readouterr().err
    assert ("1 of 2 episodes failed: cereal_box/push_south" in err) == (rc != 0)
    assert (tmp_path / "out" / "results.json").is_file()            # the results are written either way


def test_the_pick_and_place_model_trains_on_its_own_demos_alone(monkeypatch, tmp_path):
    """The demo's pick-and-place model: that task's few-shot demonstrations, no base ones (the soda
    can's push south would share its context)."""
    import sys
    import types

    from vla_evaluation import training_data as td

    calls = []
    monkeypatch.setattr(td, "Detector", lambda path: "detector")
    monkeypatch.setattr(td, "ensure_demos",
                        lambda task, n, data, seed, log=print: calls.append((task, n, seed)) or tmp_path)
    monkeypatch.setattr(td, "load_task_demos", lambda folder, task, det, limit=None: [task] * limit)

    class Result:
        def save(self, path):
            return path

    trained = {}

    def train_model(demos, cfg, **kw):
        trained["demos"], trained["cfg"] = demos, cfg
        return Result()

    fake = types.ModuleType("vla_latent_training.train")
    fake.TrainConfig = lambda **kw: kw
    fake.train_model = train_model
    monkeypatch.setitem(sys.modules, "vla_latent_training.train", fake)
    made = td.ensure_latent_models(["soda_can_pick_place_west"], tmp_path, tmp_path / "d.onnx", tmp_path,
                                   log=lambda s: None)
    assert made == {"soda_can_pick_place_west": tmp_path / "soda_can_pick_place_west"}
    assert calls == [("soda_can/pick_place_west", td.FEW_SHOT_EPISODES, td.UNSEEN_SEED)]
    assert trained["demos"] == ["soda_can/pick_place_west"] * td.FEW_SHOT_EPISODES
    assert trained["cfg"]["encoder"] == "detector"
    assert demo.model_name_for("soda_can/pick_place_west") == "soda_can_pick_place_west"


@pytest.mark.parametrize("task, spread", [("soda_can/pick_place_west", True), ("bread/push_east", False)])
def test_few_shot_hand_demonstrations_are_generated_at_spread_layouts(monkeypatch, tmp_path, task, spread):
    """A task with the hand's five demonstrations span its region (`generate --spread`); pushes keep
    random layouts."""
    from vla_evaluation import training_data as td

    cmds = []

    def run_command(cmd, log=print, accept=(0,)):
        cmds.append(cmd)
        folder = td.task_dir(tmp_path, task)
        for i in range(5):
            (folder / f"ep{i}").mkdir(parents=True, exist_ok=True)
            (folder / f"ep{i}" / "metadata.yaml").write_text("")
        return 0

    monkeypatch.setattr(td, "run_command", run_command)
    td.ensure_demos(task, 5, tmp_path, td.UNSEEN_SEED, log=lambda s: None)
    assert len(cmds) == 1 and ("--spread" in cmds[0]) == spread
    args = build_parser().parse_args(["generate", "--task", task, "--spread"])
    assert args.spread


def test_generate_spread_margin_is_an_option_of_spread(capsys):
    """`generate --spread --spread-margin M` reaches the generation's config; without --spread, or
    negative, it is refused (exit 2) before any graph starts."""
    from vla_common.tasks import SPREAD_MARGIN

    from vla_evaluation import generate

    parser = build_parser()
    args = parser.parse_args(["generate", "--task", "glass_bottle/pick_place_west", "--spread"])
    assert args.spread_margin == SPREAD_MARGIN
    args = parser.parse_args(["generate", "--task", "glass_bottle/pick_place_west", "--spread",
                              "--spread-margin", "0.06"])
    assert args.spread_margin == 0.06
    for extra in (["--spread-margin", "0.06"], ["--spread", "--spread-margin", "-0.01"]):
        args = parser.parse_args(["generate", "--task", "glass_bottle/pick_place_west", *extra])
        assert generate.run(args) == 2
        assert "--spread-margin" in capsys.readouterr().out


def test_evaluate_path_fraction_reaches_the_settings():
    """`evaluate --path-fraction F` is the controller's path_fraction in the settings (the graph's
    parameter and the teleoperator's mirror); its default is the controller's (0: the model's own);
    outside [0, 1] argparse refuses it."""
    from vla_evaluation.evaluate_cli import settings_from
    from vla_evaluation.kinematic import TeleopSettings

    parser = build_parser()
    assert settings_from(parser.parse_args(["evaluate"])).path_fraction == TeleopSettings().path_fraction
    assert settings_from(parser.parse_args(["evaluate", "--path-fraction", "0.8"])).path_fraction == 0.8
    for bad in ("1.5", "-0.1"):
        with pytest.raises(SystemExit):
            parser.parse_args(["evaluate", "--path-fraction", bad])


def test_evaluate_latent_only_reaches_the_teleoperators_parameters():
    """`evaluate --latent-only` turns the simulated user's fine alignment off (the A/B of issue 23);
    by default it is on, in the settings and in the parameters the graph sets on the teleoperator."""
    from vla_evaluation.evaluate_cli import settings_from
    from vla_evaluation.graph import TELEOP, GraphConfig

    parser = build_parser()
    for argv, want in ((["evaluate"], True), (["evaluate", "--latent-only"], False)):
        s = settings_from(parser.parse_args(argv))
        assert s.fine_align is want
        params = GraphConfig("model", "detector.onnx", settings=s).node_parameters()
        assert params[TELEOP]["fine_align"] is want


@pytest.mark.parametrize("assisted_ok, rc", [(True, 0), (False, 3)])
def test_the_assisted_row_holds_the_stick_with_the_assistance_on(tmp_path, monkeypatch, capsys, assisted_ok,
                                                                 rc):
    """Issue 34: the demo's last row is a held full stick with the controller's assistance at high,
    after the other tasks (which run without it), shown as its own row; its failure fails the demo."""
    from vla_evaluation.graph import CONTROLLER

    for name in ("default", "cereal_box_circle"):
        (tmp_path / "models" / name).mkdir(parents=True)
        (tmp_path / "models" / name / "config.json").write_text('{"encoder": "detector"}')
    runs = []

    class FakeGraph:
        def __init__(self, cfg, log):
            self.config = cfg
            self.configured = []

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def set_model(self, path):
            self.config.model_path = path

        def configure(self):
            self.configured.append(self.config.node_parameters())

        def run_episode(self, task, seed, label):
            params = self.configured[-1] if self.configured else {}
            runs.append((task, self.config.settings.hold, params.get(CONTROLLER, {}).get("assistance", "off"),
                         self.config.model_path.split("/")[-1]))
            return _record(task, assisted_ok if self.configured else True)

    monkeypatch.setattr(demo, "GraphEvaluator", FakeGraph)
    monkeypatch.setattr(demo, "ensure_detector", lambda path, data, log: tmp_path / "det.onnx")
    args = build_parser().parse_args(["demo", "--tasks", "bread/push_east", "--no-video", "--out",
                                      str(tmp_path / "out"), "--models", str(tmp_path / "models")])
    assert args.assisted == demo.ASSISTED_TASK == "cereal_box/circle"
    assert demo.run(args) == rc
    assert runs == [("bread/push_east", 0.0, "off", "default"),
                    ("cereal_box/circle", 1.0, demo.ASSISTED_LEVEL, "cereal_box_circle")]
    out = capsys.readouterr()
    assert any(line.startswith("cereal_box/circle assisted") for line in out.out.splitlines())
    assert ("1 of 2 episodes failed: cereal_box/circle" in out.err) == (rc != 0)

"""Evaluation: metrics, reports and plots (fakes), and the kinematic loop on a small trained model."""
import json

import numpy as np
import pytest
from vla_latent_controller.evaluation import metrics, plots
from vla_latent_controller.evaluation.metrics import EpisodeResult, LimitMonitor, SafetyTally
from vla_panda_bridge.panda import DQ_MAX, Q_MAX, READY_POSE


def test_final_state_error_is_joint_l2():
    q = np.zeros(7)
    w = np.array([3.0, 4.0, 0, 0, 0, 0, 0])
    assert metrics.final_state_error(q, w) == pytest.approx(5.0)
    with pytest.raises(ValueError):
        metrics.final_state_error(np.zeros(6), w)


def test_limit_monitor_counts_position_and_speed_violations():
    m = LimitMonitor()
    m.update(READY_POSE, np.zeros(7))
    assert m.violations == 0
    over = READY_POSE.copy()
    over[3] = Q_MAX[3] + 0.01
    m.update(over, np.zeros(7))
    fast = np.zeros(7)
    fast[0] = DQ_MAX[0] * 1.2
    m.update(READY_POSE, fast)
    m.update(np.zeros(3))  # malformed: ignored, never raises
    assert (m.position_violations, m.velocity_violations, m.samples) == (1, 1, 3)
    assert m.max_speed_ratio == pytest.approx(1.2)


def test_safety_tally_counts_increase_of_the_running_counter():
    s = SafetyTally()
    assert s.interventions == 0
    s.update(0, 7)
    s.update(3, 9)  # VELOCITY_SCALED, counter moved by 2 (one status lost in transit)
    s.update(0, 9, estop_active=True)
    assert s.interventions == 2 and s.by_code == {3: 1} and s.estop_seen


def test_summarize_groups_and_reports(tmp_path):
    rs = [
        EpisodeResult("bread/push_east", 1, encoder="detector", final_state_error=0.1, success=True,
                      time_to_success=10.0, safety_interventions=0, limit_violations=0,
                      extra={"n_demos": 2}),
        EpisodeResult("bread/push_east", 2, encoder="detector", final_state_error=0.3, success=False,
                      safety_interventions=1, limit_violations=0, extra={"n_demos": 2},
                      ee_path=np.zeros((3, 3))),
        EpisodeResult("bread/push_east", 3, encoder="end_to_end", final_state_error=float("nan"),
                      extra={"n_demos": 2}),
    ]
    rows = metrics.summarize(rs, keys=("encoder", "n_demos"))
    det = next(r for r in rows if r["encoder"] == "detector")
    assert det["episodes"] == 2 and det["success_rate"] == 0.5
    assert det["final_state_error"] == pytest.approx(0.2)
    assert det["final_state_error_sem"] == pytest.approx(0.1)
    assert det["time_to_success_median"] == 10.0 and det["safety_interventions"] == 1
    e2e = next(r for r in rows if r["encoder"] == "end_to_end")
    assert e2e["success_rate"] is None and np.isnan(e2e["final_state_error"])

    csv_path = metrics.write_csv([r.row() for r in rs], tmp_path / "r.csv")
    back = metrics.read_csv(csv_path)
    assert len(back) == 3 and back[0]["x_n_demos"] == "2" and back[2]["final_state_error"] == ""
    js = metrics.write_json({"episodes": [r.to_json(include_path=True) for r in rs]}, tmp_path / "r.json")
    data = json.loads(js.read_text())  # strict JSON: NaN became null
    assert data["episodes"][2]["final_state_error"] is None
    assert data["episodes"][1]["ee_path"] == [[0.0, 0.0, 0.0]] * 3


def test_plots_write_pngs(tmp_path):
    rows = [{"encoder": e, "n_demos": n, "final_state_error": v}
            for e, base in (("detector", 0.2), ("end_to_end", 0.8))
            for n in (1, 2, 3) for v in (base / n, base / n + 0.05)]
    stats = plots.sweep_stats(rows, "n_demos", "final_state_error", "encoder")
    xs, means, sems = stats["detector"]
    assert xs.tolist() == [1, 2, 3] and means[0] == pytest.approx(0.225) and sems[0] > 0
    p = plots.save_sweep_plot(rows, "n_demos", "final_state_error", "encoder", tmp_path / "a.png")
    p2 = plots.save_panel_plot([("Seen", rows), ("Near", rows)], "n_demos", "final_state_error",
                               "encoder", tmp_path / "c.png")
    path = np.column_stack([np.linspace(0.4, 0.6, 20), np.linspace(0, -0.2, 20), np.full(20, 0.1)])
    p3 = plots.save_ee_paths({"detector": [path]}, tmp_path / "paths.png",
                             objects=[{"class_id": "bread", "x": 0.5, "y": -0.1,
                                       "x_end": 0.5, "y_end": -0.25}])
    for f in (p, p2, p3):
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f.stat().st_size > 2000


# ---------------------------------------------------------------- kinematic loop on a trained model
CLASSES = ("bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box")


class _Demo:
    def __init__(self, cls, q, det):
        self.task, self.object_class, self.q = f"{cls}/push", cls, q
        self.t = np.arange(len(q)) * 0.1
        self.first_image, self.detection, self.image_size, self.bag_path = None, det, (640, 480), ""


def _direction(cls):
    v = np.random.default_rng(CLASSES.index(cls) + 7).normal(size=7)
    return 0.5 * v / np.linalg.norm(v)


def _demo(cls, rng, T=50):
    x, y = rng.uniform(0.3, 0.7, 2)
    q0 = READY_POSE + rng.normal(0, 0.02, 7)
    s = np.linspace(0, 1, T)
    q = q0 + np.outer(3 * s**2 - 2 * s**3, _direction(cls) + 0.2 * (x - 0.5))
    det = {"class_id": cls, "class_index": CLASSES.index(cls), "score": 0.9, "cx": x * 640, "cy": y * 480}
    return _Demo(cls, q, det)


def _pairs(demo, rng, windows=10, sigma=0.01):
    q = np.asarray(demo.q)
    eps = rng.normal(0, sigma, size=7)  # one draw per demo (contract 7)
    qs = [q[:-w] + eps for w in range(1, windows + 1)]
    return np.concatenate(qs), np.concatenate([q[w:] - qn for w, qn in zip(range(1, windows + 1), qs)])


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    from vla_latent_controller.model import LatentModel
    from vla_latent_controller.train import TrainConfig, train_model

    rng = np.random.default_rng(0)
    demos = [_demo(c, rng) for c in CLASSES[:4] for _ in range(4)]
    res = train_model(demos, TrainConfig(encoder="detector", epochs=150, step_size=100), classes=CLASSES,
                      pairs_fn=_pairs, progress=False, threads=1, log=lambda s: None)
    out = res.save(tmp_path_factory.mktemp("model"))
    return LatentModel.load(out), demos


@pytest.mark.slow
def test_kinematic_teleoperator_drives_trained_model_to_the_demo_goal(trained):
    from vla_latent_controller.context import Det
    from vla_latent_controller.evaluation.kinematic import Layout, TeleopSettings, run_episode
    from vla_panda_bridge.objects import ObjectPose

    model, demos = trained
    settings = TeleopSettings(rate=20.0, switch_time=6.0, time_limit=12.0)
    errors = []
    for demo in demos[::4]:
        det = Det.from_dict(demo.detection)
        lay = Layout(demo.task, 0, [], ObjectPose(demo.object_class, 0.5, 0.0, 0.0), demo.q[0].copy(),
                     [demo.q[len(demo.q) // 2], demo.q[-1]], image=None, image_size=(640, 480),
                     detections=[det])
        r = run_episode(model, lay, settings)
        start_err = np.linalg.norm(demo.q[-1] - demo.q[0])
        assert r.note == "" and r.detected_class == demo.object_class
        errors.append(r.final_state_error / start_err)
    assert np.median(errors) < 0.35, errors

    # no detection: the controller would wait, so the arm stays put and the error is the start error
    lay.detections = []
    r = run_episode(model, lay, settings)
    assert "no context" in r.note
    assert r.final_state_error == pytest.approx(np.linalg.norm(lay.waypoints[-1] - lay.q0))

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

"""Graph-level integration: the whole system in separate processes pushes a base object to success.

The graph is the shipped demo.launch.yaml, started through vla_launch by the evaluator: bridge
(MuJoCo physics, safety layer, rendered camera, /clock) -> detector_node on the rendered images ->
controller_node (shipped latent model) <- sim_teleoperator (publishes joy like a person); the bridge
resets to a fresh layout through ~/reset. The episode must succeed (object displaced
>= 10 cm within 30 deg of the task direction) with no limit violation measured on joint_states,
no rejected command and no e-stop.
"""
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.ros]


def _shipped():
    from vla_evaluation.resources import detector_model_path, latent_model_dir

    model, det = latent_model_dir("default"), detector_model_path()
    assert (Path(model) / "config.json").is_file(), f"shipped latent model missing at {model}"
    assert Path(det).is_file(), f"shipped detector missing at {det}"
    return model, det


@pytest.mark.timeout(420)
def test_graph_pushes_a_base_object_to_success(tmp_path):
    from vla_evaluation.graph import GraphConfig, GraphEvaluator
    from vla_evaluation.kinematic import TeleopSettings

    model, det = _shipped()
    cfg = GraphConfig(model_path=str(model), detector_model=str(det), real_time_factor=2.0,
                      settings=TeleopSettings(rate=100.0), stop_on_success=True, linger=1.0,
                      log_dir=tmp_path / "logs")
    with GraphEvaluator(cfg, log=print) as ev:
        # A layout never used for demonstrations. The shipped model's success rate over fresh
        # layouts is 75-95 % per task (vla_latent_controller README, "Shipped models"), so the test
        # fixes one on which it pushes with margin (19 cm, under 1 deg off, at 20 Hz and at 100 Hz
        # with the machine loaded).
        rec = ev.run_episode("milk_carton/push_south_west", seed=100_006)
    r = rec.result
    print(r.row())
    assert r.detected_class == "milk_carton"
    assert r.success, f"object moved {r.displacement_m:.3f} m at {r.angle_err_deg:.0f} deg off the direction"
    assert r.displacement_m >= 0.10
    assert r.limit_violations == 0
    assert r.extra["commands_rejected"] == 0 and not r.extra["estop"]
    assert r.time_to_success is not None and r.time_to_success < 30.0
    assert len(rec.tcp_path) > 10

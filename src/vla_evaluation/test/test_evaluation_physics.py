"""`--mode physics`: the shipped model in MuJoCo behind the safety filter, judged like graph mode."""
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def shipped():
    from vla_detector.inference import Detector
    from vla_evaluation.resources import detector_model_path, latent_model_dir
    from vla_latent_controller.model import LatentModel
    from vla_sim.sim import PandaSim

    model_dir = latent_model_dir("default")
    assert (Path(model_dir) / "config.json").is_file(), f"shipped latent model missing at {model_dir}"
    return LatentModel.load(model_dir), Detector(detector_model_path()), PandaSim(render=True)


def _layout(shipped, task, seed):
    from vla_evaluation.kinematic import make_layouts

    _model, det, sim = shipped
    return make_layouts([task], [seed], sim=sim, detector=det)[0]


def test_physics_episode_pushes_a_base_object(shipped):
    from vla_evaluation.kinematic import TeleopSettings
    from vla_evaluation.physics import run_episode

    model, _det, sim = shipped
    lay = _layout(shipped, "milk_carton/push_south_west", 100_006)  # the graph test's layout
    r = run_episode(model, lay, TeleopSettings(rate=100.0), sim, stop_on_success=True)
    assert r.mode == "physics" and r.detected_class == "milk_carton"
    assert r.success, f"object moved {r.displacement_m:.3f} m at {r.angle_err_deg:.0f} deg off"
    assert r.limit_violations == 0
    assert r.time_to_success is not None and r.duration_s < 30.0  # stopped 1 s after success
    assert r.ee_path is not None and len(r.ee_path) > 10
    assert r.final_state_error < 0.5 * r.extra["start_error"]  # much nearer the post-push pose


def test_physics_episode_without_a_detection_leaves_the_arm_still(shipped):
    from vla_evaluation.kinematic import TeleopSettings
    from vla_evaluation.physics import run_episode

    model, _det, sim = shipped
    lay = _layout(shipped, "soda_can/push_south", 100_001)
    lay.detections = []  # the camera saw nothing: the controller would wait
    r = run_episode(model, lay, TeleopSettings(rate=100.0), sim)
    assert r.success is False and r.note.startswith("no context")
    assert np.allclose(sim.q, lay.q0, atol=1e-3)
    assert r.displacement_m is None


def test_physics_mode_refuses_a_safety_period_other_than_the_physics_step(shipped):
    from vla_evaluation.kinematic import TeleopSettings
    from vla_evaluation.physics import run_episode
    from vla_panda_bridge.safety import SafetyConfig

    model, _det, sim = shipped
    lay = _layout(shipped, "soda_can/push_south", 100_001)
    with pytest.raises(ValueError, match="physics step"):
        run_episode(model, lay, TeleopSettings(rate=100.0), sim, safety_config=SafetyConfig(dt=0.01))

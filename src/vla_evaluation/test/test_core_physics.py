"""The controller's own core on the in-process physics (core_physics.py): with the assistance on, a held
stick pushes the object and the hand does a pick-and-place with three presses of its button (issue 34)."""
import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scene():
    from vla_detector.inference import Detector
    from vla_evaluation.resources import detector_model_path
    from vla_sim.sim import PandaSim

    return Detector(detector_model_path()), PandaSim(render=True)


def _run(scene, task, model, seed, operator, seconds, level="high"):
    from vla_evaluation.core_physics import run_core_episode
    from vla_evaluation.kinematic import make_layouts
    from vla_evaluation.resources import latent_model_dir
    from vla_latent_controller.model import LatentModel
    from vla_latent_controller.teleop import TeleopParams

    det, sim = scene
    lay = make_layouts([task], [seed], sim=sim, detector=det)[0]
    return run_core_episode(LatentModel.load(latent_model_dir(model)), lay, TeleopParams(assistance=level),
                            sim, operator, seconds, detector=det)


def test_a_held_stick_with_the_assistance_pushes_the_object(scene):
    from vla_evaluation.core_physics import hold

    run = _run(scene, "soda_can/push_south", "default", 100_006, hold(1.0), 10.0)
    r = run.result
    assert r.success, f"moved {r.displacement_m:.3f} m at {r.angle_err_deg:.0f} deg off"
    assert r.limit_violations == 0 and not r.extra["reflex"]
    shares = [share for _t, _stick, share, _c, _stage in run.trace]
    assert max(shares) == 1.0 and {stage for *_x, stage in run.trace} >= {"hover", "pre_push", "push_end"}


def test_pick_and_place_with_the_assistance_and_the_operators_button(scene):
    """Open above the bottle, close when the hand stands at the grasp pose, open at the place: three
    presses, the stick held forward all along."""
    seen = {"stage": "", "still": 0.0, "last": None}

    def person(s):
        st, hand = s.status.assist, s.hand
        moving = seen["last"] is None or np.linalg.norm(s.tcp - seen["last"]) > 5e-4
        seen["still"] = 0.0 if moving or st.stage != seen["stage"] else seen["still"] + 0.01
        seen["stage"], seen["last"] = st.stage, s.tcp.copy()
        idle = hand.state not in (1, 2)            # not moving, not grasping
        want = ((st.stage == "hover" and hand.width < 0.07)
                or (st.stage == "grasp" and hand.width > 0.07 and seen["still"] > 0.3)
                or (st.stage == "place" and bool(hand.holding) and seen["still"] > 0.3))
        return 1.0, bool(want and idle)

    run = _run(scene, "glass_bottle/pick_place_west", "glass_bottle_pick_place_west", 310_001, person, 20.0)
    r = run.result
    assert r.success and r.displacement_m < 0.02, f"placed {r.displacement_m:.3f} m from the target"
    assert run.presses == 3

"""A shorter chord's direction lets a held full stick follow the demonstrated path (issue 20 item 5):
the shipped model's command at path_fraction 0.65, integrated from the start pose of held-out layouts
as a person holding +1 would drive it, comes close to the planner's pre-push pose before it pushes
(the shipped `default` carries its own calibrated fraction, which the controller uses by default:
0.8, measured through the graph and the demo; 0.65 failed the demo's bread). With the raw decoder
action (the chord of the longest windows, path_fraction 1, the paper's command) the hand cut
the corner: it turned toward the push while 15-20 cm up and stayed 0.19-0.55 rad from that pose
(bread, soda can; measured on these layouts: median 0.27 and 0.40 rad against 0.11 and 0.17)."""

import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics
from vla_common.robot import DQ_MAX
from vla_evaluation.planner_demos import planner_demo
from vla_evaluation.resources import latent_model_dir
from vla_evaluation.sim_teleoperator import StickToCommand
from vla_latent_controller.model import LatentModel

NEAR_PRE_PUSH = 0.2  # rad: the median closest approach a held full stick must reach
SHORTER = 0.65  # a path fraction well below 1


def _closest_to_pre_push(task: str, seeds, path_fraction: float) -> list[float]:
    kin = PandaKinematics()
    model = LatentModel.load(latent_model_dir("default"))
    out = []
    for seed in seeds:
        demo, plan, _ = planner_demo(task, seed, kin)
        command = StickToCommand(model, model.context(demo.detection, demo.image_size), demo.object_class,
                                 dq_max=DQ_MAX, path_fraction=path_fraction)
        q, pre, best = demo.q[0].copy(), np.asarray(plan.waypoints[1]), np.inf
        for _ in range(600):  # 6 s at the controller's 100 Hz
            v = command(np.array([1.0]), q)[0]  # the controller's mapping (StickToCommand mirrors it)
            q = q + 0.01 * v
            best = min(best, float(np.linalg.norm(q - pre)))
        out.append(best)
    return out


@pytest.mark.parametrize("task", ["bread/push_east", "soda_can/push_south"])
def test_a_held_full_stick_reaches_the_pre_push_pose(task):
    seeds = range(50_000, 50_004)  # layouts never trained on
    ours = _closest_to_pre_push(task, seeds, SHORTER)
    assert np.median(ours) < NEAR_PRE_PUSH, ours
    raw = _closest_to_pre_push(task, seeds, 1.0)  # the paper's command: the chord itself
    assert np.median(raw) > NEAR_PRE_PUSH, raw


def test_the_controller_uses_the_shipped_models_calibrated_fraction():
    """The controller's default path_fraction (0) is the model's latent.path_fraction: below 1 for
    `default`, whose held stick needs it; 1, the paper's command, for a model without one."""
    from vla_latent_controller.teleop import TeleopParams

    assert TeleopParams().path_fraction == 0.0
    fraction = LatentModel.load(latent_model_dir("default")).path_fraction(TeleopParams().path_fraction)
    assert 0.5 <= fraction < 1.0
    assert LatentModel.load(latent_model_dir("cereal_box_push_south")).path_fraction() == 1.0

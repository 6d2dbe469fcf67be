"""Trained on planner demonstrations of the paper's base tasks, the latent action does the task:
one second of z > 0 from a held-out layout's start pose brings the arm closer to the configuration
above the object, and along the push it moves the end effector in that task's direction (z < 0
retraces it).

The model is one the experiments train (`Plan().train_config`: full batches of 6000 pairs, 64 units,
at least 1000 updates), whose outcome does not hinge on the seed or on which kernels the CPU's MKL
picks. The limits are set well inside what that recipe measured over 12 trainings (seeds 0-7 with
MKL_CBWR unset, 0-3 with MKL_CBWR=COMPATIBLE, AMD EPYC; docs/history/training.md); the worst of each
figure over the four tasks is in brackets beside its limit.
"""

import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import BASE_TASKS, parse_task
from vla_evaluation.experiments import Plan
from vla_evaluation.planner_demos import planner_demo, planner_demos
from vla_latent_controller.model import LatentModel
from vla_latent_training.pairs import make_pairs
from vla_latent_training.train import train_model

HOVER_MIN, HOVER_MEAN = 0.1, 0.15  # share of the distance to the hover pose covered in 1 s [0.22, 0.32]
ALONG_MEAN, ALONG_SHARE = 0.3, 0.75  # cosine with the push direction, share of states > 0 [0.59, 0.90]
BACK_MEAN = -0.4  # cosine at z < 0 [-0.68]


@pytest.fixture(scope="module")
def setup():
    kin = PandaKinematics()
    demos = planner_demos(BASE_TASKS, per_task=5, seed=0, kin=kin)
    res = train_model(
        demos, Plan().train_config("detector", seed=0), pairs_fn=make_pairs, progress=False, threads=1,
        log=lambda s: None,
    )
    return kin, res


@pytest.mark.slow
@pytest.mark.parametrize(
    "task",
    ["bread/push_east", "soda_can/push_south", "milk_carton/push_south_west", "glass_bottle/push_west"],
)
def test_positive_latent_does_the_task(setup, task, tmp_path):
    kin, res = setup
    model = LatentModel.load(res.save(tmp_path / "m"))
    d = parse_task(task).direction_vector
    to_hover, along, back = [], [], []
    for seed in range(50_000, 50_004):  # layouts and start poses never trained on
        demo, plan, _ = planner_demo(task, seed, kin)
        model.decoder.set_context(model.context(demo.detection, demo.image_size))
        g = model.gain(demo.object_class)
        assert g > 0  # the signed latent: + is the demonstrated direction by construction
        # One second at z = +gain from the start brings the arm closer to the hover configuration
        # above the object. Measured in joint space, as the teleoperator and the final state error
        # are: when the planner changes arm branch the demonstration itself first swings the hand
        # away from the hover point in Cartesian space.
        q = demo.q[0].copy()
        hover = np.asarray(plan.waypoints[0])
        d0 = np.linalg.norm(q - hover)
        for _ in range(10):
            q += 0.1 * model.decoder.decode(q, g)
        to_hover.append(1.0 - np.linalg.norm(q - hover) / d0)
        t_pre, t_post = plan.times[1], plan.times[2]
        for t in np.linspace(t_pre + 0.5, t_post - 0.5, 5):  # states on the demonstrated push
            q = demo.q[int(round(t * 10))]
            for z, out in ((0.5 * g, along), (-0.5 * g, back)):
                v = (kin.jacobian(q)[:3] @ model.decoder.decode(q, z))[:2]
                out.append(v @ d / np.linalg.norm(v))
    assert np.min(to_hover) > HOVER_MIN and np.mean(to_hover) > HOVER_MEAN, to_hover
    assert np.mean(along) > ALONG_MEAN and np.mean(np.array(along) > 0) >= ALONG_SHARE, along
    assert np.mean(back) < BACK_MEAN, back

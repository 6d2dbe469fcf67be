"""The demonstrations pass where the task's goal poses say (vla_common.task_goals is the planner's
geometry): the assistance aims where the demonstrator went."""
import numpy as np
import pytest
from vla_common.catalogue import default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.task_goals import task_goal_poses
from vla_common.tasks import task_layout
from vla_sim.planner import plan_task, random_start_pose

CAT = default_catalogue()


@pytest.mark.parametrize("task,names", [
    ("bread/push_east", ["hover", "pre_push", "push_end"]),
    ("milk_carton/push_south_west", ["hover", "pre_push", "push_end"]),
    ("glass_bottle/pick_place_west", ["hover", "grasp", "carry", "place", "retreat"]),
])
def test_planned_keyframes_lie_near_the_goal_poses(task, names):
    kin = PandaKinematics()
    spec = CAT.task(task)
    for seed in range(3):
        rng = np.random.default_rng(seed)
        obj = task_layout(spec, rng, n_objects=1)[0]
        plan = plan_task(kin, spec, obj, random_start_pose(rng), rng)
        goals = task_goal_poses(spec, CAT.spec(spec.object_class), (obj.x, obj.y))
        assert [g.name for g in goals] == names
        keyframes = np.array(plan.tcp_waypoints)
        for g in goals:   # the demonstrator's random ranges around the middle: a few centimetres
            assert np.min(np.linalg.norm(keyframes - g.position, axis=1)) < 0.045, (g.name, seed)

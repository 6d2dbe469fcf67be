"""End to end: a push planned with Pinocchio IK from the object's pose, executed through the safety
filter and the simulator's velocity interface, moves the object the intended way."""
import math

import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import TASKS, task_layout, task_success
from vla_sim.planner import execute_plan, plan_task, random_start_pose
from vla_sim.sim import PandaSim

try:
    from vla_panda_bridge.safety import SafetyConfig, SafetyFilter
except ImportError:  # the safety layer is optional here: clip to DQ_MAX instead
    SafetyConfig = SafetyFilter = None


@pytest.fixture(scope="module")
def sim():
    s = PandaSim(render=False)
    yield s
    s.close()


@pytest.mark.slow
@pytest.mark.parametrize("name, seed", [("bread/push_east", 11), ("soda_can/push_south", 12),
                                        ("milk_carton/push_south_west", 13), ("glass_bottle/push_west", 14)])
def test_scripted_push_moves_object(sim, name, seed):
    task = TASKS[name]
    rng = np.random.default_rng(seed)
    sim.reset(objects=task_layout(task, rng), q0=random_start_pose(rng))
    start = sim.object_poses()[0]
    others_before = sim.object_poses()[1:]
    plan = plan_task(PandaKinematics(), task, start, sim.q, rng)
    safety = SafetyFilter(SafetyConfig(dt=sim.physics_dt)) if SafetyFilter else None
    execute_plan(sim, plan, safety)
    end = sim.object_poses()[0]
    delta = np.array([end.x - start.x, end.y - start.y])
    moved = float(np.linalg.norm(delta))
    angle = math.degrees(math.acos(np.clip(delta @ task.direction_vector / max(moved, 1e-9), -1, 1)))
    assert moved >= 0.05 and angle <= 30.0, (moved, angle)
    ok, disp, _ = task_success(task, start, end)
    assert ok, (disp, angle)
    assert end.z == pytest.approx(start.z, abs=0.01)  # still upright on the table
    for a, b in zip(others_before, sim.object_poses()[1:]):  # the rest of the scene is untouched
        assert math.hypot(a.x - b.x, a.y - b.y) < 0.01
    # The arm ends at the plan's last waypoint, at rest.
    np.testing.assert_allclose(sim.q, plan.waypoints[-1], atol=0.01)
    assert np.abs(sim.dq).max() < 0.05

"""The scripted demonstrator's tasks with the hand, executed in MuJoCo through the safety filter:
lift (raised >= 5 cm, held >= 2 s) and pick-and-place (put down within 5 cm of the target), on
random task layouts, with the plan's hand events as the demonstrator sends them."""
import numpy as np
import pytest
from vla_common.catalogue import default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import place_target, task_layout, task_success
from vla_sim.planner import plan_task, random_start_pose
from vla_sim.sim import PandaSim

safety = pytest.importorskip("vla_panda_bridge.safety")

DT = 0.002
OPEN = (0.08, 0.08, 20.0)
GRASP = (0.0, 0.08, 30.0)


@pytest.fixture(scope="module")
def sim():
    s = PandaSim(render=False, physics_dt=DT)
    yield s
    s.close()


def run(sim, plan, obj_class, settle=0.5):
    """Execute the plan (hand events at their times); the object's (time, z) and end pose."""
    f = safety.SafetyFilter(safety.SafetyConfig(dt=DT))
    f.reset(sim.q_target)
    t0, done = sim.time, set()
    times, heights = [], []
    z0 = next(o.z for o in sim.object_poses() if o.class_id == obj_class)
    for _ in range(int((plan.duration + settle) / DT)):
        t = sim.time - t0
        for i, (when, what) in enumerate(plan.hand_events):
            if when <= t and i not in done:
                done.add(i)
                sim.hand.command(*(OPEN if what == "open" else GRASP))
        cmd, _code, _text = f.filter(plan.command(t, sim.q), sim.q_target, sim.time)
        sim.set_velocity_command(cmd)
        sim.step(1)
        times.append(t)
        heights.append(next(o.z for o in sim.object_poses() if o.class_id == obj_class) - z0)
    return (times, heights), next(o for o in sim.object_poses() if o.class_id == obj_class)


@pytest.mark.parametrize("task", ["soda_can/lift", "soda_can/pick_place_west"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scripted_grasp_tasks_succeed(sim, task, seed):
    cat = default_catalogue()
    spec = cat.task(task)
    rng = np.random.default_rng(seed)
    layout = task_layout(spec, rng)
    start = sim.reset(objects=layout, q0=random_start_pose(rng))[0]
    plan = plan_task(PandaKinematics(), spec, start, sim.q, rng)
    assert [e[1] for e in plan.hand_events][:2] == ["open", "grasp"]
    lift, end = run(sim, plan, spec.object_class)
    ok, a, b = task_success(spec, start, end, lift=lift)
    assert ok, (task, seed, a, b, [o for o in sim.object_poses()])
    assert sim.reflex() is None
    if spec.kind == "pick_place":
        assert np.linalg.norm(np.array([end.x, end.y]) - place_target(spec, start)) < 0.03
        assert sim.held_objects() == []

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


@pytest.mark.parametrize("task", ["soda_can/lift", "soda_can/pick_place_west",
                                  "glass_bottle/pick_place_west"])
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


def _directions(plan, kin):
    """Unit TCP directions of the plan's keyframe-to-keyframe moves (zero moves dropped)."""
    tcp = np.array([kin.fk(q)[0] for q in plan.waypoints])
    d = np.diff(tcp, axis=0)
    n = np.linalg.norm(d, axis=1)
    return d[n > 1e-4] / n[n > 1e-4, None]


@pytest.mark.parametrize("task, placed", [("glass_bottle/pick_place_west", True),
                                          ("soda_can/pick_place_west", False)])
def test_the_bottle_is_picked_by_its_neck_with_the_hand_2cm_across(sim, task, placed):
    """The glass bottle's pick-and-place grasps its 26 mm neck: the hand may be 2 cm off across
    (the fingers' closing axis, y) and still carry it to the target; the soda can's 66 mm body in
    the 80 mm hand is missed at 1 cm (bench/bench_grasp_window.py). A learned 1-D latent puts the
    hand near, not at, the grasp point."""
    from vla_common.objects import ObjectPose

    cat = default_catalogue()
    spec = cat.task(task)
    rng = np.random.default_rng(7)
    planned = ObjectPose(spec.object_class, 0.50, -0.05, 0.0)
    actual = ObjectPose(spec.object_class, 0.50, -0.05 + 0.02, 0.0)
    start = sim.reset(objects=[actual], q0=random_start_pose(rng))[0]
    plan = plan_task(PandaKinematics(), spec, planned, sim.q, rng)
    lift, end = run(sim, plan, spec.object_class)
    ok, err, _above = task_success(spec, start, end, lift=lift)
    assert ok == placed, (task, err, end)


@pytest.mark.parametrize("task", ["soda_can/lift", "soda_can/pick_place_west",
                                  "glass_bottle/pick_place_west"])
def test_grasp_paths_never_go_back_over_themselves(task):
    """A 1-D latent has one way forward at each state: no move of the hand's path reverses the one
    before it (a vertical descent then a lift on the same line taught + down and up at once)."""
    kin = PandaKinematics()
    spec = default_catalogue().task(task)
    for seed in range(3):
        rng = np.random.default_rng(seed)
        start = task_layout(spec, rng)[0]
        plan = plan_task(kin, spec, start, random_start_pose(rng), rng)
        d = _directions(plan, kin)
        cos = np.sum(d[1:] * d[:-1], axis=1)
        assert cos.min() > -0.8, (task, seed, cos.min())


def test_plan_command_pace_scales_the_feed_forward():
    kin = PandaKinematics()
    spec = default_catalogue().task("soda_can/pick_place_west")
    rng = np.random.default_rng(0)
    plan = plan_task(kin, spec, task_layout(spec, rng)[0], random_start_pose(rng), rng)
    t = plan.duration / 3
    q_ref, dq_ref = plan.reference(t)
    assert np.allclose(plan.command(t, q_ref), dq_ref)
    assert np.allclose(plan.command(t, q_ref, pace=0.0), 0.0)
    assert np.allclose(plan.command(t, q_ref, pace=0.5), 0.5 * dq_ref)

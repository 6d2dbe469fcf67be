"""PandaSim: velocity integration, holding, layouts (seeded, explicit, refused), camera geometry."""
import math

import numpy as np
import pytest
from require import missing
from vla_common.kinematics import PandaKinematics
from vla_common.layout import LAYOUT_X, LAYOUT_Y, overlap
from vla_common.objects import OBJECT_CLASSES, OBJECT_SPECS, ObjectPose
from vla_common.robot import DQ_MAX, READY_POSE
from vla_sim.sim import PandaSim


@pytest.fixture(scope="module")
def sim():
    s = PandaSim(render=False)
    yield s
    s.close()


def _render_sim(width=320, height=240):
    s = PandaSim(camera_width=width, camera_height=height, render=True)
    try:
        s.render()
    except Exception as exc:  # no EGL on this machine
        s.close()
        missing("RENDER", f"headless rendering unavailable: {exc}")
    return s


@pytest.fixture(scope="module")
def rsim():
    s = _render_sim()
    yield s
    s.close()


def test_constant_command_integrates(sim):
    sim.reset(seed=1)
    q0 = sim.q
    cmd = np.array([0.3, 0.2, -0.2, 0.3, 0.5, -0.4, 0.6])
    sim.set_velocity_command(cmd)
    steps = int(round(1.0 / sim.physics_dt))
    sim.step(steps)
    assert sim.time == pytest.approx(1.0)
    # Joints follow the integrated command within 2 mrad (servo lag), at the commanded velocity.
    np.testing.assert_allclose(sim.q, q0 + cmd * 1.0, atol=2e-3)
    np.testing.assert_allclose(sim.dq, cmd, atol=2e-2)
    np.testing.assert_allclose(sim.q_target, q0 + cmd * 1.0, atol=1e-9)


def test_zero_command_holds_pose_against_gravity(sim):
    q0 = np.array([0.3, 0.2, -0.3, -1.8, 0.4, 2.2, 0.1])
    sim.reset(seed=2, q0=q0)
    sim.set_velocity_command(np.zeros(7))
    sim.step(1000)
    np.testing.assert_allclose(sim.q, q0, atol=1e-4)
    assert np.all(np.isfinite(sim.effort))


def test_pinocchio_and_sim_agree_on_tcp(sim):
    kin = PandaKinematics()
    sim.reset(seed=0)
    sim.set_velocity_command([0.2, -0.1, 0.1, 0.2, -0.3, 0.2, 0.1])
    sim.step(300)
    p_sim, r_sim = sim.tcp_pose()
    p, r = kin.fk(sim.q)
    np.testing.assert_allclose(p_sim, p, atol=1e-6)
    np.testing.assert_allclose(r_sim, r, atol=1e-6)


def test_command_is_clipped_and_validated(sim):
    sim.reset(seed=0)
    sim.set_velocity_command(np.full(7, 100.0))
    sim.step(1)
    assert np.all(np.abs(sim.command) <= DQ_MAX + 1e-12)
    with pytest.raises(ValueError):
        sim.set_velocity_command(np.zeros(6))
    with pytest.raises(ValueError):
        sim.set_velocity_command([np.nan] * 7)


def test_same_seed_same_layout(sim):
    a = sim.reset(seed=42)
    sim.set_velocity_command(np.full(7, 0.1))
    sim.step(200)
    b = sim.reset(seed=42)
    assert [(p.class_id, p.x, p.y, p.yaw) for p in a] == [(p.class_id, p.x, p.y, p.yaw) for p in b]
    c = sim.reset(seed=43)
    assert [(p.class_id, p.x, p.y) for p in a] != [(p.class_id, p.x, p.y) for p in c]


def test_random_layouts_are_valid(sim):
    counts = set()
    for seed in range(40):
        layout = sim.reset(seed=seed)
        counts.add(len(layout))
        assert 1 <= len(layout) <= 4
        assert len({p.class_id for p in layout}) == len(layout)
        for i, p in enumerate(layout):
            assert LAYOUT_X[0] <= p.x <= LAYOUT_X[1] and LAYOUT_Y[0] <= p.y <= LAYOUT_Y[1]
            assert p.z == pytest.approx(OBJECT_SPECS[p.class_id].height / 2, abs=1e-6)
            for q in layout[i + 1:]:
                assert not overlap(p, q, 0.0)
    assert counts == {1, 2, 3, 4}


def test_objects_rest_on_the_table(sim):
    layout = sim.reset(seed=5)
    sim.step(500)
    for before, after in zip(layout, sim.object_poses()):
        assert after.class_id == before.class_id
        assert math.hypot(after.x - before.x, after.y - before.y) < 2e-3
        assert after.z == pytest.approx(OBJECT_SPECS[after.class_id].height / 2, abs=2e-3)


def test_explicit_layout_and_formats(sim):
    layout = sim.reset(objects=[ObjectPose("bread", 0.5, 0.1, 0.3),
                                {"class_id": "soda_can", "x": 0.6, "y": -0.2},
                                ("cereal_box", 0.4, -0.2, 1.0)])
    assert [p.class_id for p in layout] == ["bread", "soda_can", "cereal_box"]
    assert layout[0].x == pytest.approx(0.5) and layout[0].yaw == pytest.approx(0.3)
    assert layout[1].yaw == pytest.approx(0.0)
    assert sim.reset(objects=[]) == []


@pytest.mark.parametrize("objects, message", [
    ([("sandwich", 0.5, 0.0, 0.0)], "unknown object class"),
    ([("bread", 0.5, 0.0, 0.0), ("bread", 0.5, 0.3, 0.0)], "twice"),
    ([("bread", 0.5, 0.0, 0.0), ("milk_carton", 0.52, 0.02, 0.0)], "overlaps"),
    ([("bread", 3.0, 0.0, 0.0)], "off the table"),
    ([("bread", 0.05, 0.0, 0.0)], "robot base"),
    ([("bread", float("nan"), 0.0, 0.0)], "finite"),
    ([("bread", "a", 0.0, 0.0)], "numbers"),
    ([("bread", 0.5)], "not an ObjectPose"),
    ([{"class_id": "bread", "y": 0.1}], "needs"),
    ("bread", "list"),
])
def test_bad_layout_refused_scene_unchanged(sim, objects, message):
    before = sim.reset(seed=7)
    sim.step(10)
    q, poses, t = sim.q, sim.object_poses(), sim.time
    with pytest.raises(ValueError, match=message):
        sim.reset(objects=objects)
    assert sim.time == t
    np.testing.assert_array_equal(sim.q, q)
    assert [(p.class_id, p.x, p.y) for p in sim.object_poses()] == [(p.class_id, p.x, p.y) for p in poses]
    assert len(before) == len(poses)


@pytest.mark.parametrize("q0", [np.zeros(6), [np.inf] * 7, READY_POSE + np.array([0, 0, 0, 5.0, 0, 0, 0])])
def test_bad_q0_refused(sim, q0):
    sim.reset(seed=1)
    q = sim.q
    with pytest.raises(ValueError, match="q0"):
        sim.reset(seed=2, q0=q0)
    np.testing.assert_array_equal(sim.q, q)


def test_bad_seed_refused(sim):
    with pytest.raises(ValueError, match="seed"):
        sim.reset(seed=-1)


def test_no_render_mode_refuses_images_but_projects(sim):
    with pytest.raises(RuntimeError):
        sim.render()
    uv = sim.project([[0.5, 0.0, 0.0]])
    w, h = sim.camera_size
    assert 0 <= uv[0, 0] < w and 0 <= uv[0, 1] < h


def test_render_size_and_intrinsics(rsim):
    rsim.set_camera_size(320, 240)
    img = rsim.render()
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    fx, fy, cx, cy = rsim.camera_intrinsics()
    rsim.set_camera_size(640, 480)
    img = rsim.render()
    assert img.shape == (480, 640, 3)
    fx2, fy2, cx2, cy2 = rsim.camera_intrinsics()
    assert fx2 == pytest.approx(2 * fx) and fy2 == pytest.approx(fx2)
    assert (cx2, cy2) == (319.5, 239.5)
    with pytest.raises(ValueError):
        rsim.set_camera_size(0, 480)
    rsim.set_camera_size(320, 240)


def test_projection_lands_on_object_colour(rsim):
    layout = rsim.reset(objects=[("soda_can", 0.55, 0.15, 0.0), ("cereal_box", 0.45, -0.2, 0.4),
                                 ("bread", 0.68, -0.02, 1.2)])
    img = rsim.render().astype(int)
    for pose in layout:
        u, v = rsim.project([[pose.x, pose.y, pose.z]])[0]
        ui, vi = int(round(u)), int(round(v))
        patch = img[vi - 1:vi + 2, ui - 1:ui + 2].reshape(-1, 3)
        target = np.array(OBJECT_SPECS[pose.class_id].rgba[:3]) * 255
        # Lit colours vary with shading: the pixel's hue must match the object's colour best.
        dists = {c: np.linalg.norm(_chroma(patch.mean(0)) - _chroma(np.array(OBJECT_SPECS[c].rgba[:3]) * 255))
                 for c in OBJECT_CLASSES}
        assert min(dists, key=dists.get) == pose.class_id, (pose.class_id, patch.mean(0), target)
    # And a point on the table far from objects is not any object's colour.
    u, v = rsim.project([[0.3, 0.45, 0.0]])[0]
    px = img[int(round(v)), int(round(u))]
    assert np.linalg.norm(_chroma(px) - _chroma(np.array(OBJECT_SPECS["soda_can"].rgba[:3]) * 255)) > 0.1


def _chroma(rgb):
    rgb = np.asarray(rgb, float)
    return rgb / max(rgb.sum(), 1e-6)


def test_a_blocked_arm_stores_no_travel_and_does_not_lunge_when_freed(sim, monkeypatch):
    """The servo's target leads the joint by at most MAX_FOLLOWING_ERROR: a hand pressed down on the
    table while commands go on (the demo's cereal-box push, resting on the box) must not store the
    travel and release it as a lunge when the commands turn (fails with the clamp lifted)."""
    import vla_sim.sim as sim_module

    kin = PandaKinematics()
    q0, ok = kin.ik([0.5, 0.0, 0.03], np.diag([1.0, -1.0, -1.0]))
    assert ok
    sim.reset(objects=[], q0=q0)
    sim.clear_reflex()
    down = np.linalg.pinv(kin.jacobian(q0)) @ np.array([0.0, 0.0, -0.1, 0.0, 0.0, 0.0])
    sim.set_velocity_command(down)                 # 0.1 m/s into the table for 1 s: 10 cm of travel
    lead = 0.0
    for _ in range(1000):
        sim.step(1)
        lead = max(lead, float(np.max(np.abs(sim.q_target - sim.q))))
    assert lead <= sim_module.MAX_FOLLOWING_ERROR + 1e-9
    sim.set_velocity_command(np.zeros(7))          # the operator lets go: the arm settles, no lunge
    speed = 0.0
    for _ in range(500):
        sim.step(1)
        speed = max(speed, float(np.max(np.abs(sim.dq))))
    assert speed < 0.5

"""Pinocchio kinematics: one kinematic truth with the MuJoCo scene, Jacobian and IK correctness."""
import mujoco
import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics, panda_urdf_path
from vla_common.robot import Q_MAX, Q_MIN, READY_POSE
from vla_sim.scene import TCP_SITE, build_model


@pytest.fixture(scope="module")
def kin():
    return PandaKinematics()


def test_urdf_path_exists():
    path = panda_urdf_path()
    assert path.endswith("panda_description/urdf/panda.urdf")
    with open(path) as f:
        assert "panda_hand_tcp" in f.read()


def test_mujoco_tcp_matches_pinocchio(kin):
    model = build_model()
    data = mujoco.MjData(model)
    site = model.site(TCP_SITE).id
    qadr = [model.jnt_qposadr[model.joint(f"panda_joint{i}").id] for i in range(1, 8)]
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.uniform(Q_MIN, Q_MAX)
        data.qpos[qadr] = q
        mujoco.mj_kinematics(model, data)
        p, r = kin.fk(q)
        np.testing.assert_allclose(data.site_xpos[site], p, atol=1e-6)
        np.testing.assert_allclose(data.site_xmat[site].reshape(3, 3), r, atol=1e-6)


def test_ready_pose_tcp_points_down(kin):
    p, r = kin.fk(READY_POSE)
    assert 0.25 < p[0] < 0.40 and abs(p[1]) < 1e-6 and 0.4 < p[2] < 0.6
    np.testing.assert_allclose(r[:, 2], [0, 0, -1], atol=1e-6)
    fp, _ = kin.flange_fk(READY_POSE)
    assert fp[2] - p[2] == pytest.approx(0.1034, abs=1e-6)  # TCP 10.34 cm below the flange


def test_jacobian_matches_finite_differences(kin):
    rng = np.random.default_rng(2)
    q = rng.uniform(Q_MIN + 0.2, Q_MAX - 0.2)
    J = kin.jacobian(q)
    assert J.shape == (6, 7)
    eps = 1e-6
    p0, r0 = kin.fk(q)
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = eps
        p1, r1 = kin.fk(q + dq)
        np.testing.assert_allclose((p1 - p0) / eps, J[:3, i], atol=1e-5)
        w = r1 @ r0.T  # small rotation: skew part / eps is the angular velocity
        omega = np.array([w[2, 1] - w[1, 2], w[0, 2] - w[2, 0], w[1, 0] - w[0, 1]]) / (2 * eps)
        np.testing.assert_allclose(omega, J[3:, i], atol=1e-5)


def test_tcp_state_is_fk_and_jacobian_in_one_pass(kin):
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(Q_MIN + 0.2, Q_MAX - 0.2)
        p, r, J = kin.tcp_state(q)
        p0, r0 = kin.fk(q)
        np.testing.assert_allclose(p, p0, atol=1e-12)
        np.testing.assert_allclose(r, r0, atol=1e-12)
        np.testing.assert_allclose(J, kin.jacobian(q), atol=1e-12)


def test_arm_points_lie_on_the_links_and_move_with_their_jacobians(kin):
    rng = np.random.default_rng(4)
    q = rng.uniform(Q_MIN + 0.3, Q_MAX - 0.3)
    points, jacobians = kin.arm_points(q)
    mesh = kin.link_points(q)
    assert len(points) == 16 * 5
    assert np.min(np.linalg.norm(mesh[None] - points[:, None], axis=2), axis=1).max() < 1e-9
    dq = rng.normal(size=7) * 1e-6
    moved, _ = kin.arm_points(q + dq)
    np.testing.assert_allclose(moved - points, jacobians(range(len(points))) @ dq, atol=1e-10)


def test_ik_round_trip(kin):
    rng = np.random.default_rng(3)
    for _ in range(10):
        q_true = np.clip(READY_POSE + rng.normal(0, 0.3, 7), Q_MIN + 0.1, Q_MAX - 0.1)
        p, r = kin.fk(q_true)
        q, ok = kin.ik(p, r, READY_POSE)
        assert ok
        p2, r2 = kin.fk(q)
        np.testing.assert_allclose(p2, p, atol=2e-4)
        np.testing.assert_allclose(r2, r, atol=3e-3)
        assert np.all(q >= Q_MIN) and np.all(q <= Q_MAX)


def test_ik_unreachable_reports_failure(kin):
    q, ok = kin.ik([2.0, 0.0, 0.5], None, READY_POSE)
    assert not ok
    assert np.all(q >= Q_MIN) and np.all(q <= Q_MAX)


def test_bad_q_is_refused(kin):
    with pytest.raises(ValueError):
        kin.fk(np.zeros(6))
    with pytest.raises(ValueError):
        kin.fk([np.nan] * 7)


def test_link_points_match_mujoco_meshes(kin):
    model = build_model()
    data = mujoco.MjData(model)
    q = np.random.default_rng(4).uniform(Q_MIN, Q_MAX)
    data.qpos[:7] = q
    mujoco.mj_kinematics(model, data)
    for link in ("panda_link3", "panda_link5", "panda_link7"):
        pts = kin.link_points(q, (link,))
        geom = next(g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name == link)
        mesh = model.geom_dataid[geom]
        verts = model.mesh_vert[model.mesh_vertadr[mesh]:model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
        world = verts @ data.geom_xmat[geom].reshape(3, 3).T + data.geom_xpos[geom]
        np.testing.assert_allclose(pts.min(0), world.min(0), atol=1e-5)
        np.testing.assert_allclose(pts.max(0), world.max(0), atol=1e-5)

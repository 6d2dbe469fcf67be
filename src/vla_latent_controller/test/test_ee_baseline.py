"""The paper's end-effector baseline on the real Panda kinematics (Pinocchio)."""

import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics
from vla_common.robot import READY_POSE
from vla_latent_controller.ee_baseline import EE_AXES, EndEffectorBaseline, damped_pinv


def _rotvec(R: np.ndarray) -> np.ndarray:
    angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    if angle < 1e-12:
        return np.zeros(3)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return angle * w / (2 * np.sin(angle))


@pytest.fixture(scope="module")
def kin():
    return PandaKinematics()


@pytest.mark.parametrize("axis", EE_AXES)
@pytest.mark.parametrize("u", [0.6, -0.6])
def test_tcp_moves_along_the_selected_axis(kin, axis, u):
    ee = EndEffectorBaseline(kin, linear_speed=0.2, angular_speed=0.5)
    ee.select(axis)
    q = np.array(READY_POSE, float)
    p0, R0 = kin.fk(q)
    dt = 0.01
    for _ in range(50):  # 0.5 s
        q += dt * ee.command(q, u)
    p1, R1 = kin.fk(q)
    k = EE_AXES.index(axis)
    if k < 3:
        motion, other = p1 - p0, _rotvec(R1 @ R0.T)
        expected = 0.5 * 0.2 * u
        assert motion[k] == pytest.approx(expected, rel=0.05)
        assert np.linalg.norm(np.delete(motion, k)) < 0.05 * abs(expected)
        assert np.linalg.norm(other) < 0.01
    else:
        motion, other = _rotvec(R1 @ R0.T), p1 - p0
        expected = 0.5 * 0.5 * u
        assert motion[k - 3] == pytest.approx(expected, rel=0.05)
        assert np.linalg.norm(np.delete(motion, k - 3)) < 0.05 * abs(expected)
        assert np.linalg.norm(other) < 0.005


def test_debounced_cycling():
    ee = EndEffectorBaseline(kinematics=None, debounce=0.25)
    assert ee.axis == "x"
    assert ee.press(1.0) and ee.axis == "y"
    assert not ee.press(1.1) and ee.axis == "y"
    assert ee.press(1.3) and ee.axis == "z"
    for t in range(4):
        ee.press(2.0 + t)
    assert ee.axis == "x"  # wraps after yaw


def test_damped_pinv_is_bounded_at_a_singularity():
    J = np.zeros((6, 7))
    J[0, 0] = 1.0  # rank 1
    P = damped_pinv(J, 0.05)
    assert np.all(np.isfinite(P)) and np.abs(P).max() <= 1.0
    np.testing.assert_allclose(J @ P @ np.eye(6)[:, 0], [1 / (1 + 0.05**2), 0, 0, 0, 0, 0], atol=1e-12)

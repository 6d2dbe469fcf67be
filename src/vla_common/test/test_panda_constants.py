import numpy as np
import pytest

from vla_common import robot
from vla_common import robot as panda


def test_limits_are_consistent():
    assert len(panda.JOINT_NAMES) == panda.NUM_JOINTS == 7
    assert np.all(panda.Q_MIN < panda.Q_MAX)
    assert np.all((panda.READY_POSE > panda.Q_MIN) & (panda.READY_POSE < panda.Q_MAX))
    assert np.all(panda.DQ_MAX > 0) and np.all(panda.DDQ_MAX > 0) and np.all(panda.DDDQ_MAX > 0)


@pytest.mark.parametrize("spec", list(robot.ROBOTS.values()), ids=lambda s: s.name)
def test_every_model_has_a_consistent_read_only_table(spec):
    assert spec.num_joints == 7 and len(set(spec.joint_names)) == 7
    assert all(n.startswith(spec.name + "_joint") for n in spec.joint_names)
    assert spec.base_frame == spec.name + "_link0"
    assert np.all(spec.q_min < spec.q_max)
    assert np.all((spec.ready_pose > spec.q_min) & (spec.ready_pose < spec.q_max))
    for table in (spec.q_min, spec.q_max, spec.dq_max, spec.ddq_max, spec.dddq_max, spec.tau_max,
                  spec.ready_pose):
        assert table.shape == (7,) and not table.flags.writeable
    assert np.all(spec.dq_max > 0) and np.all(spec.ddq_max > 0) and np.all(spec.dddq_max > 0)
    assert np.all(spec.tau_max > 0)


def test_module_names_are_the_panda_and_the_fr3_has_its_own_limits():
    assert panda.JOINT_NAMES == robot.PANDA.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    assert panda.DQ_MAX is robot.PANDA.dq_max and panda.Q_MIN is robot.PANDA.q_min
    fr3 = robot.robot_spec("fr3")
    assert fr3.joint_names[0] == "fr3_joint1"
    np.testing.assert_array_equal(fr3.q_min[[3, 5]], [-3.0421, 0.5445])
    np.testing.assert_array_equal(fr3.dq_max, [2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26])
    # libfranka enforces 10 rad/s^2 and 5000 rad/s^3 on an FR3; the table keeps its 0.001 margin below
    np.testing.assert_array_equal(fr3.ddq_max, [9.999] * 7)
    np.testing.assert_array_equal(fr3.dddq_max, [4999.999] * 7)
    with pytest.raises(ValueError, match="fr3"):
        robot.robot_spec("ur5")

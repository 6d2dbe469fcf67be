import numpy as np

from vla_common import robot as panda


def test_limits_are_consistent():
    assert len(panda.JOINT_NAMES) == panda.NUM_JOINTS == 7
    assert np.all(panda.Q_MIN < panda.Q_MAX)
    assert np.all((panda.READY_POSE > panda.Q_MIN) & (panda.READY_POSE < panda.Q_MAX))
    assert np.all(panda.DQ_MAX > 0) and np.all(panda.DDQ_MAX > 0) and np.all(panda.DDDQ_MAX > 0)

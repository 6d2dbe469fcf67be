"""contact.contact_scales: external torque -> speed factor (issue 20 item 5), no ROS."""
import math

import numpy as np
import pytest
from vla_common.robot import PANDA
from vla_panda_bridge.contact import CONTACT_SLOW, CONTACT_STOP, contact_scales

TAU_MAX = [float(x) for x in PANDA.tau_max]


def _tau(joint: int, ratio: float) -> list[float]:
    tau = [0.0] * 7
    tau[joint] = ratio * TAU_MAX[joint]
    return tau


@pytest.mark.parametrize("ratio, want", [(0.1, None), (CONTACT_SLOW, None), (0.5, 0.5), (0.69, 0.025),
                                         (CONTACT_STOP, 0.0), (3.0, 0.0)])
def test_motion_into_the_torque_slows_linearly_and_stops_before_a_reflex(ratio, want):
    target = [0.0, 0.4, 0, 0, 0, 0, 0]
    got = contact_scales(target, _tau(1, -ratio), TAU_MAX)     # the contact pushes back against +dq
    if want is None:
        assert got == {}
    else:
        assert got == {1: pytest.approx(want)}


def test_motion_that_eases_the_torque_or_stands_still_is_never_slowed():
    assert contact_scales([0, -0.4, 0, 0, 0, 0, 0], _tau(1, -0.9), TAU_MAX) == {}
    assert contact_scales([0.0] * 7, _tau(1, -0.9), TAU_MAX) == {}
    both = [-0.9 * t for t in TAU_MAX]
    assert contact_scales([0.1] * 7, both, TAU_MAX) == dict.fromkeys(range(7), 0.0)


@pytest.mark.parametrize("bad", [None, "x", [1.0, 2.0], 5.0, [math.nan] * 7, [object()] * 7])
def test_an_unusable_measurement_changes_nothing(bad):
    assert contact_scales([0.4] * 7, bad, TAU_MAX) == {}


def test_a_missing_joint_is_skipped_and_the_rest_judged():
    tau = _tau(3, -0.5)
    tau[1] = math.nan
    assert contact_scales([0.4] * 7, np.array(tau), TAU_MAX) == {3: pytest.approx(0.5)}

"""contact.contact_scales: external torque -> speed factor (issue 20 item 5), no ROS."""
import math

import numpy as np
import pytest
from vla_common.robot import PANDA
from vla_panda_bridge.contact import (
    CONTACT_RELEASE,
    CONTACT_SLOW,
    CONTACT_STOP,
    ContactMemory,
    contact_scales,
)
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

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
    assert contact_scales([0, 0, 0, 0.4, 0, 0, 0], np.array(tau), TAU_MAX) == {3: pytest.approx(0.5)}
    # every joint moving: the hand as a whole pushes into the contact, so all of them slow
    assert contact_scales([0.4] * 7, np.array(tau), TAU_MAX) == dict.fromkeys(range(7), pytest.approx(0.5))


def test_joints_that_push_the_hand_into_a_contact_felt_at_another_joint_are_slowed_too():
    """One contact point: tau = J^T F. Joints 2 and 4 drive the hand down against the table while the
    torque shows on the wrist (joint 6): the whole command slows; lifting the hand does not."""
    rng = np.random.default_rng(4)
    jac = rng.normal(size=(3, 7))
    force = np.array([0.0, 0.0, 1.0])                          # the table pushes the hand up
    tau = jac.T @ force
    tau *= 0.5 * TAU_MAX[5] / abs(tau[5])                       # the wrist at half its tau_max
    assert max(abs(t) / m for t, m in zip(tau, TAU_MAX)) == pytest.approx(0.5)
    down = np.linalg.pinv(jac) @ np.array([0.0, 0.0, -0.2])     # the hand moved down into the table
    assert float(tau @ down) < 0.0
    got = contact_scales(down.tolist(), tau, TAU_MAX)
    assert set(got) == {i for i in range(7) if down[i] != 0.0}
    assert max(got.values()) == pytest.approx(0.5)              # (0.7 - 0.5) / (0.7 - 0.3)
    up = -down                                                  # backing out: only the per-joint rule
    assert float(tau @ up) > 0.0
    per_joint = {i for i in range(7) if abs(tau[i]) / TAU_MAX[i] > CONTACT_SLOW and up[i] * tau[i] < 0}
    assert set(contact_scales(up.tolist(), tau, TAU_MAX)) == per_joint


def test_the_memory_follows_a_rise_at_once_and_lets_go_with_its_time_constant():
    mem = ContactMemory()
    assert mem.update(_tau(1, -0.1), 0.002) == _tau(1, -0.1)
    assert mem.update(_tau(1, -0.6), 0.002) == _tau(1, -0.6)            # a rise: at once
    got = mem.update(_tau(1, 0.0), 0.1)                                 # a fall: decays
    assert got[1] == pytest.approx(-0.6 * TAU_MAX[1] * math.exp(-0.1 / CONTACT_RELEASE))
    for _ in range(400):
        got = mem.update(_tau(1, 0.0), 0.01)
    assert abs(got[1]) < 1e-3                                           # ... to nothing
    mem.clear()
    assert mem.update(_tau(2, 0.2), 0.002) == _tau(2, 0.2)


@pytest.mark.parametrize("bad", [None, "x", 5.0, [object()] * 7])
def test_the_memory_ignores_an_unusable_measurement(bad):
    mem = ContactMemory()
    mem.update(_tau(1, -0.5), 0.002)
    assert mem.update(bad, 0.002) is None
    assert mem.update(_tau(1, 0.0), 0.0)[1] == pytest.approx(-0.5 * TAU_MAX[1])   # kept


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan])
def test_a_non_finite_sample_is_unknown_not_a_torque_that_lasts_forever(bad):
    mem = ContactMemory()
    tau = _tau(1, 0.0)
    tau[1] = bad
    assert math.isnan(mem.update(tau, 0.002)[1])
    assert mem.update(_tau(1, -0.1), 0.002) == _tau(1, -0.1)            # the next sample counts


def test_a_bouncing_contact_keeps_the_arm_slowed_between_its_hits():
    """A full stick into a loaf: the torque swung between ~0.1 and ~1 of the real arm's reflex
    torque at ~50 Hz. Judged sample by sample the slowing let go between hits and the speed came
    back (the next hit harder); judged on the recent peak the joint stays slow throughout."""
    f = SafetyFilter(SafetyConfig(dt=0.002))
    f.reset([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0])
    push = [0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0]
    f.filter([0.0] * 7, None, 0.0)                                      # armed at rest
    speeds = []
    q = [0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0]
    for k in range(1, 400):                                             # 0.8 s
        hit = k >= 100 and (k // 5) % 2 == 0                            # 10 ms on, 10 ms off
        tau = _tau(1, -0.65 if hit else -0.05) if k >= 100 else None
        dq, _, _ = f.filter(push, q, k * 0.002, tau)
        q = [a + 0.002 * b for a, b in zip(q, dq)]
        speeds.append(float(dq[1]))
    free = max(speeds[:100])
    after = speeds[150:]                                                # 0.1 s into the bouncing
    assert free == pytest.approx(0.3, abs=1e-6)
    # 0.65 of the reflex judged throughout gives (0.7 - 0.65) / 0.4 = 12.5 % speed; the decayed
    # peak between hits (10 ms, exp(-0.01 / 0.25) = 0.96) allows at most ~20 %.
    assert max(after) < 0.25 * free

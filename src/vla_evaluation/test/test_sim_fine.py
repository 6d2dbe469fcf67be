"""The simulated operator's fine alignment: where the latent's path stops short, the hand reaches the
point in end-effector mode, over the object first when it is beside it, one axis at a time, slowing
as it arrives; the axis button is pressed until the controller shows the wanted axis, never a flood."""
import math

import numpy as np
import pytest
from vla_evaluation.sim_fine import (
    CLEARANCE,
    MAX_SPEED,
    MIN_SPEED,
    PRESS_INTERVAL,
    TOLERANCE,
    FineAlign,
    stick_for,
)

CYCLE = ("x", "y", "z", "roll", "pitch", "yaw")   # the controller's default ee_axes


class FakeEndEffector:
    """The controller's end-effector mode as the operator sees it: an axis cycled by the button, the
    stick past the deadband moving the TCP along it at `speed` m/s at full stick."""

    def __init__(self, tcp, deadband=0.1, speed=0.2):
        self.tcp, self.deadband, self.speed, self.axis = np.array(tcp, float), deadband, speed, 0
        self.path = [self.tcp.copy()]

    def run(self, fine: FineAlign, dt=0.01, limit=30.0):
        t = 0.0
        while t < limit:
            s = fine.step(t, self.tcp, CYCLE[self.axis])
            if s.done:
                return t
            if s.press_axis_button:
                self.axis = (self.axis + 1) % len(CYCLE)
            u = s.axis_value
            if abs(u) > self.deadband and CYCLE[self.axis] in "xyz":
                v = np.sign(u) * (abs(u) - self.deadband) / (1 - self.deadband) * self.speed
                self.tcp["xyz".index(CYCLE[self.axis])] += v * dt
            self.path.append(self.tcp.copy())
            t += dt
        return None


def test_from_beside_the_object_it_rises_over_it_then_moves_across_then_down():
    goal = np.array([0.5, 0.0, 0.087])
    arm = FakeEndEffector(goal + [-0.03, 0.04, 0.0])         # 5 cm short, at grasp height
    t = arm.run(FineAlign(goal, arm.tcp))
    assert t is not None and t < 10.0
    assert np.all(np.abs(arm.tcp - goal) <= TOLERANCE)
    path = np.array(arm.path)
    across = np.linalg.norm(path[:, :2] - goal[:2], axis=1) > 0.015
    # it went up by the clearance before moving sideways, and never below the point while beside it
    first_side = np.argmax(np.abs(np.diff(path[:, :2], axis=0)).sum(1) > 0)
    assert path[first_side, 2] >= goal[2] + CLEARANCE - TOLERANCE
    assert np.all(path[across, 2] >= goal[2] - TOLERANCE)


def test_above_the_object_it_goes_straight_across_and_down():
    goal = np.array([0.5, 0.0, 0.087])
    arm = FakeEndEffector(goal + [0.005, -0.01, 0.03])
    assert arm.run(FineAlign(goal, arm.tcp)) is not None
    assert np.max(np.array(arm.path)[:, 2]) <= goal[2] + 0.03 + 1e-9   # no detour upwards


def test_the_stick_slows_as_the_hand_arrives_and_stays_past_the_deadband():
    db = 0.1
    assert stick_for(1.0, db) == pytest.approx(db + MAX_SPEED * (1 - db))
    assert stick_for(-0.001, db) == pytest.approx(-(db + MIN_SPEED * (1 - db)))
    assert abs(stick_for(0.01, db)) < abs(stick_for(0.03, db)) < abs(stick_for(0.2, db))
    assert all(abs(stick_for(e, db)) > db for e in (1e-4, 0.01, -0.3))


def test_presses_the_axis_button_until_the_wanted_axis_never_faster_than_the_interval():
    fine = FineAlign([0.5, 0.0, 0.2], [0.5, 0.0, 0.1])    # only z to move (above: no clearance)
    steps = [fine.step(t, np.array([0.5, 0.0, 0.1]), "x") for t in np.arange(0.0, 2.0, 0.01)]
    presses = [s for s in steps if s.press_axis_button]
    assert len(presses) == math.ceil(2.0 / PRESS_INTERVAL - 1e-9)   # one at 0, then every interval
    assert all(s.axis_value == 0.0 for s in steps)       # the stick rests on the wrong axis
    s = fine.step(2.0, np.array([0.5, 0.0, 0.1]), "z")
    assert s.axis_value > 0 and not s.press_axis_button


def test_bad_input_rests_the_stick_and_is_refused_at_the_start():
    fine = FineAlign([0.5, 0.0, 0.2], [0.5, 0.0, 0.1])
    s = fine.step(0.0, np.array([np.nan, 0.0, 0.1]), "z")
    assert s.axis_value == 0.0 and not s.press_axis_button and not s.done
    with pytest.raises(ValueError):
        FineAlign([0.5, np.inf, 0.2], [0.5, 0.0, 0.1])

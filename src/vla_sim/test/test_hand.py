"""The simulated Franka Hand: the fingers open and close at the commanded speed, squeeze with at most
the commanded force, and a grasped object lifts and stays in the hand while the arm carries it,
the arm's measured motion inside the Panda's limit table (finite differences of q at 1 kHz, as
test_arm_limits measures it).
"""
import math

import numpy as np
import pytest
from vla_common.kinematics import PandaKinematics
from vla_common.robot import DDQ_MAX, DQ_MAX, HAND
from vla_sim.planner import DOWN
from vla_sim.sim import PandaSim

safety = pytest.importorskip("vla_panda_bridge.safety")

DT = 0.001
CAN = ("soda_can", 0.5, 0.0, 0.0)


@pytest.fixture(scope="module")
def sim():
    s = PandaSim(render=False, physics_dt=DT)
    yield s
    s.close()


@pytest.fixture(scope="module")
def kin():
    return PandaKinematics()


class Driver:
    """The arm through the bridge's SafetyFilter at 1 kHz along min-jerk joint segments to IK goals;
    records q after every physics step and the object's pose."""

    def __init__(self, sim, kin):
        self.sim, self.kin = sim, kin
        self.filter = safety.SafetyFilter(safety.SafetyConfig(dt=DT))
        self.filter.reset(sim.q_target)
        self.qs = [sim.q]

    def _step(self, cmd):
        dq, _code, _text = self.filter.filter(cmd, self.sim.q_target, self.sim.time)
        self.sim.set_velocity_command(dq)
        self.sim.step(1)
        self.qs.append(self.sim.q)

    def move(self, pos, duration):
        q0 = self.sim.q_target
        goal, ok = self.kin.ik(pos, DOWN, q0)
        assert ok, pos
        n = int(round(duration / DT))
        for k in range(n):
            t = (k + 1) / n
            ds = 30 * t * t * (1 - t) ** 2 / duration
            ref = q0 + (t ** 3 * (10 - 15 * t + 6 * t * t)) * (goal - q0)
            self._step(ds * (goal - q0) + 5.0 * (ref - self.sim.q_target))

    def hold(self, seconds):
        for _ in range(int(round(seconds / DT))):
            self._step(np.zeros(7))

    def measured(self):
        q = np.array(self.qs)
        v = np.diff(q, axis=0) / DT
        return v, np.diff(v, axis=0) / DT


def can(sim):
    return next(o for o in sim.object_poses() if o.class_id == "soda_can")


def test_fingers_follow_the_command(sim):
    sim.reset(objects=[], hand_width=0.0)
    assert sim.hand.width == pytest.approx(0.0, abs=1e-9)
    sim.hand.command(0.08, 0.05, 20.0)
    widths = []
    for _ in range(2500):
        sim.step(1)
        widths.append(sim.hand.width)
    speed = np.diff(widths) / DT
    assert widths[-1] == pytest.approx(0.08, abs=1e-3)
    assert float(np.max(speed)) <= 0.05 * 1.2          # the servo's target moves at the speed
    j1, j2 = sim.hand.finger_positions
    assert j1 == pytest.approx(j2, abs=1e-4)           # the mimic coupling
    assert 0.0 <= j1 <= HAND.max_width / 2 + 1e-4


def test_force_is_limited(sim):
    sim.reset(objects=[], hand_width=0.0)
    sim.hand.command(0.0, 0.05, 15.0)
    sim.step(300)
    assert max(abs(f) for f in sim.hand.finger_forces) <= 15.0 + 1e-9
    with pytest.raises(ValueError):
        sim.hand.command(0.05, 0.05, HAND.max_force * 2)
    with pytest.raises(ValueError):
        sim.hand.command(math.nan, 0.05, 10.0)
    with pytest.raises(ValueError):
        sim.hand.command(0.05, 0.5, 10.0)


def test_grasp_lift_10cm_hold_2s(sim, kin):
    """Close on the can, lift it 10 cm, hold 2 s: it stays in the hand (rises with the TCP, its offset
    from the TCP changes by < 5 mm, both fingers on it), and the measured arm motion while carrying
    it stays within the limit table."""
    sim.reset(objects=[CAN], hand_width=0.0)
    drive = Driver(sim, kin)
    grasp_z = 0.122 - 0.035          # the finger tips 3.5 cm down the can's side
    sim.hand.command(0.08, 0.08, 20.0)
    drive.move([0.5, 0.0, 0.25], 2.0)
    drive.move([0.5, 0.0, grasp_z], 2.0)
    drive.hold(0.3)
    assert sim.hand.width > 0.075
    z_table = can(sim).z
    sim.hand.command(0.0, 0.05, 30.0)
    drive.hold(1.0)
    assert sim.held_objects() == ["soda_can"]
    assert 0.060 < sim.hand.width < 0.067                # the can is 66 mm across
    offset0 = np.array(sim.tcp_pose()[0]) - np.array([can(sim).x, can(sim).y, can(sim).z])
    carry_start = len(drive.qs)
    drive.move([0.5, 0.0, grasp_z + 0.10], 2.0)
    lifted = can(sim).z - z_table
    drive.hold(2.0)
    held = can(sim).z - z_table
    offset1 = np.array(sim.tcp_pose()[0]) - np.array([can(sim).x, can(sim).y, can(sim).z])
    assert lifted > 0.095 and held > 0.095, (lifted, held)
    assert float(np.linalg.norm(offset1 - offset0)) < 0.005
    assert sim.held_objects() == ["soda_can"]
    assert sim.reflex() is None
    v, a = drive.measured()
    v, a = v[carry_start:], a[carry_start:]
    assert np.all(np.abs(v) <= DQ_MAX * (1 + 1e-9)), np.max(np.abs(v) / DQ_MAX)
    assert np.all(np.abs(a) <= DDQ_MAX * (1 + 1e-6)), np.max(np.abs(a) / DDQ_MAX)
    # opening puts it down: above the table it falls out of the hand
    sim.hand.command(0.08, 0.05, 20.0)
    drive.hold(1.5)
    assert sim.held_objects() == []
    assert can(sim).z - z_table < 0.01


def test_closed_hand_after_reset_stays_closed_when_pushed(sim):
    """The pushing tasks push with the closed hand: a reset closes it, pressed together."""
    sim.reset(objects=[CAN])
    sim.step(200)
    assert sim.hand.width == pytest.approx(0.0, abs=1e-3)   # pressed into the stops
    sim.data.xfrc_applied[sim.model.body("panda_leftfinger").id, 1] = 10.0  # pull a finger open, 10 N
    sim.step(300)
    assert sim.hand.width < 0.002
    sim.data.xfrc_applied[:] = 0.0

"""What the simulated arm does stays inside the Panda's limit table for any command stream the safety
filter passes, measured as the robot would be: finite differences of q on the physics clock (1 kHz).
Where contact forces a joint past its limits the arm reports a reflex and stops; initial poses in
collision are refused.

Tolerances: |dq| <= dq_max (1 + 1e-9) and |ddq| <= ddq_max (1 + 1e-6) — the servo follows the filter's
output to ~1e-13 rad/s, and second differences of rounded positions are off by ~1e-10 relative.
"""
import numpy as np
import pytest
from vla_common.robot import DDQ_MAX, DQ_MAX, Q_MAX, READY_POSE
from vla_sim.arm_checks import POSITION_REFLEX, TORQUE_REFLEX, VELOCITY_REFLEX
from vla_sim.sim import PandaSim

safety = pytest.importorskip("vla_panda_bridge.safety")   # the filter whose output the arm must follow

DT = 0.001
Q_START = np.array([0.0, 0.0, 0.0, -1.6, 0.0, 1.9, 0.0])   # upright: seconds of room before the table


@pytest.fixture(scope="module")
def sim():
    s = PandaSim(render=False, physics_dt=DT)
    yield s
    s.close()


def _garbage(rng, n):
    out = []
    for _ in range(n):
        r = rng.random()
        if r < 0.6:
            out.append(None)
        elif r < 0.7:
            out.append(rng.choice([1e9, -1e9, 1e308, -1e308]) * np.sign(rng.normal(size=7)))
        elif r < 0.75:
            out.append([np.nan] * 7)
        elif r < 0.8:
            out.append([0.1] * 3)
        else:
            out.append(rng.normal(0, 3.0, 7))
    return out


def _random(rng, n):
    return [rng.uniform(-1, 1, 7) * DQ_MAX if rng.random() < 0.2 else None for _ in range(n)]


def _alternating(rng, n, period):
    base = DQ_MAX * np.sign(rng.normal(size=7))
    return [base * (1 if (k // period) % 2 else -1) for k in range(n)]


def _strokes(rng, n):
    """Full-stick strokes as the controller sends them: a 1.5 rad/s-norm direction at 50 Hz, held
    for 0.4 s, released, reversed."""
    out, d = [], np.zeros(7)
    for k in range(n):
        if k % 400 == 0:
            d = rng.normal(size=7)
            d *= 1.5 / np.linalg.norm(d)
            d /= max(1.0, float(np.max(np.abs(d) / DQ_MAX)))
            d *= (0.0, 1.0, -1.0)[(k // 400) % 3]
        out.append(d if k % 20 == 0 else None)
    return out


STREAMS = {
    "garbage": lambda rng: _garbage(rng, 3000),
    "random": lambda rng: _random(rng, 3000),
    "alternating every period": lambda rng: _alternating(rng, 1000, 1),
    "alternating every 25 ms": lambda rng: _alternating(rng, 3000, 25),
    "full-stick strokes": lambda rng: _strokes(rng, 3000),
}


def _drive(sim, commands, q0=Q_START):
    """Commands through the filter into the simulator at 1 kHz; q after every physics step, the
    filter's outputs, whether any robot link touched something, the first reflex."""
    f = safety.SafetyFilter(safety.SafetyConfig(dt=DT))
    sim.reset(seed=0, q0=q0)
    f.reset(sim.q_target)
    m = sim.model
    robot = {b for b in range(m.nbody) if m.body(b).name.startswith("panda_")}
    qs, outs, touched = [sim.q], [], False
    for k, cmd in enumerate(commands):
        dq, _, _ = f.filter(cmd, sim.q_target if k % 5 == 0 else None, sim.time)
        sim.set_velocity_command(dq)
        sim.step(1)
        qs.append(sim.q)
        outs.append(dq)
        d = sim.data
        touched |= any(m.geom_bodyid[c.geom1] in robot or m.geom_bodyid[c.geom2] in robot
                       for c in d.contact[:d.ncon])
    return np.array(qs), np.array(outs), touched


def _measured_ratios(qs):
    v = np.diff(qs, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    return np.max(np.abs(v) / DQ_MAX), np.max(np.abs(a) / DDQ_MAX), v


@pytest.mark.parametrize("stream", list(STREAMS))
@pytest.mark.parametrize("seed", [0, 1])
def test_measured_motion_stays_inside_the_table_for_any_filtered_stream(sim, stream, seed):
    qs, outs, touched = _drive(sim, STREAMS[stream](np.random.default_rng(seed)))
    assert not touched, "the stream must stay in free motion to test the servo"
    rv, ra, v = _measured_ratios(qs)
    assert rv <= 1 + 1e-9 and ra <= 1 + 1e-6, (rv, ra)
    if sim.torque_limited_steps == 0:                     # the servo follows the filter exactly
        np.testing.assert_allclose(v, outs, rtol=0, atol=1e-9)
    assert sim.reflex() is None


def test_where_the_torque_limits_cannot_give_the_acceleration_it_is_scaled_not_overshot(sim):
    """Every joint reversing at its table limits with the arm leaning out needs more than the Panda's
    torques: the arm lags (its acceleration scaled as a whole) and catches up within the table."""
    base = DQ_MAX * np.array([1, -1, 1, 1, 1, -1, 1.0])
    commands = [base * (1 if (k // 60) % 2 else -1) for k in range(1500)]
    sim.torque_limited_steps = 0
    qs, outs, touched = _drive(sim, commands, q0=np.array([0.0, 0.5, 0.0, -1.0, 0.0, 1.9, 0.0]))
    assert not touched and sim.torque_limited_steps > 100
    rv, ra, v = _measured_ratios(qs)
    assert rv <= 1 + 1e-9 and ra <= 1 + 1e-6, (rv, ra)
    assert np.abs(v - outs).max() > 1e-3                  # it did lag the command


def test_contact_that_forces_a_joint_past_its_limits_is_a_reflex_and_the_arm_stops(sim):
    """Full speed down into the table (joint 2 forward): a libfranka-like reflex, then hold() stops it."""
    f = safety.SafetyFilter(safety.SafetyConfig(dt=DT))
    q0 = READY_POSE.copy()
    q0[3] = -1.2
    sim.reset(seed=0, q0=q0)
    f.reset(sim.q_target)
    cmd = np.zeros(7)
    cmd[1] = DQ_MAX[1]
    text = None
    for k in range(3000):
        dq, _, _ = f.filter(cmd, sim.q_target if k % 5 == 0 else None, sim.time)
        sim.set_velocity_command(dq)
        sim.step(1)
        text = sim.reflex()
        if text:
            break
    assert text and text.split(":")[0] in (TORQUE_REFLEX, VELOCITY_REFLEX, POSITION_REFLEX), text
    assert "panda_joint" in text
    sim.hold()
    sim.step(1000)                                       # it bounces off the table, then rests there
    p0 = sim.tcp_pose()[0]
    sim.step(500)
    assert np.abs(sim.dq).max() < 0.01
    assert np.linalg.norm(sim.tcp_pose()[0] - p0) < 1e-3
    assert sim.reflex() == text                          # latched until cleared
    sim.clear_reflex()
    sim.step(10)
    assert sim.reflex() is None


def test_past_a_position_limit_only_motion_further_out_is_a_reflex(sim):
    sim.reset(seed=0, q0=READY_POSE)
    q = sim.data.qpos
    q[5] = Q_MAX[5] + 0.01                               # joint 6 pushed past its limit
    sim.data.qvel[5] = -0.1                              # moving back in: no reflex
    sim.hold()
    sim.step(1)
    assert sim.reflex() is None
    sim.reset(seed=0, q0=READY_POSE)
    sim.data.qpos[5] = Q_MAX[5] + 0.01
    sim.data.qvel[5] = 0.5                               # further out: a reflex
    sim.step(1)
    assert sim.reflex().startswith(POSITION_REFLEX) and "panda_joint6" in sim.reflex()


@pytest.mark.parametrize("q0,pair", [
    ([0.0, 1.4, 0.0, -1.0, 0.0, 1.5708, 0.7854], "with table_top"),
    ([0.959, -0.236, 0.861, -3.05, 0.907, 0.645, -0.47], "panda_link2 with panda_link7"),
])
def test_initial_positions_in_collision_are_refused_and_the_scene_is_unchanged(sim, q0, pair):
    assert sim.collisions(READY_POSE) == []
    assert any(pair in c for c in sim.collisions(q0))
    before = sim.reset(seed=4)
    q_before = sim.q
    with pytest.raises(ValueError, match="collision"):
        sim.reset(seed=5, q0=q0, refuse_collisions=True)
    np.testing.assert_array_equal(sim.q, q_before)
    assert [o.class_id for o in sim.object_poses()] == [o.class_id for o in before]
    sim.reset(seed=5, q0=q0)                             # without the check: as before (callers' choice)
    np.testing.assert_allclose(sim.q, q0)

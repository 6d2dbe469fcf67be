"""The safety layer: each behaviour, and property tests with random and adversarial command streams.

The plant in these tests integrates the output exactly (q += dt * dq), as a velocity-integrating servo
target does. Limits are checked on finite differences of the output: a = diff(v)/dt, j = diff(a)/dt
(from rest). Tolerances: |v| <= V (1 + 1e-9), |a| <= A (1 + 1e-6), |j| <= J (1 + 1e-6) — the
differences of rounded floats are off by ~1e-10 relative — and positions within the margins to 1e-9 rad.
"""
import math

import numpy as np
import pytest
from vla_common.robot import DDDQ_MAX, DDQ_MAX, DQ_MAX, Q_MAX, Q_MIN, READY_POSE
from vla_common.safety_status import SafetyCode
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

from vla_panda_bridge import safety

DT = 0.001
MID = (Q_MIN + Q_MAX) / 2


def run(f: SafetyFilter, commands, q0=READY_POSE, t0=0.0):
    """Feed one command (or None) per period; return outputs (N,7), positions (N,7), codes."""
    q = np.array(q0, dtype=float)
    h = f.config.dt
    vs, qs, codes = [], [], []
    for k, cmd in enumerate(commands):
        dq, code, text = f.filter(cmd, q, t0 + k * h)
        assert isinstance(text, str) and (code == SafetyCode.OK or text)
        q = q + h * dq
        vs.append(dq)
        qs.append(q)
        codes.append(code)
    return np.array(vs), np.array(qs), np.array(codes)


def assert_within_limits(f: SafetyFilter, vs: np.ndarray, qs: np.ndarray | None = None, v0=None):
    h = f.config.dt
    v_prev = np.zeros(7) if v0 is None else v0
    acc = np.diff(vs, axis=0, prepend=v_prev[None]) / h
    jerk = np.diff(acc, axis=0, prepend=np.zeros((1, 7))) / h
    assert np.all(np.isfinite(vs))
    assert np.max(np.abs(vs) / f.v_max) <= 1 + 1e-9
    assert np.max(np.abs(acc) / f.a_max) <= 1 + 1e-6
    assert np.max(np.abs(jerk) / f.j_max) <= 1 + 1e-6
    if qs is not None:
        margin = f.config.position_margin
        assert np.all(qs >= Q_MIN + margin - 1e-9), np.min(qs - (Q_MIN + margin))
        assert np.all(qs <= Q_MAX - margin + 1e-9), np.max(qs - (Q_MAX - margin))


@pytest.mark.parametrize("field,value", [("dt", 0.0), ("dt", -1.0), ("velocity_scale", 1.5),
                                         ("acceleration_scale", 0.0), ("jerk_scale", float("nan")),
                                         ("position_margin", -0.1), ("command_timeout", 0.0)])
def test_bad_config_is_refused_with_its_name(field, value):
    with pytest.raises(ValueError, match=field):
        SafetyFilter(SafetyConfig(**{field: value}))


def test_constant_command_is_reached_exactly_after_a_limited_ramp():
    f = SafetyFilter()
    cmd = np.array([0.3, -0.2, 0.1, 0.25, -0.3, 0.2, 0.4])
    vs, _, codes = run(f, [cmd] * 300)
    assert_within_limits(f, vs)
    np.testing.assert_array_equal(vs[-1], cmd)               # lands exactly, no residual
    assert codes[-1] == SafetyCode.OK
    # Not instantaneous: the first step is bounded by the jerk limit.
    assert np.all(np.abs(vs[0]) <= DDDQ_MAX * DT * DT * (1 + 1e-9))


def test_step_to_full_speed_uses_but_never_exceeds_the_acceleration_limit():
    f = SafetyFilter()
    vs, _, codes = run(f, [DQ_MAX.copy()] * 600, q0=MID)
    acc = np.diff(vs, axis=0, prepend=np.zeros((1, 7))) / DT
    assert_within_limits(f, vs)
    np.testing.assert_allclose(np.max(np.abs(acc), axis=0), DDQ_MAX, rtol=1e-9)   # time-optimal-ish
    np.testing.assert_allclose(vs[-1], DQ_MAX, rtol=0, atol=1e-12)
    assert SafetyCode.ACCELERATION_LIMITED in codes


def test_over_limit_vector_is_scaled_uniformly_keeping_direction():
    f = SafetyFilter()
    cmd = np.array([3.9, -1.0, 0.5, 2.0, 0.0, -3.0, 1.0])   # joint 1 is 1.79x over its limit
    vs, _, codes = run(f, [cmd] * 800, q0=MID)
    ratio = np.max(np.abs(cmd) / DQ_MAX)
    np.testing.assert_allclose(vs[-1], cmd / ratio, atol=1e-12)
    assert abs(vs[-1][0]) == pytest.approx(DQ_MAX[0])
    assert codes[-1] == SafetyCode.VELOCITY_SCALED
    assert f.interventions >= 1 and f.last_intervention in (SafetyCode.VELOCITY_SCALED,
                                                              SafetyCode.ACCELERATION_LIMITED)


def test_configurable_lower_velocity_limit():
    f = SafetyFilter(SafetyConfig(velocity_scale=0.5))
    cmd = DQ_MAX * np.array([1, -1, 0.5, 0.2, 0.0, 0.1, -0.4])
    vs, _, _ = run(f, [cmd] * 800, q0=MID)
    np.testing.assert_allclose(vs[-1], cmd * 0.5, atol=1e-12)
    assert_within_limits(f, vs)


@pytest.mark.parametrize("bad", [[np.nan] * 7, [0.1, 0.2, np.inf, 0, 0, 0, 0], [0.1, -np.inf] + [0] * 5])
def test_non_finite_command_is_rejected_counted_and_treated_as_zero(bad):
    f = SafetyFilter()
    cruise = np.full(7, 0.5)
    vs, _, codes = run(f, [cruise] * 300 + [bad] + [None] * 400, q0=MID)
    assert codes[300] == SafetyCode.NON_FINITE_COMMAND
    assert f.commands_rejected == 1 and f.commands_received == 301
    assert f.last_intervention == SafetyCode.NON_FINITE_COMMAND
    assert np.all(vs[-1] == 0.0)                             # treated as zero: braked to rest
    assert np.all(np.abs(vs[301]) < 0.5)                     # braking starts at once, not at timeout
    assert_within_limits(f, vs)


@pytest.mark.parametrize("bad", [[0.1] * 6, [0.1] * 8, [], "fast", [[0.1] * 7, [0.1] * 7], [None] * 7,
                                 {"a": 1}, object()])
def test_wrong_length_or_malformed_command_is_rejected(bad):
    f = SafetyFilter()
    vs, _, codes = run(f, [np.full(7, 0.2)] * 100 + [bad] + [None] * 300, q0=MID)
    assert codes[100] in (SafetyCode.WRONG_LENGTH, SafetyCode.NON_FINITE_COMMAND)
    assert f.commands_rejected == 1
    assert np.all(vs[-1] == 0.0)
    assert_within_limits(f, vs)


def test_watchdog_brakes_after_command_timeout_within_limits():
    f = SafetyFilter(SafetyConfig(command_timeout=0.1))
    cmd = np.array([0.5, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5])
    vs, _, codes = run(f, [cmd] + [None] * 600, q0=MID)
    # Held for the timeout (100 periods), then decelerates with the limits, to exactly zero.
    np.testing.assert_array_equal(vs[99], cmd)
    assert codes[101] == SafetyCode.COMMAND_TIMEOUT
    assert np.all(np.abs(vs[102]) < np.abs(cmd))
    # At rest, the watchdog's stop holds: the same command again is ignored until a zero command.
    assert np.all(vs[-1] == 0.0) and codes[-1] == SafetyCode.AWAITING_ZERO
    assert_within_limits(f, vs)
    vs3, _, codes3 = run(f, [cmd] * 50, q0=MID, t0=1.0)
    assert np.all(vs3 == 0.0) and codes3[-1] == SafetyCode.AWAITING_ZERO
    vs4, _, _ = run(f, [np.zeros(7)] + [cmd] * 200, q0=MID, t0=2.0)
    np.testing.assert_array_equal(vs4[-1], cmd)                        # neutral, then it moves
    # A command every 50 ms keeps it alive.
    f2 = SafetyFilter(SafetyConfig(command_timeout=0.1))
    vs2, _, codes2 = run(f2, [cmd if k % 50 == 0 else None for k in range(600)], q0=MID)
    np.testing.assert_array_equal(vs2[-1], cmd)
    assert SafetyCode.COMMAND_TIMEOUT not in codes2


def test_estop_latches_zero_until_released_and_a_new_command_arrives():
    f = SafetyFilter()
    cruise = DQ_MAX * 0.5
    vs, qs, _ = run(f, [cruise] * 200, q0=MID)
    f.set_estop(True)
    assert f.estop_active
    vs2, qs2, codes = run(f, [cruise] * 300, q0=qs[-1], t0=0.2)   # commands keep coming: ignored
    assert np.all(codes == SafetyCode.ESTOP)
    assert np.all(vs2[-1] == 0.0)
    # As fast as the limits allow: about v/A plus the jerk ramps.
    stop_steps = np.argmax(np.all(vs2 == 0.0, axis=1))
    assert stop_steps * DT < np.max(cruise / DDQ_MAX + 2 * DDQ_MAX / DDDQ_MAX) + 0.01
    assert_within_limits(f, np.vstack([vs, vs2]))
    f.set_estop(False)
    vs3, _, codes3 = run(f, [None] * 50, q0=qs2[-1], t0=0.5)
    assert np.all(vs3 == 0.0)                                  # release does not resume the command
    assert np.all(codes3 == SafetyCode.AWAITING_ZERO)
    vs4, _, _ = run(f, [np.zeros(7)] + [-cruise] * 200, q0=qs2[-1], t0=0.55)
    np.testing.assert_allclose(vs4[-1], -cruise)


def test_after_an_estop_release_a_held_stick_moves_nothing_until_a_zero_command():
    f = SafetyFilter()
    stick = DQ_MAX * 0.4
    _, qs, _ = run(f, [stick] * 300, q0=MID)
    f.set_estop(True)
    _, qs, _ = run(f, [stick] * 300, q0=qs[-1], t0=0.3)
    f.set_estop(False)
    vs, qs, codes = run(f, [stick] * 500, q0=qs[-1], t0=0.6)     # the stick is still held
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.AWAITING_ZERO)
    assert f.awaiting_zero and f.commands_rejected == 0          # ignored, not rejected
    vs, _, codes = run(f, [stick * 1e-7] + [stick] * 300, q0=qs[-1], t0=1.1)   # zero within 1e-6 rad/s
    np.testing.assert_allclose(vs[-1], stick)
    assert not f.awaiting_zero and codes[-1] == SafetyCode.OK


@pytest.mark.parametrize("value", [1e9, -1e9, 1e308, -1e308, 2.0 * 2.175 * 1.0001])
def test_implausible_command_is_rejected_like_nan_not_scaled(value):
    f = SafetyFilter()
    cruise = np.full(7, 0.5)
    bad = np.zeros(7)
    bad[1] = value
    vs, _, codes = run(f, [cruise] * 300 + [bad] + [bad] * 10 + [None] * 400, q0=MID)
    assert codes[300] == SafetyCode.IMPLAUSIBLE_COMMAND
    assert f.commands_rejected == 11 and f.last_intervention == SafetyCode.IMPLAUSIBLE_COMMAND
    assert np.all(np.abs(vs[301]) < 0.5)                      # braking at once, not executing it
    assert np.all(vs[-1] == 0.0)
    assert_within_limits(f, vs)
    _, code, text = f.filter(bad, MID, 1.0)
    assert code == SafetyCode.IMPLAUSIBLE_COMMAND and "panda_joint2" in text and "2x" in text


def test_a_command_at_the_plausibility_bound_is_scaled():
    f = SafetyFilter(SafetyConfig(plausibility_factor=2.0))
    cmd = np.zeros(7)
    cmd[1] = 2.0 * DQ_MAX[1]
    vs, _, codes = run(f, [cmd] * 400, q0=MID)
    assert f.commands_rejected == 0 and codes[-1] == SafetyCode.VELOCITY_SCALED
    np.testing.assert_allclose(vs[-1][1], DQ_MAX[1])


def test_a_reflex_holds_zero_until_cleared_and_then_needs_a_zero_command():
    f = SafetyFilter()
    cruise = DQ_MAX * 0.3
    _, qs, _ = run(f, [cruise] * 200, q0=MID)
    f.reset(qs[-1])                                            # the robot stopped itself
    f.set_fault("joint_velocity_violation: panda_joint2")
    vs, qs, codes = run(f, [cruise] * 200, q0=qs[-1], t0=0.2)
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.REFLEX)
    assert f.last_intervention == SafetyCode.REFLEX and f.holding
    assert f.clear_fault() and not f.clear_fault()
    vs, qs, codes = run(f, [cruise] * 100, q0=qs[-1], t0=0.4)   # recovery never starts motion itself
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.AWAITING_ZERO)
    vs, _, _ = run(f, [np.zeros(7)] + [cruise] * 300, q0=qs[-1], t0=0.5)
    np.testing.assert_allclose(vs[-1], cruise)


def test_position_margin_stops_at_the_margin_and_allows_motion_away():
    f = SafetyFilter()
    toward = DQ_MAX.copy()
    vs, qs, codes = run(f, [toward] * 3000, q0=MID)
    hi = Q_MAX - 0.1
    assert_within_limits(f, vs, qs)
    assert np.all(vs[-1] == 0.0)
    np.testing.assert_allclose(qs[-1], hi, atol=1e-3)        # stops at the margin, not short of it
    assert codes[-1] == SafetyCode.POSITION_MARGIN
    # Away from the limit: free, immediately.
    vs2, qs2, _ = run(f, [-toward * 0.5] * 500, q0=qs[-1], t0=3.0)
    np.testing.assert_allclose(vs2[-1], -toward * 0.5)
    assert np.all(qs2[-1] < hi - 0.1)
    assert_within_limits(f, np.vstack([vs, vs2]), np.vstack([qs, qs2]))


def test_start_outside_the_margin_blocks_motion_toward_the_limit_only():
    f = SafetyFilter()
    q0 = MID.copy()
    q0[3] = Q_MAX[3] - 0.03                                   # inside the 0.1 rad margin
    toward = np.zeros(7)
    toward[3] = 1.0
    vs, qs, codes = run(f, [toward] * 200, q0=q0)
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.POSITION_MARGIN)
    vs2, qs2, _ = run(f, [-toward] * 400, q0=q0)
    assert vs2[-1][3] == -1.0 and qs2[-1][3] < q0[3] - 0.1


def test_measured_position_drift_resyncs_the_reference():
    f = SafetyFilter(SafetyConfig(position_sync_tolerance=0.05))
    f.filter(np.full(7, 0.1), MID, 0.0)
    f.filter(None, MID + 0.2, 0.001)                          # the robot is not where we integrated
    np.testing.assert_allclose(f.reference_position, MID + 0.2 + DT * f.velocity)
    assert f.resyncs == 1


def test_missing_or_invalid_measured_position():
    f = SafetyFilter()
    dq, code, _ = f.filter(np.full(7, 0.3), None, 0.0)       # never measured: cannot check limits
    assert code == SafetyCode.INVALID_STATE and np.all(dq == 0.0)
    vs, qs, _ = run(f, [np.full(7, 0.3)] * 100, q0=MID)
    # None = no new measurement: the integrated reference carries on.
    vs2 = [f.filter(None, None, 0.1 + k * DT)[0] for k in range(20)]
    np.testing.assert_array_equal(vs2[-1], np.full(7, 0.3))
    # An invalid measurement brakes (within the limits) and says why.
    out = [f.filter(None, [np.nan] * 7, 0.12 + k * DT) for k in range(300)]
    assert all(c == SafetyCode.INVALID_STATE for _, c, _ in out[:5])
    assert np.all(out[-1][0] == 0.0)
    assert_within_limits(f, np.vstack([vs, vs2, [o[0] for o in out]]))


def test_never_raises_on_garbage_state_or_clock():
    f = SafetyFilter()
    for q in (None, [np.nan] * 7, [1, 2], "q", READY_POSE):
        for now in (0.0, float("nan"), None, "t", 1e300):
            dq, code, text = f.filter(np.full(7, 0.1), q, now)
            assert dq.shape == (7,) and np.all(np.isfinite(dq))
    # With a bad clock the watchdog treats every command as expired.
    f2 = SafetyFilter()
    vs, _, codes = run(f2, [np.full(7, 0.1)] * 5, q0=MID)
    dq, code, _ = f2.filter(None, MID, float("nan"))
    assert code == SafetyCode.COMMAND_TIMEOUT


def test_excursion_bound_covers_simulated_braking():
    """The lemma the position guarantee rests on: braking from (v, a) travels no further than the bound."""
    rng = np.random.default_rng(7)
    for dt in (0.0005, 0.001, 0.002):
        f = SafetyFilter(SafetyConfig(dt=dt, acceleration_scale=0.7, jerk_scale=0.3))
        for _ in range(400):
            i = int(rng.integers(7))
            _, A, J, D, _, _, tail, _, _, _ = f._lim[i]
            v = rng.uniform(-1, 1) * DQ_MAX[i] * (0.02 if rng.random() < 0.3 else 1.0)
            a = rng.uniform(-A, A)
            bound = safety._excursion_bound(v, a, dt, A, D, tail)
            pos = peak = 0.0
            vv, aa = v, a
            for _ in range(100000):
                vv, aa = safety._track(vv, aa, 0.0, dt, A, J, D)
                pos += dt * vv
                peak = max(peak, pos)
                if vv == 0.0 and aa == 0.0:
                    break
            assert vv == 0.0 and aa == 0.0                     # it always comes to rest
            assert peak <= bound + 1e-12


def _adversarial_stream(rng: np.random.Generator, n: int, bias_to_limits: bool):
    """Segments of: random vectors, +/-huge steps (1e9: rejected; 1.9x the limit: scaled), sign flips
    every period, NaN bursts, wrong lengths, dropouts longer than the timeout, and (optionally)
    full-speed pushes into the position limits."""
    out = []
    while len(out) < n:
        kind = rng.integers(8 if bias_to_limits else 7)
        length = int(rng.integers(1, 400))
        if kind == 0:
            out += [rng.normal(0, 2, 7)] * length
        elif kind == 1:
            out += [rng.choice([-1.0, 1.0], 7) * (1e9 if rng.random() < 0.5 else DQ_MAX * 1.9)] * length
        elif kind == 2:
            base = rng.uniform(-3, 3, 7)
            out += [base * (-1) ** k for k in range(length)]
        elif kind == 3:
            out += [np.where(rng.random(7) < 0.5, np.nan, 1.0) for _ in range(length)]
        elif kind == 4:
            out += [list(rng.normal(size=int(rng.integers(0, 12)))) for _ in range(min(length, 20))]
        elif kind == 5:
            out += [None] * length
        elif kind == 6:
            out += [rng.normal(0, 2, 7) if rng.random() < 0.1 else None for _ in range(length)]
        else:
            out += [np.sign(rng.normal(size=7)) * DQ_MAX * 2] * (length * 3)
    return out[:n]


@pytest.mark.parametrize("seed", range(4))
def test_random_and_adversarial_streams_stay_within_all_limits(seed):
    rng = np.random.default_rng(seed)
    cfg = [SafetyConfig(), SafetyConfig(dt=0.002, velocity_scale=0.6),
           SafetyConfig(acceleration_scale=0.5, jerk_scale=0.1, position_margin=0.2),
           SafetyConfig(dt=0.0005, command_timeout=0.02)][seed]
    f = SafetyFilter(cfg)
    q0 = READY_POSE + rng.uniform(-0.3, 0.3, 7)
    vs, qs, codes = run(f, _adversarial_stream(rng, 6000, bias_to_limits=True), q0=q0)
    assert_within_limits(f, vs, qs)
    assert f.commands_rejected > 0
    assert SafetyCode.POSITION_MARGIN in codes                     # the stream did reach the limits
    # And whatever the state, an e-stop brings it to rest in bounded time.
    f.set_estop(True)
    n_stop = int(math.ceil(f.stopping_time_bound() / cfg.dt))
    vs2, qs2, _ = run(f, [None] * n_stop, q0=qs[-1], t0=len(vs) * cfg.dt)
    assert np.all(vs2[-1] == 0.0)
    assert_within_limits(f, np.vstack([vs, vs2]), np.vstack([qs, qs2]))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4, 12))
def test_long_adversarial_streams(seed):
    rng = np.random.default_rng(seed)
    f = SafetyFilter(SafetyConfig(velocity_scale=float(rng.uniform(0.2, 1.0)),
                                  acceleration_scale=float(rng.uniform(0.2, 1.0)),
                                  jerk_scale=float(rng.uniform(0.05, 1.0))))
    q0 = np.clip(READY_POSE + rng.uniform(-1, 1, 7), Q_MIN + 0.1, Q_MAX - 0.1)
    vs, qs, _ = run(f, _adversarial_stream(rng, 20000, bias_to_limits=bool(seed % 2)), q0=q0)
    assert_within_limits(f, vs, qs)


def test_hard_position_check_alone_holds_the_margin(monkeypatch):
    """The soft cap only smooths the approach; the braking-distance check is what guarantees it."""
    monkeypatch.setattr(safety, "_cap", lambda *args: math.inf)
    rng = np.random.default_rng(3)
    f = SafetyFilter()
    vs, qs, codes = run(f, [DQ_MAX.copy()] * 1500 + _adversarial_stream(rng, 3000, True), q0=MID)
    assert_within_limits(f, vs, qs)
    assert np.any(qs[:1500] > Q_MAX - 0.1 - 1e-3, axis=0).all()    # it went right up to the margin


def test_teaching_mode_ignores_commands_and_leaving_it_needs_a_zero_command():
    f = SafetyFilter()
    _, qs, _ = run(f, [None] * 10, q0=MID)
    f.set_teaching(True)
    assert f.teaching and f.holding
    vs, _, codes = run(f, [np.full(7, 0.3)] * 100, q0=MID + 0.01)   # the hand moves the arm
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.TEACHING)
    np.testing.assert_allclose(f.reference_position, MID + 0.01)     # follows the measured position
    f.set_teaching(False)
    vs, _, codes = run(f, [np.full(7, 0.3)] * 50, q0=MID + 0.01, t0=0.2)
    assert np.all(vs == 0.0) and np.all(codes == SafetyCode.AWAITING_ZERO)
    vs, _, _ = run(f, [np.zeros(7)] + [np.full(7, 0.3)] * 200, q0=MID + 0.01, t0=0.3)
    np.testing.assert_allclose(vs[-1], 0.3)


def test_the_filter_enforces_the_robot_it_drives():
    from vla_common.robot import FR3

    f = SafetyFilter(robot=FR3)
    cmd = np.zeros(7)
    cmd[4] = 4.0                                               # within the FR3's 5.26, over the Panda's 2.61
    mid = (FR3.q_min + FR3.q_max) / 2
    vs, _, codes = run(f, [cmd] * 600, q0=mid)
    np.testing.assert_allclose(vs[-1], cmd)
    assert_within_limits(f, vs)
    np.testing.assert_allclose(f.a_max, FR3.ddq_max)
    cmd[5] = 9.0                                               # beyond 2x the FR3's 4.18: rejected
    _, code, text = f.filter(cmd, mid, 1.0)
    assert code == SafetyCode.IMPLAUSIBLE_COMMAND and "fr3_joint6" in text
    q0 = mid.copy()
    q0[5] = FR3.q_min[5] + 0.05                                # inside the FR3's margin (0.5445 + 0.1)
    toward = np.zeros(7)
    toward[5] = -1.0
    vs, _, codes = run(safety.SafetyFilter(robot=FR3), [toward] * 100, q0=q0)
    assert np.all(vs == 0.0) and codes[-1] == SafetyCode.POSITION_MARGIN


def test_motion_into_a_rising_external_torque_slows_and_stops_before_a_reflex():
    """Issue 20 item 5: a held stick drove the hand into the loaf until a reflex (87-249 Nm). Where the
    backend measures an external torque, a joint commanded further into it slows from 0.3 x tau_max
    and stops at 0.7 x; a command that eases it is never slowed, so the operator can back out."""
    tau_max = safety.PANDA.tau_max
    cmd = np.zeros(7)
    cmd[1] = 0.5
    for ratio, want in ((0.1, 0.5), (0.5, 0.25), (0.8, 0.0)):
        f = SafetyFilter()
        tau = np.zeros(7)
        tau[1] = -ratio * tau_max[1]                     # the contact pushes back against +dq
        q, code = MID.copy(), SafetyCode.OK
        for k in range(1500):
            dq, code, text = f.filter(cmd if k == 0 or k % 50 == 0 else None, q, k * DT, tau)
            q = q + DT * dq
        assert dq[1] == pytest.approx(want, abs=1e-9), (ratio, dq[1])
        assert code == (SafetyCode.CONTACT if ratio > 0.3 else SafetyCode.OK), (ratio, code, text)
        if ratio > 0.3:
            assert "panda_joint2" in text and "external torque" in text
    back = SafetyFilter()                                 # backing out of the same contact: full speed
    tau = np.zeros(7)
    tau[1] = -0.8 * tau_max[1]
    q = MID.copy()
    for k in range(1500):
        dq, code, _ = back.filter(-cmd if k % 50 == 0 else None, q, k * DT, tau)
        q = q + DT * dq
    assert dq[1] == pytest.approx(-0.5) and code == SafetyCode.OK
    garbage = SafetyFilter()                              # an unusable measurement changes nothing
    for bad in (None, [1.0, 2.0], "x", [np.nan] * 7):
        dq, code, _ = garbage.filter(cmd, MID, 0.0, bad)
        assert np.all(np.isfinite(dq)) and code != SafetyCode.CONTACT


def test_contact_thresholds_are_fractions_of_the_reflex_table_the_filter_is_given():
    """A real Franka's reflex fires at its configured collision thresholds (libfranka's
    upper_torque_thresholds, 20 Nm on joint 2), far below tau_max (87 Nm): the contact slowing must act
    below them. 15 Nm against joint 2's motion is 0.17 x tau_max (nothing slows) but 0.75 x 20 Nm."""
    reflex = [20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0]
    cmd = np.zeros(7)
    cmd[1] = 0.5
    tau = np.zeros(7)
    tau[1] = -15.0
    for f, want in ((SafetyFilter(), 0.5), (SafetyFilter(reflex_torque=reflex), 0.0)):
        q = MID.copy()
        for k in range(1500):
            dq, code, _ = f.filter(cmd if k % 50 == 0 else None, q, k * DT, tau)
            q = q + DT * dq
        assert dq[1] == pytest.approx(want, abs=1e-9)
    assert code == SafetyCode.CONTACT
    assert SafetyFilter().reflex_torque == [float(x) for x in safety.PANDA.tau_max]   # the default
    for bad in ([20.0] * 6, [20.0] * 6 + [0.0], [20.0] * 6 + [math.nan]):
        with pytest.raises(ValueError, match="reflex_torque"):
            SafetyFilter(reflex_torque=bad)

"""The safety layer between any joint-velocity command and the arm (plain NumPy, no ROS).

Every backend (MuJoCo, ros2_control) runs each command through one `SafetyFilter`, once per control
period `dt`. The filter turns an arbitrary, possibly malformed stream of 7-value velocity commands into
a velocity output that is continuous, within the robot's velocity/acceleration/jerk table (a
`vla_common.robot.RobotSpec`, the Panda's by default), stays clear of the position limits, and comes
to rest when commands stop, on e-stop, on a reflex of the robot and on shutdown.

Pipeline per control period:
  1. validation: a new command with the wrong length, a NaN/Inf, or a value beyond
     `plausibility_factor` times the joint's dq_max (1e9 rad/s is a fault, not "full speed") is
     rejected (counted, reported, treated as zero);
  2. velocity scaling: a vector over the velocity limit is scaled uniformly by the worst joint's
     ratio, so its direction is kept;
  3. watchdog / holds: no valid command for `command_timeout`, or a hold — a latched e-stop, a reflex
     the robot reported (until recovered), teaching mode — sets the target to zero and ignores
     commands. Every stop the operator did not choose (e-stop, watchdog, invalid state, reflex,
     recovery, teaching; `disarm` for the backends' own) disarms the filter: motion then needs a zero
     command first (`vla_common.arming`, the one owner of that rule);
  4. position margin, soft part: near a limit the target towards it is capped so the joint can still
     stop at `position_margin` from the limit; motion away is never capped;
     contact, likewise: where the backend measures an external torque (a real arm's estimate, MuJoCo's
     constraint forces), a joint commanded further into it is slowed from `contact_slow` x its reflex
     torque on and stopped at `contact_stop` x, well before the robot's own reflex at 1 x (the
     reflex table `reflex_torque`: tau_max by default, where the simulated arm's reflex fires; the
     bridge gives a real arm's collision thresholds); motion that eases the torque is never slowed
     (the operator can always back out); the torque judged is the recent peak (`ContactMemory`), so
     a bouncing contact stays slowed between its hits;
     the workspace floor, likewise, where the bridge gives one (`workspace.py`): the part of the target
     that lowers the hand faster than it may go that close to the table is removed; the rest is kept;
  5. a per-joint jerk-limited tracker moves the output velocity towards the target;
  6. position margin, hard part: if the tracker's step would leave the joint unable to stop before
     the margin (by a braking-distance bound), that joint takes the braking step instead.

Guarantees (exact up to floating-point rounding; tested with random and adversarial streams):
- Tracker. With a = (v_k - v_{k-1})/dt and j = (a_k - a_{k-1})/dt, each step picks
  a' = clip(a_des, a - J dt, a + J dt) with |a_des| <= A, so |a| <= A and |j| <= J by construction.
  a_des is the largest acceleration from which the accel can still be ramped to zero at the jerk
  limit without passing the target: dt|a| + a^2/(2J) <= |v_t - v|. With G(a) the exact velocity
  gained while ramping a > 0 down to zero in steps of J dt (G(a) <= a^2/(2J)), every step keeps
  v + G(a+) <= max(v_t, previous value) (and the mirror image), so with |v_t| <= V the output never
  exceeds V. With v_t = 0 the output converges to rest (quadratically near zero): it can always stop.
- Position. `_excursion_bound(v, a)` bounds how far the joint still travels if it brakes (tracks
  zero) from (v, a): ramp steps at the peak velocity + v_pk^2/(2A) + a geometric tail. If the state
  after a step passes the check, its braking trajectory ends inside the margin; if not, the joint
  brakes, and the next state lies on a braking trajectory that already did. So once inside the
  margin, the reference position never leaves it; started outside, it never moves further out.
The reference position is the integral of the output (what a velocity-integrating servo follows),
re-synchronised to the measured position at rest and whenever they differ by more than
`position_sync_tolerance`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from vla_common.arming import Arming
from vla_common.robot import NUM_JOINTS, PANDA, RobotSpec
from vla_common.safety_status import SafetyCode as Code

from vla_panda_bridge.contact import CONTACT_SLOW, CONTACT_STOP, ContactMemory, contact_scales
from vla_panda_bridge.workspace import WorkspaceFloor

_REJECTIONS = (Code.NON_FINITE_COMMAND, Code.WRONG_LENGTH, Code.IMPLAUSIBLE_COMMAND)
_COUNTED_WHEN_ENTERED = (Code.VELOCITY_SCALED, Code.ACCELERATION_LIMITED, Code.POSITION_MARGIN,
                         Code.INVALID_STATE, Code.AWAITING_ZERO, Code.CONTACT, Code.WORKSPACE)

# The soft position cap plans the approach with this fraction of the deceleration limit, so the
# tracker follows it without leaning on the hard check (which would brake in bang-bang fashion).
_CAP_DECEL_FRACTION = 0.8
_SNAP = 1e-12  # |v_t - v| below which the output lands exactly on the target
ZERO_COMMAND = 1e-6  # rad/s: a command with every |value| at or below this counts as zero (re-arming)


@dataclass(frozen=True)
class SafetyConfig:
    """Parameters of the safety layer; limits are fractions of the robot's table (vla_common.robot)."""

    dt: float = 0.001                    # control period (s): one filter update per servo/physics step
    velocity_scale: float = 1.0          # fraction of dq_max allowed (a configurable lower max)
    acceleration_scale: float = 1.0      # fraction of ddq_max
    jerk_scale: float = 1.0              # fraction of dddq_max
    position_margin: float = 0.1         # rad kept from every position limit
    command_timeout: float = 0.1         # s without a valid command before braking to zero
    position_sync_tolerance: float = 0.05  # rad of reference-vs-measured drift that forces a re-sync
    plausibility_factor: float = 2.0     # a command beyond this times dq_max is a fault: rejected
    contact_slow: float = CONTACT_SLOW   # external torque / reflex torque from which motion into it slows
    contact_stop: float = CONTACT_STOP   # ... and at which it stops (the robot's reflex is at 1.0)

    def validate(self) -> None:
        """Raise ValueError naming the first bad value."""
        def check(name: str, value: float, lo: float, hi: float, lo_open: bool = True) -> None:
            ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
            if not ok:
                bracket = "(" if lo_open else "["
                raise ValueError(f"safety: {name}={value!r} is outside {bracket}{lo}, {hi}]")

        check("dt", self.dt, 0.0, 0.02)
        check("velocity_scale", self.velocity_scale, 0.0, 1.0)
        check("acceleration_scale", self.acceleration_scale, 0.0, 1.0)
        check("jerk_scale", self.jerk_scale, 0.0, 1.0)
        check("position_margin", self.position_margin, 0.0, 0.5, lo_open=False)
        check("command_timeout", self.command_timeout, 0.0, 10.0)
        check("position_sync_tolerance", self.position_sync_tolerance, 0.0, 1.0)
        check("plausibility_factor", self.plausibility_factor, 1.0, 100.0, lo_open=False)
        check("contact_slow", self.contact_slow, 0.0, 1.0)
        check("contact_stop", self.contact_stop, self.contact_slow, 1.0)


class SafetyFilter:
    """Per-control-period filter: `filter(cmd, q, now) -> (dq_out, code, text)`; never raises on input.

    `cmd` is the command that arrived since the previous call, or None when none did (the previous
    valid command stays the target until the watchdog expires). `q` is the measured joint position
    (None: no new measurement this period; anything but 7 finite values: invalid, brake),
    `now` the time in seconds (simulated or wall clock) used by the watchdog only; integration uses
    the fixed period `config.dt`. The per-step core works on Python floats joint by joint: for seven
    values that is several times faster than NumPy, which matters at 1 kHz.
    """

    def __init__(self, config: SafetyConfig | None = None, robot: RobotSpec = PANDA,
                 floor: WorkspaceFloor | None = None, reflex_torque: Sequence[float] | None = None):
        self.config = cfg = config or SafetyConfig()
        self.floor = floor                                  # the TCP's lowest height, where given
        cfg.validate()
        # The joint torques (Nm) at which the robot's own reflex stops it: the contact thresholds are
        # fractions of these. Default tau_max (the simulated arm's reflex); a real Franka's fires at
        # the collision thresholds it was configured with (libfranka: upper_torque_thresholds).
        reflex = [float(x) for x in (robot.tau_max if reflex_torque is None else reflex_torque)]
        if len(reflex) != NUM_JOINTS or not all(math.isfinite(x) and x > 0.0 for x in reflex):
            raise ValueError(f"safety: reflex_torque must be {NUM_JOINTS} finite values > 0, got {reflex}")
        self.reflex_torque = reflex
        self._contact = ContactMemory()                     # the recent peak torque the rule judges
        self.robot = robot
        self._names = robot.joint_names
        h = cfg.dt
        self.v_max = robot.dq_max * cfg.velocity_scale
        self.a_max = robot.ddq_max * cfg.acceleration_scale
        self.j_max = robot.dddq_max * cfg.jerk_scale
        self._plausible = robot.dq_max * cfg.plausibility_factor
        A, J = self.a_max, self.j_max
        D = J * h                                           # largest acceleration change per step
        v_star = h * A + A * A / (2 * J)                    # below it braking is on the jerk-limited curve
        tail = v_star * A / (2 * J)                         # distance covered by that geometric tail
        cap_n = np.ceil(A / D) * h                          # ramp-time term of the bound at a = 0
        cap_a = A * _CAP_DECEL_FRACTION
        # Beyond this distance from both margins neither the cap nor the check can act.
        v_pk = self.v_max + A * A / (2 * J)
        far_check = np.ceil(2 * A / D) * h * v_pk + v_pk ** 2 / (2 * A) + tail
        far_cap = cap_n * self.v_max + self.v_max ** 2 / (2 * cap_a) + tail
        far = np.maximum(far_check, far_cap) + 2 * h * self.v_max + 1e-6
        q_lo = robot.q_min + cfg.position_margin
        q_hi = robot.q_max - cfg.position_margin
        self._h = h
        # Per joint: (V, A, J, D, q_lo, q_hi, tail, cap_n, cap_a, far) as Python floats.
        self._lim = [tuple(float(x[i]) for x in (self.v_max, A, J, D, q_lo, q_hi, tail, cap_n, cap_a, far))
                     for i in range(NUM_JOINTS)]

        self._v = [0.0] * NUM_JOINTS
        self._a = [0.0] * NUM_JOINTS
        self._q_ref: list[float] | None = None
        self._q_meas: list[float] | None = None             # the latest valid measurement
        self._target = [0.0] * NUM_JOINTS
        self._target_code = Code.OK                              # why the target is what it is
        self._target_text = ""
        self._last_valid: float | None = None
        self._estop = False
        self._fault = ""                                    # reflex text while one is latched
        self._teaching = False
        # Armed at start (the arm rests): the controller starts disarmed, waiting for the operator's
        # neutral, and the libfranka loop disarms on every connection.
        self.arming = Arming()
        self._code = Code.OK
        self.commands_received = 0
        self.commands_rejected = 0
        self.interventions = 0
        self.resyncs = 0
        self.last_intervention = Code.OK

    # ----------------------------------------------------------------------------------------- state
    @property
    def velocity(self) -> np.ndarray:
        return np.array(self._v)

    @property
    def acceleration(self) -> np.ndarray:
        return np.array(self._a)

    @property
    def reference_position(self) -> np.ndarray | None:
        return None if self._q_ref is None else np.array(self._q_ref)

    @property
    def estop_active(self) -> bool:
        return self._estop

    @property
    def fault(self) -> str:
        """The latched reflex text ("" when none)."""
        return self._fault

    @property
    def teaching(self) -> bool:
        return self._teaching

    @property
    def holding(self) -> bool:
        """Commands are ignored and the output held at zero (e-stop, reflex or teaching)."""
        return self._estop or bool(self._fault) or self._teaching

    @property
    def awaiting_zero(self) -> bool:
        return not self.arming.armed

    @property
    def is_stopped(self) -> bool:
        return not any(self._v) and not any(self._a)

    @property
    def code(self) -> int:
        return self._code

    def reset(self, q=None) -> None:
        """Forget motion (the arm was teleported or restarted): output at rest, target zero, watchdog
        cleared, reference re-synchronised to `q` (or on the next call). Holds and the wait for a
        zero command survive."""
        self._v = [0.0] * NUM_JOINTS
        self._a = [0.0] * NUM_JOINTS
        self._target = [0.0] * NUM_JOINTS
        self._target_code, self._target_text = Code.OK, ""
        self._last_valid = None
        self._q_ref = _valid_q(q)
        self._contact.clear()

    def follow(self, v, a, q) -> bool:
        """Continue from the robot's own reference: after lost cycles the FCI extrapolated the velocity
        at frozen acceleration and judges the next command against that, not against this filter's last
        output (libfranka: intermittent drops "could trigger discontinuity errors"). `v`, `a`: the
        reference velocity and acceleration (libfranka's dq_d, ddq_d); `q` the measured position.
        Ignored (False) unless all are 7 finite values; the acceleration is clipped to the limit."""
        ref = [_valid_q(x) for x in (v, a, q)]
        if any(x is None for x in ref):
            return False
        v, a, q = ref
        self._v = list(v)
        self._a = [min(max(x, -lim[1]), lim[1]) for x, lim in zip(a, self._lim)]
        self._q_ref = q
        return True

    def set_estop(self, active: bool) -> None:
        """Latch (True) or release (False). After a release motion needs a zero command first."""
        active = bool(active)
        if active and not self._estop:
            self._count_intervention(Code.ESTOP)
        if active or self._estop:
            self.disarm("e-stop")
        self._estop = active
        self._zero_target()

    def set_fault(self, text: str) -> None:
        """The robot stopped itself with a reflex (`text` says which): hold zero until clear_fault()."""
        if not self._fault:
            self._count_intervention(Code.REFLEX)
        self.disarm(f"robot reflex: {text or 'reflex'}")
        self._fault = text or "reflex"
        self._zero_target()

    def clear_fault(self) -> bool:
        """Recovered: motion needs a zero command first. False if no reflex was latched."""
        if not self._fault:
            return False
        self._fault = ""
        self.disarm("recovered from a reflex")
        self._zero_target()
        return True

    def set_teaching(self, active: bool) -> None:
        """Teaching mode (the arm backdrivable): output zero, commands ignored. Leaving it needs a zero
        command before motion, as after an e-stop."""
        active = bool(active)
        if active or self._teaching:
            self.disarm("teaching mode")
        self._teaching = active
        self._zero_target()

    def disarm(self, why: str) -> None:
        """A stop: brake to zero now, and motion needs a zero command first (the filter's own stops
        call it, and so do the backends' and the node's: a silent robot, ~/recover)."""
        self.arming.disarm(why)
        self._zero_target()

    def _zero_target(self) -> None:
        self._target = [0.0] * NUM_JOINTS
        self._target_code, self._target_text = Code.OK, ""
        self._last_valid = None

    def hold_code(self) -> int:
        """The code a hold or the wait for a zero command gives now (OK if none): for a status sent
        right after a service changed them, before the next period."""
        if self._estop:
            return Code.ESTOP
        if self._fault:
            return Code.REFLEX
        if self._teaching:
            return Code.TEACHING
        return Code.OK if self.arming.armed else Code.AWAITING_ZERO

    def stopping_time_bound(self) -> float:
        """Upper bound (s) on how long braking from the current state takes (for shutdown loops)."""
        return float(np.max(np.abs(self._v) / self.a_max + 2 * self.a_max / self.j_max) + 50 * self._h)

    # ----------------------------------------------------------------------------------------- update
    def filter(self, cmd, q, now: float, tau_ext=None) -> tuple[np.ndarray, int, str]:
        """One control period. Returns the safe velocity (7,), the status code and a text. `tau_ext`:
        the measured external torque per joint (Nm), where the backend has one."""
        if not (isinstance(now, float | int) and math.isfinite(now)):
            now = math.nan                                  # an unusable clock expires the watchdog
        event_code, event_text = Code.OK, ""
        if cmd is not None:
            event_code, event_text = self.submit(cmd, now)

        # Watchdog: a target older than command_timeout decays to zero.
        if self._last_valid is not None:
            age = now - self._last_valid
            if age < 0.0:                                   # clock went back (sim reset): restart
                self._last_valid = now
            elif not age <= self.config.command_timeout:
                self.disarm("command watchdog (no valid command in time)")   # target zero too
                self._target_code = Code.COMMAND_TIMEOUT
                self._target_text = (f"no valid command for {self.config.command_timeout:.3g} s: "
                                     "decelerating to zero")
                self._count_intervention(Code.COMMAND_TIMEOUT)

        had_state = self._q_ref is not None
        state_ok = self._sync_position(q)
        if not state_ok and had_state:                      # lost, not yet to come: a stop
            self.disarm("no valid measured joint position")
        q_ref = self._q_ref
        hold = self._estop or self._fault or self._teaching or not state_ok   # no valid position: brake
        h = self._h
        v_out = [0.0] * NUM_JOINTS
        a_out = [0.0] * NUM_JOINTS
        margin_joints: list[int] = []
        accel_limited = False
        target, vel, acc = self._target, self._v, self._a
        judged = None if tau_ext is None else self._contact.update(tau_ext, h)
        contact = None if hold or judged is None else self._contact_scales(target, judged)
        if contact:
            target = [t * contact.get(i, 1.0) for i, t in enumerate(target)]
        floored = None
        if self.floor is not None and not hold and q_ref is not None and any(target):
            floored = self._floor_limit(target, q_ref, self._q_meas or q_ref)
            if floored is not None:                         # back within the velocity table, if it left
                over = max(abs(t) / lim[0] for t, lim in zip(floored, self._lim))
                target = [t / over for t in floored] if over > 1.0 else floored
        for i, (_, A, J, D, lo, hi, tail, cap_n, cap_a, far) in enumerate(self._lim):
            t = 0.0 if hold else target[i]
            v, a = vel[i], acc[i]
            near = q_ref is not None and (hi - q_ref[i] < far or q_ref[i] - lo < far)
            if near:
                qi = q_ref[i]
                capped = _position_cap(t, qi, lo, hi, tail, cap_n, cap_a)
                if abs(capped - t) > 1e-9:
                    margin_joints.append(i)
                t = capped
            if v == t and a == 0.0:                         # on target: what _track returns, faster
                vn, an = v, 0.0
            else:                                           # _track, inlined (the 1 kHz path)
                e = t - v
                ae = abs(e)
                mag = 2.0 * ae / (h + math.sqrt(h * h + 2.0 * ae / J))
                a_des = (mag if mag < A else A) if e >= 0.0 else -(mag if mag < A else A)
                an = a - D if a_des < a - D else a + D if a_des > a + D else a_des
                vn = v + h * an
                if abs(t - vn) < _SNAP and abs(an) < 1e-6:
                    vn, an = t, 0.0
            if near and not self._reachable(i, vn, an):
                vn, an = _track(v, a, 0.0, h, A, J, D)      # brake: a state that already passed
                if not margin_joints or margin_joints[-1] != i:
                    margin_joints.append(i)
            if abs(an) >= A * (1 - 1e-9):
                accel_limited = True
            v_out[i], a_out[i] = vn, an
        self._v, self._a = v_out, a_out
        if q_ref is not None:
            self._q_ref = [qr + h * vn for qr, vn in zip(q_ref, v_out)]

        # Status: the most important reason the output differs from the raw command.
        moving = not self.is_stopped
        if self._estop:
            code, text = Code.ESTOP, "e-stop latched: decelerating to zero and holding until released"
        elif self._fault:
            code, text = Code.REFLEX, f"robot reflex ({self._fault}): holding until ~/recover"
        elif self._teaching:
            code, text = Code.TEACHING, "teaching mode: the arm is backdrivable, commands are ignored"
        elif event_code != Code.OK:
            code, text = event_code, event_text
        elif not state_ok:
            code, text = Code.INVALID_STATE, "no valid measured joint position: braking to zero"
        elif (self._target_code == Code.COMMAND_TIMEOUT or self._target_code in _REJECTIONS) and moving:
            code, text = self._target_code, self._target_text
        elif not self.arming.armed:
            code = Code.AWAITING_ZERO
            text = f"stopped ({self.arming.reason}): send a zero command before moving"
        elif contact:
            worst = min(contact, key=contact.get)
            code = Code.CONTACT
            text = (f"{', '.join(self._names[i] for i in sorted(contact))} slowed by an external torque "
                    f"({self._names[worst]} at {contact[worst]:.0%} speed): moving further into the "
                    "contact stops before a reflex")
        elif floored is not None:
            code = Code.WORKSPACE
            text = (f"the hand slowed above the workspace floor (TCP at z >= {self.floor.floor:.3g} m): "
                    "lowering it further is slowed to a stop; moving up or sideways is not")
        elif margin_joints:
            names = ", ".join(self._names[i] for i in margin_joints)
            code = Code.POSITION_MARGIN
            text = f"{names} slowed to stop {self.config.position_margin:.3g} rad from the position limit"
        elif self._target_code == Code.VELOCITY_SCALED:
            code, text = Code.VELOCITY_SCALED, self._target_text
        elif accel_limited:
            code = Code.ACCELERATION_LIMITED
            text = "acceleration limit shaping the output (jerk-limited ramp)"
        else:
            code, text = Code.OK, ""
        if code != self._code and code in _COUNTED_WHEN_ENTERED:
            self._count_intervention(code)                  # the others are counted where they happen
        self._code = code
        return np.array(v_out), code, text

    # -------------------------------------------------------------------------------------- internals
    def _count_intervention(self, code: int) -> None:
        self.interventions += 1
        self.last_intervention = code

    def submit(self, cmd, now: float) -> tuple[int, str]:
        """Take a new command without stepping (a node calls this as each message arrives, so every
        command is validated and counted even if several arrive within one period; the latest valid
        one is the target). Returns (NON_FINITE_COMMAND | WRONG_LENGTH | IMPLAUSIBLE_COMMAND, text) on
        rejection, else (OK, ""); a valid command that a hold or the wait for a zero command ignores is
        (OK, "") too (the status code says why nothing moves)."""
        if not (isinstance(now, float | int) and math.isfinite(now)):
            now = math.nan
        self.commands_received += 1
        try:
            arr = np.asarray(cmd, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.shape != (NUM_JOINTS,):
            n = "non-numeric" if arr is None else f"{arr.size} values"
            return self._reject(Code.WRONG_LENGTH,
                                f"command rejected: {n}, expected {NUM_JOINTS}; treated as zero")
        finite = np.isfinite(arr)
        if not finite.all():
            bad = ", ".join(self._names[i] for i in np.flatnonzero(~finite))
            return self._reject(Code.NON_FINITE_COMMAND,
                                f"command rejected: non-finite value at {bad}; treated as zero")
        excess = np.abs(arr) / self._plausible
        if excess.max() > 1.0:
            i = int(np.argmax(excess))
            return self._reject(Code.IMPLAUSIBLE_COMMAND,
                                f"command rejected: {self._names[i]} at {arr[i]:.3g} rad/s is beyond "
                                f"{self.config.plausibility_factor:g}x its limit "
                                f"({self.robot.dq_max[i]:g} rad/s); treated as zero")
        if self.holding:
            return Code.OK, ""                                   # ignored while held
        if not self.arming.offer(float(np.abs(arr).max()) <= ZERO_COMMAND):
            return Code.OK, ""                                   # ignored until a zero command
        self._last_valid = now
        ratios = np.abs(arr) / self.v_max
        ratio = float(ratios.max())
        if ratio > 1.0:
            worst = self._names[int(np.argmax(ratios))]
            self._target = (arr / ratio).tolist()
            self._target_code = Code.VELOCITY_SCALED
            self._target_text = (f"velocity scaled by {1.0 / ratio:.3g} keeping its direction "
                                 f"({worst} was {ratio:.3g}x its limit)")
        else:
            self._target = arr.tolist()
            self._target_code, self._target_text = Code.OK, ""
        return Code.OK, ""

    def _contact_scales(self, target: list[float], tau_ext) -> dict[int, float]:
        """`contact.contact_scales` with this filter's reflex table and thresholds, on the torque
        `ContactMemory` judges (the recent peak)."""
        return contact_scales(target, tau_ext, self.reflex_torque, self.config.contact_slow,
                              self.config.contact_stop)

    def _floor_limit(self, target: list[float], q_ref: list[float], q: list[float]) -> list[float] | None:
        """`workspace.WorkspaceFloor.limit` at the measured position (the reference may be up to
        position_sync_tolerance away: centimetres at the hand), on the target as the position caps
        below will leave it: a joint near its limit keeps its capped speed and is not used for the
        change (the cap would undo it, and the hand would go on down)."""
        capped, free = [], []
        for t, qi, (_, _, _, _, lo, hi, tail, cap_n, cap_a, far) in zip(target, q_ref, self._lim):
            near = hi - qi < far or qi - lo < far
            if near:
                t = _position_cap(t, qi, lo, hi, tail, cap_n, cap_a)
            capped.append(t)
            free.append(not near)
        return self.floor.limit(capped, q, free)

    def _reject(self, code: int, text: str) -> tuple[int, str]:
        self.commands_rejected += 1
        self._count_intervention(code)
        self._target = [0.0] * NUM_JOINTS
        self._target_code, self._target_text = code, text
        self._last_valid = None                             # zero target: nothing left to time out
        return code, text

    def _sync_position(self, q) -> bool:
        """Update the reference position from a measurement. q None = no new measurement this period
        (the integrated reference carries on, if there is one). False if there is no usable position:
        q is not 7 finite values, or None before any measurement."""
        if q is None:
            return self._q_ref is not None
        q = _valid_q(q)
        if q is None:
            return False
        self._q_meas = q
        if self._q_ref is None or self.is_stopped:
            self._q_ref = q
        elif max(abs(x - y) for x, y in zip(q, self._q_ref)) > self.config.position_sync_tolerance:
            self._q_ref = q
            self.resyncs += 1
        return True

    def _reachable(self, i: int, vn: float, an: float) -> bool:
        """Whether joint i, after stepping to (vn, an), can still brake to rest inside its margin —
        or, if it is outside already, ends no further out than braking now would."""
        _, A, J, D, lo, hi, tail, _, _, _ = self._lim[i]
        h, qi = self._h, self._q_ref[i]
        q_next = qi + h * vn
        up = q_next + _excursion_bound(vn, an, h, A, D, tail)
        down = q_next - _excursion_bound(-vn, -an, h, A, D, tail)
        if up <= hi and down >= lo:
            return True
        vb, ab = _track(self._v[i], self._a[i], 0.0, h, A, J, D)
        qb = qi + h * vb
        if up > hi and up > qb + _excursion_bound(vb, ab, h, A, D, tail) + 1e-12:
            return False
        return not (down < lo and down < qb - _excursion_bound(-vb, -ab, h, A, D, tail) - 1e-12)


def _valid_q(q) -> list[float] | None:
    """q as 7 finite floats, or None."""
    if q is None:
        return None
    try:
        arr = np.asarray(q, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return None
    if arr.shape != (NUM_JOINTS,) or not np.isfinite(arr).all():
        return None
    return arr.tolist()


def _track(v: float, a: float, vt: float, h: float, A: float, J: float, D: float) -> tuple[float, float]:
    """One jerk-limited step of the velocity v (acceleration a) towards vt (see the module docstring)."""
    e = vt - v
    ae = abs(e)
    mag = 2.0 * ae / (h + math.sqrt(h * h + 2.0 * ae / J))   # solves h m + m^2 / (2J) = |e|
    a_des = min(mag, A) if e >= 0.0 else -min(mag, A)
    a_new = min(max(a_des, a - D), a + D)
    v_new = v + h * a_new
    if abs(vt - v_new) < _SNAP and abs(a_new) < 1e-6:     # land exactly (rest is exactly zero)
        return vt, 0.0
    return v_new, a_new


def _excursion_bound(v: float, a: float, h: float, A: float, D: float, tail: float) -> float:
    """Upper bound on the further travel in the + direction while braking (tracking zero) from (v, a)."""
    ap = a if a > 0.0 else 0.0
    m = math.floor(ap / D)
    v_pk = v + h * (m * ap - D * m * (m + 1) / 2)           # + exact gain while ramping ap to zero
    if v_pk <= 0.0:
        return 0.0
    ramp_steps = math.ceil((max(a, -A) + A) / D)
    return ramp_steps * h * v_pk + v_pk * v_pk / (2 * A) + tail


def _position_cap(t: float, q: float, lo: float, hi: float, tail: float, cap_n: float, cap_a: float) -> float:
    """Target velocity t capped so the joint at q can still stop inside [lo, hi] (step 4's soft part)."""
    return min(max(t, -_cap(q - lo, tail, cap_n, cap_a)), _cap(hi - q, tail, cap_n, cap_a))


def _cap(d: float, tail: float, cap_n: float, cap_a: float) -> float:
    """Largest speed towards a margin at distance d from which the planned approach stops in time."""
    room = d - tail
    if room <= 0.0:
        return 0.0
    return cap_a * (math.sqrt(cap_n * cap_n + 2.0 * room / cap_a) - cap_n)

"""The gripper behind the bridge's safety layer: one core for every backend's hand (plain Python).

Requests mirror control_msgs/GripperCommand (a target width and a maximum force) and libfranka's
Gripper (homing, move, grasp with epsilon, stop); `vla_interfaces/srv/GripperCommand` carries them.
`GripperCore` checks each one against the hand's range (width 0..max_width, force within the hand's
rating, speed at most 0.1 m/s, finite numbers) and refuses it with a reason, hands what it accepts to
the backend's `HandDriver` (non-blocking: a real hand's calls block, so its driver runs them in a
thread of its own), and follows the driver's readings to say what the hand does and holds:

- a grasp that ends outside [width - epsilon_inner, width + epsilon_outer] is GRASP_FAILED, reported
  once and never retried (the next grasp is the user's);
- the e-stop stops a moving hand where it is; a hand that holds something keeps holding it (an
  e-stop never opens a closed hand: it would drop what it holds); while latched, only `stop` is taken;
- requests closer together than `min_interval` (a flood of toggles) are refused, so the hand never
  chatters; a stop is always taken;
- a driver that fails (a lost connection) makes the state LOST; the arm is not affected.

Never raises on bad input. States are `vla_interfaces/GripperStatus` constants (a test checks).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from vla_common.robot import HAND, HandSpec

# Commands (vla_interfaces/srv/GripperCommand constants)
OPEN, GRASP, MOVE, STOP, HOMING, TOGGLE = 0, 1, 2, 3, 4, 5
COMMAND_NAMES = {OPEN: "open", GRASP: "grasp", MOVE: "move", STOP: "stop", HOMING: "homing",
                 TOGGLE: "toggle"}

# States (vla_interfaces/msg/GripperStatus constants)
IDLE, MOVING, GRASPING, HOLDING, GRASP_FAILED, STOPPED, LOST, NONE = 0, 1, 2, 3, 4, 5, 6, 7
STATE_NAMES = {IDLE: "IDLE", MOVING: "MOVING", GRASPING: "GRASPING", HOLDING: "HOLDING",
               GRASP_FAILED: "GRASP_FAILED", STOPPED: "STOPPED", LOST: "LOST", NONE: "NONE"}

# What a request with speed, force or epsilon 0 gets.
DEFAULT_SPEED = 0.05
DEFAULT_FORCE = 20.0
DEFAULT_EPSILON = 0.005
MIN_INTERVAL = 0.2   # s between accepted motion requests: a flood of toggles is refused, not obeyed
TOGGLE_MIN_OBJECT = 0.005  # m: a toggled grasp succeeds on anything this wide or wider (up to open)


@dataclass(frozen=True)
class HandOp:
    """One motion for a driver: kind MOVE (to width at speed), GRASP (close at speed, squeeze with
    force; success judged by the core from the final width) or HOMING."""

    kind: int
    width: float = 0.0
    speed: float = DEFAULT_SPEED
    force: float = DEFAULT_FORCE
    epsilon_inner: float = DEFAULT_EPSILON
    epsilon_outer: float = DEFAULT_EPSILON


@dataclass
class HandReading:
    """What a driver measured: the finger gap (m), whether its motion still runs (True from the
    moment `start` returns), whether the hand holds something now (None: it cannot tell; a real
    hand's is_grasped, the simulation's finger contacts), what it holds ("" unknown), an error
    text when the hand is gone, and why the motion that ended failed (a hand that refused it)."""

    width: float
    moving: bool
    grasped: bool | None = None
    holding: str = ""
    error: str = ""
    finger_velocity: float = 0.0
    failed: str = ""


class HandDriver(Protocol):
    max_width: float

    def start(self, op: HandOp) -> None:
        """Begin a motion (returns at once); a running one is stopped first."""

    def stop(self) -> None:
        """Stop a running motion where the fingers are; a finished grasp keeps holding."""

    def read(self) -> HandReading:
        """The latest reading (never blocks)."""


def _finite(*values) -> bool:
    try:
        return all(math.isfinite(float(v)) for v in values)
    except (TypeError, ValueError):
        return False


@dataclass
class GripperStatusData:
    state: int = IDLE
    text: str = ""
    width: float = 0.0
    holding: str = ""
    target_width: float = math.nan
    force: float = 0.0
    commands_received: int = 0
    commands_rejected: int = 0


class GripperCore:
    """The gripper's safety layer and state machine for one hand driver. `request(...)` returns
    (accepted, message); `update(now)` once per tick follows the driver; `status` says what the
    hand does."""

    def __init__(self, driver: HandDriver, hand: HandSpec = HAND, min_interval: float = MIN_INTERVAL) -> None:
        self.driver = driver
        self.limits = hand
        self.min_interval = float(min_interval)
        self.status = GripperStatusData()
        self._op: HandOp | None = None       # the motion the driver runs (None: none)
        self._last_accept = -math.inf
        self._estop = False
        self._closed = True                  # the last accepted motion closed the hand (a toggle opens)
        self._changed = True
        self.last_reading: HandReading | None = None
        self.update(-math.inf)
        self._closed = self.status.width < 0.5 * hand.max_width   # a toggle first opens a closed hand

    def reset(self, text: str = "reset") -> None:
        """The hand was reset with the scene (the simulation: closed, holding nothing)."""
        self._op, self._closed = None, True
        self.status.holding = ""
        self._set(IDLE, text)
        self._read()

    # ------------------------------------------------------------------ requests
    def check(self, command: int, width: float, speed: float, force: float,
              epsilon_inner: float = DEFAULT_EPSILON, epsilon_outer: float = DEFAULT_EPSILON) -> str | None:
        """Why this request is refused, or None."""
        lim = self.limits
        if isinstance(command, bool) or not isinstance(command, int) or command not in COMMAND_NAMES:
            return f"unknown gripper command {command!r}; one of {COMMAND_NAMES}"
        if command == STOP:
            return None
        if not _finite(width, speed, force, epsilon_inner, epsilon_outer):
            return f"{COMMAND_NAMES[command]} refused: non-finite values (NaN or Inf)"
        if command in (MOVE, GRASP) and not 0.0 <= width <= lim.max_width:
            return f"width {width:g} m is outside the hand's range 0..{lim.max_width:g} m"
        if not 0.0 <= speed <= lim.max_speed:
            return f"speed {speed:g} m/s is outside 0..{lim.max_speed:g} m/s (0: the default)"
        if not 0.0 <= force <= lim.max_force:
            return f"force {force:g} N is outside the hand's rating 0..{lim.max_force:g} N (0: the default)"
        if not (0.0 <= epsilon_inner <= lim.max_width and 0.0 <= epsilon_outer <= lim.max_width):
            return f"epsilon must be within 0..{lim.max_width:g} m (0: the default)"
        return None

    def request(self, command: int, now: float, width: float = 0.0, speed: float = 0.0, force: float = 0.0,
                epsilon_inner: float = DEFAULT_EPSILON, epsilon_outer: float = DEFAULT_EPSILON
                ) -> tuple[bool, str]:
        """One request (speed 0 / force 0: the defaults). (accepted, what was done or why not)."""
        st = self.status
        st.commands_received += 1
        reason = self.check(command, width, speed, force, epsilon_inner, epsilon_outer)
        if reason is None:
            reason = self._refusal(command, now)
        if reason is not None:
            st.commands_rejected += 1
            return False, reason
        if command == STOP:
            return True, self._stop("stopped on request")
        speed = float(speed) or DEFAULT_SPEED
        force = float(force) or DEFAULT_FORCE
        epsilon_inner = float(epsilon_inner) or DEFAULT_EPSILON
        epsilon_outer = float(epsilon_outer) or DEFAULT_EPSILON
        if command == TOGGLE:  # what the object's size is, a button does not say: any 5..80 mm
            command = OPEN if self._closed else GRASP
            lo, hi = TOGGLE_MIN_OBJECT, self.limits.max_width
            width, epsilon_inner, epsilon_outer = (lo + hi) / 2, (hi - lo) / 2, (hi - lo) / 2
        if command == OPEN:
            op = HandOp(MOVE, self.limits.max_width, speed)
        elif command == MOVE:
            op = HandOp(MOVE, float(width), speed)
        elif command == HOMING:
            op = HandOp(HOMING, self.limits.max_width, speed)
        else:
            op = HandOp(GRASP, float(width), speed, force, epsilon_inner, epsilon_outer)
        try:
            self.driver.start(op)
        except Exception as exc:  # a driver that fails to start: the hand is lost
            self._lose(f"{type(exc).__name__}: {exc}")
            return False, st.text
        self._op, self._last_accept = op, now
        self._closed = op.kind == GRASP or (op.kind == MOVE and op.width < 0.5 * self.limits.max_width)
        name = COMMAND_NAMES[command]
        self._set(GRASPING if op.kind == GRASP else MOVING, f"{name}: width {op.width:.3f} m at "
                  f"{op.speed:g} m/s" + (f", force {op.force:g} N" if op.kind == GRASP else ""))
        st.target_width = op.width
        st.force = op.force if op.kind == GRASP else 0.0
        return True, st.text

    def _refusal(self, command: int, now: float) -> str | None:
        st = self.status
        if st.state == LOST and command != STOP:
            return f"the hand is lost ({st.text}); the arm keeps working without it"
        if command == STOP:
            return None
        if self._estop:
            return "e-stop active: the hand takes only stop until the e-stop is released"
        if now - self._last_accept < self.min_interval:
            return (f"too soon: {now - self._last_accept:.3f} s after the last gripper command "
                    f"(at least {self.min_interval:g} s apart)")
        return None

    # ------------------------------------------------------------------ e-stop
    def set_estop(self, active: bool) -> str:
        """Latch/release the e-stop: a moving hand stops where it is; a hand that holds keeps holding.
        Releasing starts nothing."""
        self._estop = bool(active)
        if active and self._op is not None:
            return self._stop("stopped by the e-stop")
        return "e-stop " + ("latched" if active else "released")

    @property
    def estop_active(self) -> bool:
        return self._estop

    def _stop(self, why: str) -> str:
        try:
            self.driver.stop()
        except Exception as exc:
            self._lose(f"{type(exc).__name__}: {exc}")
            return self.status.text
        self._op = None
        reading = self._read()
        if reading is not None and self.status.state != LOST:
            held = self.status.state == HOLDING
            self._set(HOLDING if held else STOPPED, (f"{why}; holding {self.status.holding or 'an object'}"
                                                      if held else f"{why} at {reading.width:.3f} m"))
        return self.status.text

    # ------------------------------------------------------------------ following the driver
    def _read(self) -> HandReading | None:
        try:
            r = self.driver.read()
        except Exception as exc:
            self._lose(f"{type(exc).__name__}: {exc}")
            return None
        if r.error:
            self._lose(r.error)
            return None
        if not _finite(r.width):
            self._lose(f"the hand reports a non-finite width ({r.width!r})")
            return None
        self.status.width = float(r.width)
        self.last_reading = r
        return r

    def update(self, now: float) -> bool:
        """Follow the driver (once per tick). True when the state changed since the last call."""
        r = self._read()
        if r is not None:
            st, op = self.status, self._op
            if op is not None and not r.moving:
                self._op = None
                self._finish(op, r)
            elif st.state == HOLDING and r.grasped is False:
                self._set(IDLE, f"no longer holding {st.holding or 'the object'} (slipped or taken) at "
                          f"{r.width:.3f} m")
            elif st.state == HOLDING and r.holding and r.holding != st.holding:
                st.holding = r.holding
                self._changed = True
            elif st.state == LOST:
                self._set(IDLE, f"the hand answers again at {r.width:.3f} m")
        changed, self._changed = self._changed, False
        return changed

    def _finish(self, op: HandOp, r: HandReading) -> None:
        if r.failed:
            state = GRASP_FAILED if op.kind == GRASP else STOPPED
            self._set(state, f"{r.failed} at {r.width:.3f} m; not retried")
            return
        if op.kind != GRASP:
            self._set(IDLE, f"{'homed' if op.kind == HOMING else 'moved'} to {r.width:.3f} m")
            return
        in_range = op.width - op.epsilon_inner <= r.width <= op.width + op.epsilon_outer
        ok = in_range and r.grasped is not False
        if ok:
            self.status.holding = r.holding
            self._set(HOLDING, f"holding {r.holding or 'an object'} at {r.width:.3f} m")
        else:
            self.status.holding = ""
            self._set(GRASP_FAILED, f"grasp failed: the fingers closed to {r.width:.3f} m, expected "
                      f"{op.width:.3f} m (-{op.epsilon_inner:g}/+{op.epsilon_outer:g}); not retried")

    def _lose(self, why: str) -> None:
        self._op = None
        self.status.holding = ""
        self._set(LOST, f"hand lost: {why}")

    def _set(self, state: int, text: str) -> None:
        st = self.status
        if state not in (HOLDING, STOPPED):
            st.holding = ""
        if (state, text) != (st.state, st.text):
            st.state, st.text = state, text
            self._changed = True

    @property
    def holding(self) -> str:
        return self.status.holding if self.status.state == HOLDING else ""

    @property
    def closed(self) -> bool:
        """The hand was last told to close (grasp or a narrow move): what a toggle undoes."""
        return self._closed

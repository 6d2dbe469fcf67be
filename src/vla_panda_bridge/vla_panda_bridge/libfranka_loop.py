"""The 1 kHz libfranka loop, in a process of its own (pylibfranka holds the GIL inside readOnce, so a
thread beside rclpy would miss robot cycles). Plain Python, no ROS: `python -m
vla_panda_bridge.libfranka_loop --slots PATH --settings JSON --parent-pid PID`.

Every robot cycle: read the robot state (this paces the loop), take the latest command from the
shared slots, run the bridge's SafetyFilter for the cycle (so the command the robot gets is
continuous in velocity and acceleration, within the limits, and braked to zero by the watchdog),
write the command, publish the state. A motion starts when a non-zero command arrives and ends,
with zero velocity and acceleration and `motion_finished`, once the arm is at rest and nothing asks
it to move; between motions the loop reads the robot state at its rate.

Errors never end the process: a reflex (ControlException) stops the arm and waits for a recover
request; a lost connection (a server restart, a cable) drops the Robot and reconnects with back-off;
a FATAL error (protocol version, real-time kernel) waits for a recover request. The status code and
libfranka's text go to the state slot. Teaching: torque control with tau = -teaching_damping * dq
(the robot compensates gravity itself); leaving it ends the torque motion at rest, and the robot
holds the pose until the next velocity motion starts from it.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from enum import Enum, IntEnum

import numpy as np
from vla_common.robot import robot_spec
from vla_common.safety_status import SafetyCode, code_name

from vla_panda_bridge.libfranka_driver import (
    FATAL,
    PERIOD,
    REFLEX,
    Driver,
    DriverSettings,
    RobotError,
)
from vla_panda_bridge.libfranka_open import open_driver
from vla_panda_bridge.libfranka_slots import (
    CMD_ARRIVED,
    CMD_N,
    CMD_SEQ,
    CMD_VALUES,
    CONTROL,
    NUM_JOINTS,
    STATE,
    Slots,
)
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter


class LoopStatus(IntEnum):
    """The loop's status, its one form: the state slot holds the number, ~/status shows the name."""

    OK = 0
    CONNECTING = 1
    DISCONNECTED = 2
    REFLEX = 3
    FATAL = 4
    STOPPED = 5


class Mode(IntEnum):
    """What the loop is doing with the robot (state slot "mode")."""

    NONE = -1       # not connected
    IDLE = 0        # reading states between motions
    VELOCITY = 1    # a joint-velocity motion
    TORQUE = 2      # teaching


class State(Enum):
    """The loop's states; each is one (status, mode) pair of the state slot."""

    CONNECTING = (LoopStatus.CONNECTING, Mode.NONE)
    DISCONNECTED = (LoopStatus.DISCONNECTED, Mode.NONE)
    FATAL = (LoopStatus.FATAL, Mode.NONE)
    IDLE = (LoopStatus.OK, Mode.IDLE)
    VELOCITY = (LoopStatus.OK, Mode.VELOCITY)
    TORQUE = (LoopStatus.OK, Mode.TORQUE)
    REFLEX = (LoopStatus.REFLEX, Mode.IDLE)
    STOPPED = (LoopStatus.STOPPED, Mode.NONE)


@dataclass(frozen=True)
class Row:
    states: tuple[State, ...]   # the states the event is handled in
    event: str
    does: str                   # what the loop does (in words; the code beside `_go(event)` does it)
    next: State | None          # None: the state stays
    disarm: bool                # a stop the operator did not choose: motion needs a zero command first


_S = State
_CONNECTED = (_S.IDLE, _S.VELOCITY, _S.TORQUE, _S.REFLEX)
_DOWN = (_S.CONNECTING, _S.DISCONNECTED)
# The state machine, written once: every change of state or arming goes through `_go(event)`, which
# takes the row of the current state and the event (README "The 1 kHz loop" renders this table).
TABLE: tuple[Row, ...] = (
    Row(_DOWN, "connected", "reset the filter at the measured pose, drop older commands", _S.IDLE, True),
    Row(_DOWN, "connect failed", "retry after a back-off (doubled up to reconnect_max)", None, False),
    Row((*_DOWN, *_CONNECTED), "fatal error", "drop the connection, wait for ~/recover",
        _S.FATAL, True),
    Row((_S.FATAL,), "recover request", "try to connect now", _S.CONNECTING, False),
    Row(_CONNECTED, "connection lost", "drop the connection, reconnect with back-off", _S.DISCONNECTED,
        True),
    Row(_CONNECTED, "reflex", "the robot stopped the motion; ignore commands until ~/recover", _S.REFLEX,
        True),
    Row((_S.IDLE, _S.REFLEX), "recover request", "the robot's error recovery, filter reset at the pose",
        _S.IDLE, True),
    Row((_S.IDLE,), "teaching on", "torque control, tau = -teaching_damping * dq", _S.TORQUE, False),
    Row((_S.TORQUE,), "teaching ends", "(off, ~/recover, e-stop, shutdown) end the torque motion, filter "
        "reset at the pose", _S.IDLE, True),
    Row((_S.IDLE,), "motion wanted", "(armed, fresh non-zero command) start a velocity motion, two "
        "zero commands first", _S.VELOCITY, False),
    Row((_S.VELOCITY,), "at rest", "(stopped, nothing wanted for finish_hold; or braked for shutdown, "
        "~/recover, teaching) end the motion with motion_finished", _S.IDLE, False),
    Row(_CONNECTED, "e-stop change", "the filter brakes (on) or holds zero (off); drop older commands",
        None, True),
    Row(_CONNECTED, "robot silent", "(no robot state for longer than command_timeout) the filter brakes",
        None, True),
    Row((*_DOWN, _S.FATAL, _S.IDLE, _S.REFLEX), "shutdown", "drop the connection, exit", _S.STOPPED,
        False),
)
_ROWS = {(state, row.event): row for row in TABLE for state in row.states}


def table_markdown() -> str:
    """TABLE as a Markdown table (README "The 1 kHz loop")."""
    lines = ["| in state | event | the loop | next state | disarms |", "|---|---|---|---|---|"]
    for r in TABLE:
        states = ", ".join(s.name for s in r.states)
        nxt = "(same)" if r.next is None else r.next.name
        lines.append(f"| {states} | {r.event} | {r.does} | {nxt} | {'yes' if r.disarm else ''} |")
    return "\n".join(lines) + "\n"


# Zero commands that open every motion before the filter's first step: the robot (franka-sim's
# checker too) judges the jerk of a velocity stream from its own history, which a motion starts
# without; two zeros give it an acceleration of zero to difference against.
START_ZEROS = 2


@dataclass
class LoopSettings:
    """Everything the loop process needs; JSON on its command line."""

    driver: str = "pylibfranka"
    robot: dict = field(default_factory=lambda: {"robot_ip": "172.16.0.2"})   # DriverSettings fields
    safety: dict = field(default_factory=dict)                                 # SafetyConfig fields
    robot_model: str = "fr3"
    reconnect_min: float = 0.1      # s before the first reconnection attempt, doubled up to ...
    reconnect_max: float = 2.0
    finish_hold: float = 0.1        # s at rest with nothing to do before a motion ends
    priority: int = 0               # SCHED_FIFO priority of the loop process (0: normal scheduling)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> LoopSettings:
        return cls(**json.loads(text))

    def driver_settings(self) -> DriverSettings:
        return DriverSettings(**self.robot)


def make_filter(settings: LoopSettings) -> SafetyFilter:
    """The bridge's SafetyFilter at the robot's rate, with the limit table of the robot model."""
    config = SafetyConfig(**{**settings.safety, "dt": PERIOD})
    return SafetyFilter(config, robot=robot_spec(settings.robot_model))


_ZEROS = (0.0,) * NUM_JOINTS


class ControlLoop:
    """The loop's state machine; `step()` is one iteration (one robot cycle while connected), so a
    test can drive it with a fake driver. `run()` steps until a shutdown request has been served."""

    def __init__(self, slots: Slots, settings: LoopSettings,
                 opener: Callable[[str, DriverSettings], Driver] = open_driver,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time,
                 sleep: Callable[[float], None] = time.sleep, parent_pid: int | None = None):
        self.slots = slots
        self.settings = settings
        self._open = opener
        self._clock = clock
        self._wall = wall
        self._sleep = sleep
        self._parent = parent_pid
        self.filter = make_filter(settings)
        self._timeout = self.filter.config.command_timeout
        self._damping = [float(d) for d in settings.driver_settings().teaching_damping]
        self.driver: Driver | None = None
        self.state = State.CONNECTING
        self.text = ""
        self._filter_text = ""
        self._next_attempt = clock()
        self._backoff = settings.reconnect_min
        self._cmd_seq = -1.0
        self._cmd_seq = self._seq_in_slot()
        self._cmd_t = -math.inf          # robot time of the latest command taken
        self._cmd_arrived = math.nan
        self._latency_pending = False
        self._want = False               # the latest valid command is non-zero and the filter armed
        self._cause = ""                 # the error that lost the connection
        self._rest_since: float | None = None
        self._estop = False
        self._t = 0.0                    # robot time of the latest state
        self._last_read: float | None = None
        self._dq = [0.0] * NUM_JOINTS
        self._motion_cycles = 0
        self._code = SafetyCode.OK
        self.cycle = 0
        self.connects = self.errors = self.missed = self.motions = 0
        self.latency = math.nan
        self.recover_ack = int(slots.control[CONTROL["recover_req"]])
        self.recover_ok = 0
        self.teaching_ack = int(slots.control[CONTROL["teaching_req"]])
        self.stopped = False
        self.orphaned = False            # stopped because the bridge is gone (nobody else cleans up)
        self._period = math.nan
        slots.claim_state_writer()
        self._publish_status()

    @property
    def status(self) -> LoopStatus:
        return self.state.value[0]

    @property
    def mode(self) -> Mode:
        return self.state.value[1]

    def _go(self, event: str, text: str | None = None, why: str = "") -> None:
        """Handle `event` by its row of TABLE: disarm if the row says so, enter its next state, and
        set the status text. An event the table does not list for the state is a bug: it raises."""
        row = _ROWS.get((self.state, event))
        if row is None:
            raise RuntimeError(f"libfranka loop: no transition for {event!r} in state {self.state.name}")
        if row.disarm:
            self.filter.disarm(why or event)
        if row.next is not None:
            self.state = row.next
        if text is not None:
            self._set_text(text)

    # ------------------------------------------------------------------------------------ the loop
    def run(self) -> None:
        while self.step():
            pass

    def step(self) -> bool:
        """One iteration; False once the loop has stopped (shutdown served)."""
        if self.stopped:
            return False
        shutdown = self._shutdown_requested()
        if self.driver is None:
            if shutdown:
                return self._stop()
            self._disconnected_step()
            return True
        try:
            if self.mode == Mode.VELOCITY:
                self._velocity_step(shutdown)
            elif self.mode == Mode.TORQUE:
                self._torque_step(shutdown)
            elif shutdown:
                return self._stop()
            else:
                self._idle_step()
        except RobotError as exc:
            self._on_error(exc)
        return True

    def _shutdown_requested(self) -> bool:
        if self.slots.control[CONTROL["shutdown"]]:
            return True
        if self._parent is not None and (self.cycle % 200 == 0 or self.driver is None):
            self.orphaned = os.getppid() != self._parent   # the ROS node is gone: stop the arm, exit
            return self.orphaned
        return False

    # ------------------------------------------------------------------------- connection, errors
    def _disconnected_step(self) -> None:
        if self._recover_requested():
            self._next_attempt = self._clock()       # ~/recover: try now
            self._backoff = self.settings.reconnect_min
            if self.state is State.FATAL:
                self._go("recover request")
        if self.state is State.FATAL:
            self._teaching_request()                 # answered (refused) while nothing is connected
            self._publish_status()
            self._sleep(0.02)
            return
        wait = self._next_attempt - self._clock()
        if wait > 0.0:
            self._teaching_request()
            self._publish_status()
            self._sleep(min(wait, 0.02))
            return
        try:
            driver = self._open(self.settings.driver, self.settings.driver_settings())
            state = driver.read_idle()
        except RobotError as exc:
            self._connect_failed(exc)
            return
        self.driver = driver
        self.connects += 1
        self._backoff = self.settings.reconnect_min
        name = getattr(driver, "name", self.settings.driver)
        self._last_read = None                       # no silence across a connection: it disarms anyway
        self._on_state(state, None)
        self.filter.reset(state.q)
        self._forget_commands()                      # a command from before the connection is stale
        self._go("connected", f"connected to {self.settings.driver_settings().robot_ip} ({name})")
        self._answer_recover(True)
        self._publish(state, math.nan)

    def _connect_failed(self, exc: RobotError) -> None:
        if exc.kind == FATAL:
            self._go("fatal error", f"{exc.text} (~/recover retries)")
            self._answer_recover(False)
            return
        wait = f"{self._backoff:.2g} s"
        if not self._cause:
            self._go("connect failed", f"{exc.text}; retrying in {wait}")
        else:                                        # keep the cause first: it is what went wrong
            self._go("connect failed", f"{self._cause}; reconnecting (last try: {exc.text}; next in {wait})")
        self._answer_recover(False)
        self._next_attempt = self._clock() + self._backoff
        self._backoff = min(2.0 * self._backoff, self.settings.reconnect_max)

    def _on_error(self, exc: RobotError) -> None:
        """The arm stopped (reflex) or the connection is gone: forget the motion, report, carry on."""
        self.errors += 1
        self.filter.reset()
        self._dq = [0.0] * NUM_JOINTS
        self._forget_commands()
        self._rest_since = None
        why = f"robot error: {exc.text}"
        if exc.kind == REFLEX:
            self._go("reflex", f"{exc.text} (arm stopped; ~/recover to resume)", why)
        else:
            self._drop_driver()
            if exc.kind == FATAL:
                self._go("fatal error", f"{exc.text} (~/recover retries)", why)
            else:
                self._cause = exc.text
                self._go("connection lost", f"{exc.text}; reconnecting", why)
                self._next_attempt = self._clock() + self.settings.reconnect_min
                self._backoff = self.settings.reconnect_min
        self._publish_status()

    def _drop_driver(self) -> None:
        if self.driver is not None:
            try:
                self.driver.close()
            except Exception:  # a dead connection may fail to close: it is dropped either way
                pass
        self.driver = None

    # ------------------------------------------------------------------------------------ requests
    def _recover_requested(self) -> bool:
        return int(self.slots.control[CONTROL["recover_req"]]) != self.recover_ack

    def _answer_recover(self, ok: bool) -> None:
        """Acknowledge an open recover request (if any); its outcome text is the status text."""
        if self._recover_requested():
            self.recover_ok = int(ok)
            self.recover_ack = int(self.slots.control[CONTROL["recover_req"]])
            self._publish_status()

    def _recover(self) -> None:
        """Automatic error recovery (also when nothing is wrong: it is harmless at rest)."""
        try:
            self.driver.recover()
            state = self.driver.read_idle()
        except RobotError as exc:
            self._on_error(exc)
            self._answer_recover(False)
            return
        self._on_state(state, None)
        self.filter.reset(state.q)
        self._forget_commands()
        self._go("recover request", "error recovery done: ready", "error recovery")
        self._answer_recover(True)
        self._publish(state, math.nan)

    def _teaching_request(self) -> bool | None:
        """The pending teaching request's wanted value if it asks for a change, else None. A request
        that changes nothing, or that cannot be served (no connection, an error, e-stop), is
        acknowledged at once; the state slot's mode tells the ROS side what happened."""
        c = self.slots.control
        if int(c[CONTROL["teaching_req"]]) == self.teaching_ack:
            return None
        want = bool(c[CONTROL["teaching"]])
        teaching = self.mode == Mode.TORQUE
        blocked = self.driver is None or self.status != LoopStatus.OK or (self._estop and want)
        if want == teaching or blocked:
            self.teaching_ack = int(c[CONTROL["teaching_req"]])
            return None
        return want

    def _ack_teaching(self) -> None:
        self.teaching_ack = int(self.slots.control[CONTROL["teaching_req"]])

    def _sync_estop(self) -> None:
        estop = bool(self.slots.control[CONTROL["estop"]])
        if estop != self._estop:
            self._estop = estop
            self.filter.set_estop(estop)
            self._forget_commands()
            self._go("e-stop change", why="e-stop " + ("latched" if estop else "released"))

    # ------------------------------------------------------------------------------------ commands
    def _forget_commands(self) -> None:
        """After a connection, an error, a recovery, teaching or an e-stop change the commands so far
        are stale (the same rows of TABLE disarm the filter: vla_common.arming owns that rule)."""
        self._cmd_seq = self._seq_in_slot()
        self._want = False

    def _seq_in_slot(self) -> float:
        c = self.slots.read_command()
        return self._cmd_seq if c is None else float(c[CMD_SEQ])

    def _take_command(self, apply: bool) -> None:
        """The latest command, if new, into the filter (timed in robot time, like the watchdog)."""
        c = self.slots.read_command()
        if c is None or c[CMD_SEQ] == self._cmd_seq:
            return                                   # nothing new, or the writer is mid-write
        self._cmd_seq = c[CMD_SEQ]
        if not apply:
            return
        n = int(c[CMD_N])
        values = c[CMD_VALUES:] if n == NUM_JOINTS else [0.0] * max(n, 0)
        code, _ = self.filter.submit(values, self._t)     # ignored while disarmed, unless zero
        self._cmd_t = self._t
        if c[CMD_ARRIVED] != self._cmd_arrived:      # a new input (not the same one written again)
            self._cmd_arrived = c[CMD_ARRIVED]
            self._latency_pending = True
        self._want = (code == SafetyCode.OK and not self._estop and bool(np.any(values))
                      and self.filter.arming.armed)

    def _wants_motion(self) -> bool:
        return self._want and self._t - self._cmd_t <= self._timeout

    # ---------------------------------------------------------------------------------- the modes
    def _idle_step(self) -> None:
        state = self.driver.read_idle()
        self._on_state(state, None)
        self._sync_estop()
        if self.state is State.REFLEX:
            self._take_command(apply=False)          # nothing moves until ~/recover
            if self._recover_requested():
                self._recover()
                return
            self._teaching_request()
            self._publish(state, math.nan)
            return
        if self._recover_requested():
            self._recover()
            return
        if self._teaching_request():
            self._take_command(apply=False)
            self.driver.start_torque()
            self.motions += 1
            self._ack_teaching()
            self._go("teaching on", "teaching: torque control, the arm follows the hand")
            self._publish(state, math.nan)
            return
        self._take_command(apply=True)
        self._idle_filter_status()
        if self._wants_motion():
            self.driver.start_velocity()
            self._go("motion wanted")
            self.motions += 1
            self._rest_since = None
            self._last_read = None
            self._motion_cycles = 0
        self._publish(state, math.nan)

    def _idle_filter_status(self) -> None:
        """Between motions the filter does not run, but a zero command re-arms it (and a connection
        disarms it): report its hold, not the last motion's code. A motion that ended on the watchdog
        otherwise kept AWAITING_ZERO in the state slot after the zero that re-armed it (load 30)."""
        code = self.filter.hold_code()
        if code != self._code:
            text = {SafetyCode.OK: "", SafetyCode.AWAITING_ZERO: f"stopped ({self.filter.arming.reason}): "
                    "send a zero command before moving"}.get(code, code_name(code))
            self._filter_status(code, text)

    def _velocity_step(self, shutdown: bool) -> None:
        state, dt = self.driver.read_cycle()
        t0 = self._on_state(state, dt)
        self._sync_estop()
        teaching = self._teaching_request()
        stopping = shutdown or bool(teaching) or self._recover_requested()
        if stopping:
            self._take_command(apply=False)
            self.filter.submit(_ZEROS, self._t)      # brake to zero before the motion ends
            self._want = False
        else:
            self._take_command(apply=True)
        f = self.filter
        self._motion_cycles += 1
        if self._motion_cycles <= START_ZEROS:
            self.driver.write_velocity(_ZEROS, False)
            self._publish(state, math.nan, t0)
            return
        if dt > 1.5 * PERIOD:                        # lost cycles: the robot went on without us
            f.follow(*self.driver.gap_reference(f.velocity, f.acceleration, round(dt / PERIOD) - 1), state.q)
        out, code, text = f.filter(None, state.q, self._t)
        self._filter_status(code, text)
        finished = False
        if f.is_stopped and not self._wants_motion():
            if self._rest_since is None:
                self._rest_since = self._t
            finished = stopping or self._t - self._rest_since >= self.settings.finish_hold - 1e-9
        else:
            self._rest_since = None
        dq = out.tolist()
        self.driver.write_velocity(dq, finished)
        self._dq = dq
        latency = math.nan
        if self._latency_pending:
            self._latency_pending = False
            latency = self.latency = self._clock() - self._cmd_arrived
        if finished:
            self._go("at rest")
            self._rest_since = None
        self._publish(state, latency, t0)

    def _torque_step(self, shutdown: bool) -> None:
        state, dt = self.driver.read_cycle()
        t0 = self._on_state(state, dt)
        self._sync_estop()
        self._take_command(apply=False)              # the hand moves the arm, not the commands
        teaching = self._teaching_request()
        finished = shutdown or teaching is False or self._recover_requested() or self._estop
        dq = state.dq
        d = self._damping
        tau = [0.0] * NUM_JOINTS if finished else [-d[i] * dq[i] for i in range(NUM_JOINTS)]
        self.driver.write_torque(tau, finished)
        if finished:
            if teaching is not None:
                self._ack_teaching()
            self.filter.reset(state.q)               # the hand moved it: start from where it is
            self._forget_commands()
            self._go("teaching ends", "teaching ended: holding the pose", "teaching mode")
        self._publish(state, math.nan, t0)

    def _stop(self) -> bool:
        self._drop_driver()
        self.stopped = True
        self._go("shutdown", "loop stopped (shutdown)")
        self._publish_status()
        return False

    # ------------------------------------------------------------------------------- state, status
    def _on_state(self, state, dt: float | None) -> float:
        """Book-keeping for a new robot state; returns the time it arrived (monotonic)."""
        now = self._clock()
        self._period = math.nan if self._last_read is None else now - self._last_read
        self._last_read = now
        if self._period > self._timeout:             # the robot was silent (or this loop stalled)
            self._go("robot silent", why=f"robot silent for {self._period:.2f} s")
        self._t = state.time.to_sec()
        self.cycle += 1
        if dt is not None and dt > 1.5 * PERIOD:
            self.missed += round(dt / PERIOD) - 1
        return now

    def _filter_status(self, code: int, text: str) -> None:
        self._code = code
        if text != self._filter_text:
            self._filter_text = text
            self.slots.write_text("filter", text)

    def _set_text(self, text: str) -> None:
        if text != self.text:
            self.text = text
            self.slots.write_text("status", text)

    def _fill_status(self, b: np.ndarray) -> None:
        f = self.filter
        b[STATE["dq_cmd"]] = self._dq
        b[STATE["status"]] = self.status
        b[STATE["filter_code"]] = self._code
        b[STATE["interventions"]] = f.interventions
        b[STATE["last_intervention"]] = f.last_intervention
        b[STATE["mode"]] = self.mode
        b[STATE["estop_active"]] = f.estop_active
        b[STATE["cmd_seq"]] = self._cmd_seq
        b[STATE["latency"]] = self.latency
        b[STATE["recover_ack"]] = self.recover_ack
        b[STATE["recover_ok"]] = self.recover_ok
        b[STATE["teaching_ack"]] = self.teaching_ack
        b[STATE["connects"]] = self.connects
        b[STATE["errors"]] = self.errors
        b[STATE["missed"]] = self.missed
        b[STATE["motions"]] = self.motions
        b[STATE["pid"]] = os.getpid()

    def _publish(self, state, latency: float, t0: float | None = None) -> None:
        stamp = self._wall()
        self.slots.push_history(self.cycle, stamp, state.q, state.dq, state.tau_J)
        b = self.slots.begin_state()
        b[STATE["cycle"]] = self.cycle
        b[STATE["robot_time"]] = self._t
        b[STATE["stamp"]] = stamp
        b[STATE["q"]] = state.q
        b[STATE["dq"]] = state.dq
        b[STATE["tau_J"]] = state.tau_J
        b[STATE["tau_ext_hat_filtered"]] = state.tau_ext_hat_filtered
        b[STATE["O_T_EE"]] = state.O_T_EE
        b[STATE["robot_mode"]] = int(state.robot_mode)
        b[STATE["success_rate"]] = state.control_command_success_rate
        self._fill_status(b)
        self.slots.end_state()
        if t0 is not None:
            self.slots.ring_push(self._period, self._clock() - t0, latency)

    def _publish_status(self) -> None:
        """Status only (no new robot state: the cycle counter stays, so nothing looks fresh)."""
        b = self.slots.begin_state()
        self._fill_status(b)
        self.slots.end_state()


# ------------------------------------------------------------------------------------ the process
def _set_priority(priority: int) -> str:
    if priority <= 0:
        return ""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return f"could not set SCHED_FIFO priority {priority}: {exc}"
    return ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slots", required=True, help="the shared-memory file the bridge created")
    ap.add_argument("--settings", required=True, help="LoopSettings as JSON")
    ap.add_argument("--parent-pid", type=int, default=None, help="exit (stopping the arm) when it is gone")
    args = ap.parse_args(argv)
    # Ctrl-C in a terminal reaches the whole process group: the bridge stops this loop through the
    # shutdown flag (braking first), so SIGINT is ignored; SIGTERM asks for the same shutdown.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    slots = Slots.attach(args.slots)
    signal.signal(signal.SIGTERM, lambda *_: slots.control.__setitem__(CONTROL["shutdown"], 1.0))
    settings = LoopSettings.from_json(args.settings)
    warning = _set_priority(settings.priority)
    loop = ControlLoop(slots, settings, parent_pid=args.parent_pid)
    if warning:
        loop._set_text(warning)
        print(f"libfranka_loop: {warning}", file=sys.stderr)
    # Keep the collector off the 1 kHz path: everything allocated so far is permanent.
    gc.collect()
    gc.freeze()
    gc.set_threshold(100_000, 50, 100)
    loop.run()
    slots.close()
    if loop.orphaned:                                # the bridge died without unlinking its slots
        try:
            os.unlink(args.slots)
        except FileNotFoundError:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The libfranka loop process as seen from the bridge (plain Python, no ROS): start, supervise, and
exchange the latest command and the latest state with it.

The 1 kHz loop runs in a process of its own (`libfranka_loop`); this side and the loop share only
latest-value slots (`libfranka_slots`), so nothing the ROS node does can cost the loop a robot cycle.
The loop runs the bridge's SafetyFilter at the robot's rate on every command it gets; this side
forwards commands, reads the latest robot state, and passes on e-stop, teaching and recover
requests (each answered through the state slot).

`fresh_sample()` returns a state only once, and only while the robot is talking: a silent robot
(lost network, a server restart, a loop stuck in libfranka's 1 s UDP timeout) produces no samples,
so joint_states are never republished as fresh. `poll()` supervises the loop process as the bridge
supervises each of its helpers (`child_process.ChildProcess`): one that exits is restarted with
back-off, one whose slots stay unchanged for `stuck_timeout` (`start_timeout` while it starts or
connects) is killed and restarted.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from vla_panda_bridge.backend import JointSample
from vla_panda_bridge.child_process import ChildProcess
from vla_panda_bridge.libfranka_loop import LoopSettings, LoopStatus, Mode
from vla_panda_bridge.libfranka_slots import (
    CONTROL,
    H_DQ,
    H_END,
    H_Q,
    H_STAMP,
    H_TAU,
    HISTORY,
    Slots,
    StateView,
)


@dataclass
class LibfrankaSample(JointSample):
    """A joint state from the robot, with the robot's own end-effector pose (O_T_EE, 4x4)."""

    ee_matrix: np.ndarray | None = None
    cycle: int = 0
    robot_time: float = 0.0      # the robot's own clock (s)


@dataclass
class LibfrankaStatus:
    """What the loop reports, as read on this side."""

    code: LoopStatus             # (OK also while teaching)
    text: str                    # the loop's status text (libfranka's error text on an error)
    filter_code: int             # the safety filter's code of the loop's last cycle
    filter_text: str
    robot_mode: int              # franka RobotMode as an int (-1 before any state)
    success_rate: float          # control_command_success_rate of the last state
    silent_for: float            # s since the last new robot state (inf before the first)
    teaching: bool
    estop_active: bool
    interventions: int
    last_intervention: int
    connects: int
    errors: int
    missed: int
    latency: float               # s from the last command's arrival to the robot command with it
    process: str = ""            # the loop process' supervision note ("" while it runs normally)
    extra: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.code.name

    @property
    def connected(self) -> bool:
        return self.code == LoopStatus.OK and self.silent_for < 0.1


class LoopProcess:
    """One libfranka loop process and its slots; see the module docstring."""

    def __init__(self, settings: LoopSettings, loop_prefix: str | Sequence[str] = "",
                 stuck_timeout: float = 3.0, python: str = sys.executable,
                 clock: Callable[[], float] = time.monotonic):
        """`clock`: monotonic seconds, how long the robot has been silent is measured on (a test's)."""
        self.settings = settings
        self._clock = clock
        self.slots = Slots.create()
        self.slots.control[CONTROL["parent_pid"]] = os.getpid()
        self.child = ChildProcess("libfranka loop", "vla_panda_bridge.libfranka_loop",
                                  ["--slots", self.slots.path, "--settings", settings.to_json(),
                                   "--parent-pid", str(os.getpid())],
                                  prefix=loop_prefix, python=python, stuck_timeout=stuck_timeout, clock=clock)
        self._last_cycle = -1.0
        self._fresh_cycle = -1.0
        self._history_cycle = 0
        self._cycle_seen_at = -math.inf
        self._state: StateView | None = None
        self._texts: dict[str, str] = {}
        self._closed = False
        self.commands_sent = 0

    # ------------------------------------------------------------------------------ the process
    def start(self) -> None:
        """Start the loop process (it connects to the robot on its own and keeps retrying)."""
        self.child.start()

    @property
    def pid(self) -> int | None:
        return self.child.pid

    @property
    def restarts(self) -> int:
        return self.child.restarts

    @property
    def process_note(self) -> str:
        return self.child.note

    def poll(self) -> str:
        """Supervise the loop process; returns a note when something happened to it, else "". While it
        connects, libfranka's connect blocks it (bounded by libfranka): the supervisor is patient."""
        s = self._read()
        connecting = s is None or int(s.status) in (LoopStatus.CONNECTING, LoopStatus.DISCONNECTED)
        return self.child.poll(self.slots.state_seq, patient=connecting)

    # ------------------------------------------------------------------------------- commands
    def submit(self, values: Sequence[float], arrived: float | None = None) -> int:
        """Hand the loop its next command (the loop's filter validates it; a malformed one is treated
        as zero there). `arrived` (monotonic s, default now) is when its input arrived: the loop
        measures the latency to the first robot command with it, once per distinct value. Returns
        its sequence number."""
        self.commands_sent += 1
        # the loop process's own clock (time.monotonic there too), not the injected one
        return self.slots.write_command(values, time.monotonic() if arrived is None else arrived)

    def set_estop(self, active: bool) -> None:
        self.slots.control[CONTROL["estop"]] = float(bool(active))

    def request_recover(self) -> int:
        """Ask the loop for error recovery (or an immediate reconnection); `recover_result` answers."""
        c = self.slots.control
        c[CONTROL["recover_req"]] += 1.0
        return int(c[CONTROL["recover_req"]])

    def recover_result(self, token: int) -> tuple[bool, str] | None:
        """None while the request is pending, else (success, the loop's status text)."""
        s = self._read()
        if s is None or s.recover_ack < token:
            return None
        return bool(s.recover_ok), self._text("status")

    def request_teaching(self, active: bool) -> int:
        c = self.slots.control
        c[CONTROL["teaching"]] = float(bool(active))
        c[CONTROL["teaching_req"]] += 1.0
        return int(c[CONTROL["teaching_req"]])

    def teaching_result(self, token: int) -> bool | None:
        """None while the request is pending, else whether the arm is in teaching mode now."""
        s = self._read()
        if s is None or s.teaching_ack < token:
            return None
        return int(s.mode) == Mode.TORQUE

    # ----------------------------------------------------------------------------------- state
    def _read(self) -> StateView | None:
        s = self.slots.read_state()
        if s is None:
            return self._state                           # the loop is inside a write: the previous one
        if s.pid == 0:
            return None                                  # no loop process has written yet
        self._state = s
        now = self._clock()
        if s.cycle != self._last_cycle:
            self._last_cycle = s.cycle
            self._cycle_seen_at = now
        return s

    def read(self) -> LibfrankaSample | None:
        """The latest robot state (also when it is old), or None before the first."""
        s = self._read()
        if s is None or s.cycle <= 0:
            return None
        return self._sample(s)

    def new_samples(self, every: int = 1, limit: int = HISTORY) -> list[LibfrankaSample]:
        """Every `every`-th robot state (by cycle number) since the previous call, oldest first: none
        is lost while the caller is less than HISTORY states late. Empty while the robot is silent."""
        s = self._read()
        if s is None or s.cycle <= 0:
            return []
        now = int(s.cycle)
        if now < self._history_cycle:                    # a new loop process counts from 0 again
            self._history_cycle = 0
        start = max(self._history_cycle + 1, now - min(limit, HISTORY) + 1)
        start += (-start) % every                        # on the decimation grid
        out = []
        for cycle in range(start, now + 1, every):
            e = self.slots.read_history(cycle)
            if e is not None:
                out.append(LibfrankaSample(e[H_Q:H_DQ], e[H_DQ:H_TAU], e[H_TAU:H_END],
                                           stamp_ns=int(e[H_STAMP] * 1e9), cycle=cycle))
        self._history_cycle = now
        return out

    def external_torque(self) -> np.ndarray | None:
        """The robot's external torque estimate (libfranka's tau_ext_hat_filtered, Nm per joint) in the
        state last read (by `new_samples`, `read`, `status`: no read of its own), or None before the
        first robot state."""
        s = self._state
        return None if s is None or s.cycle <= 0 else s.tau_ext_hat_filtered

    def fresh_sample(self) -> LibfrankaSample | None:
        """The latest robot state if it is newer than the one returned last time, else None."""
        s = self._read()
        if s is None or s.cycle <= 0 or s.cycle == self._fresh_cycle:
            return None
        self._fresh_cycle = s.cycle
        return self._sample(s)

    @staticmethod
    def _sample(s: StateView) -> LibfrankaSample:
        return LibfrankaSample(
            position=s.q, velocity=s.dq, effort=s.tau_J, stamp_ns=int(s.stamp * 1e9),
            ee_matrix=s.O_T_EE.reshape(4, 4).T.copy(), cycle=int(s.cycle), robot_time=s.robot_time,
        )

    def _text(self, which: str) -> str:
        text = self.slots.read_text(which)
        if text is None:
            return self._texts.get(which, "")            # the loop is inside a write: the previous one
        self._texts[which] = text
        return text

    def status(self) -> LibfrankaStatus:
        s = self._read()
        silent = self._clock() - self._cycle_seen_at
        if s is None:
            return LibfrankaStatus(LoopStatus.CONNECTING, "loop process starting",
                                   0, "", -1, 0.0, math.inf, False, False, 0, 0, 0, 0, 0, math.nan,
                                   self.process_note)
        code = LoopStatus(int(s.status))
        return LibfrankaStatus(
            code=code, text=self._text("status"),
            filter_code=int(s.filter_code), filter_text=self._text("filter"),
            robot_mode=int(s.robot_mode) if s.cycle > 0 else -1, success_rate=s.success_rate,
            silent_for=silent, teaching=int(s.mode) == Mode.TORQUE, estop_active=bool(s.estop_active),
            interventions=int(s.interventions), last_intervention=int(s.last_intervention),
            connects=int(s.connects), errors=int(s.errors), missed=int(s.missed), latency=s.latency,
            process=self.process_note,
        )

    # -------------------------------------------------------------------------------- shutdown
    def close(self, timeout: float = 1.5) -> bool:
        """Ask the loop to brake to zero, end the motion and exit; kill it after `timeout`.
        Returns True if it stopped by itself."""
        if self._closed:
            return True
        self._closed = True
        self.slots.control[CONTROL["shutdown"]] = 1.0
        clean = self.child.close(timeout)
        self.slots.close()
        return clean

"""The bridge's helper processes, supervised one way (plain Python, no ROS): the 1 kHz libfranka loop
(`libfranka_process.LoopProcess`) and the Franka Hand's (`libfranka_hand.HandProcess`).

Each runs as `python -m MODULE ARGS` after a prefix (e.g. `ip netns exec NS`), in a session of its own:
a terminal's Ctrl-C (SIGINT to the foreground process group) does not reach it, even while it still
imports; the bridge stops it through its shared-memory slots (`shm.py`, the one way the bridge and its
helpers talk) and it exits by itself when the bridge is gone. `poll(progress)` supervises it: one that
exits is restarted after RESTART_MIN s, doubled up to RESTART_MAX while it keeps failing; one whose
`progress` (its slots' write counter) stays unchanged for `stuck_timeout` is killed and restarted.
Until a started process first makes progress (Python starting, importing), and while the caller says
it may block (`patient`: connecting to the robot), the bound is `start_timeout` instead: at a load
average of 30 the loop process wrote nothing for over 3 s after its start, or inside libfranka's
connect, and a 3 s bound killed every start (and, mid-connect, left franka-sim unable to accept the
next client), so the bridge never connected.
`close(timeout)` waits for it to leave once it was asked to, then kills it.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence

RESTART_MIN = 0.5   # s before restarting a process that exited, doubled up to RESTART_MAX
RESTART_MAX = 10.0
START_TIMEOUT = 30.0   # s a started process may take to make its first progress (only against a hang)


class ChildProcess:
    """One supervised helper process; see the module docstring. `name` is how notes call it."""

    def __init__(self, name: str, module: str, args: Sequence[str], prefix: str | Sequence[str] = "",
                 python: str = sys.executable, stuck_timeout: float | None = 3.0,
                 clock: Callable[[], float] = time.monotonic, start_timeout: float = START_TIMEOUT):
        self.name = name
        self._prefix = shlex.split(prefix) if isinstance(prefix, str) else list(prefix)
        self._cmd = [python, "-m", module, *args]
        self.stuck_timeout = stuck_timeout
        self.start_timeout = start_timeout
        self._clock = clock
        self._proc: subprocess.Popen | None = None
        self._restart_at = 0.0
        self._restart_wait = RESTART_MIN
        self.restarts = 0
        self.note = ""            # what happened to the process ("" while it runs normally)
        self._progress: float | None = None
        self._progress_at = clock()
        self._working = False     # the process made progress since it was started
        self._closed = False

    def start(self) -> None:
        self._proc = subprocess.Popen([*self._prefix, *self._cmd], stdin=subprocess.DEVNULL,
                                      start_new_session=True)
        self._progress_at = self._clock()
        self._working = False

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def poll(self, progress: float, patient: bool = False) -> str:
        """Supervise; `progress` changes while the process works, `patient` while it may block (see
        the module docstring). A note when something happened."""
        if self._proc is None or self._closed:
            return ""
        now = self._clock()
        code = self._proc.poll()
        if code is None:
            self._watch(progress, now)
            starting = patient or not self._working
            limit = self.start_timeout if starting else self.stuck_timeout
            if self.stuck_timeout is not None and now - self._progress_at > limit:
                self._proc.kill()
                self._proc.wait()
                since = " while starting or connecting" if starting else ""
                self.note = (f"the {self.name} process wrote nothing for {limit:g} s{since} and was "
                             "killed; restarting it")
                self._progress = progress          # its last: a restarted one's first write differs
                self._schedule_restart(now)
                return self.note
            return ""
        if self._restart_at == 0.0:
            self._progress = progress              # its last: a restarted one's first write differs
            self.note = f"the {self.name} process exited with code {code}; restarting it"
            self._schedule_restart(now)
            return self.note
        if now >= self._restart_at:
            self._restart_at = 0.0
            self.restarts += 1
            self.start()
            self.note = f"{self.name} process restarted ({self.restarts} restarts)"
            return self.note
        return ""

    def _watch(self, progress: float, now: float) -> None:
        if progress != self._progress:
            self._working = self._progress is not None   # the first value seen is only a baseline
            self._progress = progress
            self._progress_at = now
            if self.note:                      # working again: the next failure waits RESTART_MIN
                self._restart_wait = RESTART_MIN
                self.note = ""

    def _schedule_restart(self, now: float) -> None:
        self._restart_at = now + self._restart_wait
        self._restart_wait = min(2.0 * self._restart_wait, RESTART_MAX)

    def close(self, timeout: float) -> bool:
        """After the process was asked to leave: wait `timeout` s, then kill it. True if it left."""
        self._closed = True
        if self._proc is None or self._proc.poll() is not None:
            return True
        try:
            self._proc.wait(timeout)
            return True
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
            return False

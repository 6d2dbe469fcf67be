"""Process supervision for `vla launch`: start, stream, forward signals, tear down, no orphans.

One thread, one `selectors` loop: child pipes and a signal wake-up pipe are watched together, so
output, exits and Ctrl-C are handled as they happen without polling threads.

- Every child runs in its own process group (a terminal's Ctrl-C reaches only `vla launch`, which
  forwards it) and gets PR_SET_PDEATHSIG=SIGTERM, so it is stopped even if `vla launch` is killed.
  A dead-man reaper (`reaper.py`) SIGKILLs a child that outlives a killed launch by its
  `sigkill_timeout`, which a live launch would have done.
As `ros2 launch` (launch 3.4) does it:
- Every output line of a child, from its stdout or its stderr, is printed to stdout as
  `[<exec>-<n>] line`: the executable's basename (or `exec_name`/`name`) and a counter of the
  processes this launch has started (1, 2, ...; a respawn keeps its process's tag). The launcher's
  own lines go to stdout too, worded as launch 3.4 words them: `[INFO] [talker-1]: process started
  with pid [N]`, `process has finished cleanly [pid N]`, `[ERROR] [talker-1]: process has died [pid
  N, exit code C, cmd '...'].`, `sending signal 'SIGINT' to process[talker-1]`, `[INFO] [launch]:
  process[talker-1] was required: shutting down launched system` (on_exit), `[WARNING] [launch]:
  user interrupted with ctrl-c (SIGINT)`.
- A process that ends, whatever its code, leaves the others running; `respawn` restarts it after
  `respawn_delay` s; `on_exit: shutdown` shuts the launch down. The exit code stays 0.
  `keep_going=False` (harnesses) instead tears down on a non-zero exit and returns that code.
- Shutdown (Ctrl-C, SIGTERM, SIGHUP): the signal goes to every child's group at once, so the stop
  takes as long as the slowest node, not their sum. A node can hang in Fast DDS 2.14's participant
  deletion when the others leave the graph with it (eProsima/Fast-DDS#6513); that is bounded per
  node: SIGTERM after `sigterm_timeout`, SIGKILL after `sigkill_timeout`. Another Ctrl-C (a second
  or more later) escalates every child at once. At the end every child group is SIGKILLed,
  catching stray grandchildren.
- Exit code: 0, unless a process could not start (127), did not stop cleanly at shutdown (its code;
  128 + signal number for a death by signal, a SIGKILL escalation included), or died under
  `keep_going=False`.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TextIO

from vla_launch import reaper

_PR_SET_PDEATHSIG = 1
try:
    _PRCTL = ctypes.CDLL(None, use_errno=True).prctl
except (OSError, AttributeError):  # not Linux
    _PRCTL = None

_REPEAT_DEBOUNCE_S = 1.0
_SHUTTING_DOWN = "shutting down launched system"
_CLEAN_STOP_CODES = {0, -signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGINT, 128 + signal.SIGTERM}


@dataclass
class ProcessSpec:
    label: str
    cmd: list[str]
    env: dict[str, str | None] = field(default_factory=dict)  # overrides; None unsets
    cwd: str | None = None
    on_exit_shutdown: bool = False
    respawn: bool = False
    respawn_delay: float = 0.0
    sigterm_timeout: float | None = None
    sigkill_timeout: float | None = None
    exec_name: str | None = None  # the output tag's stem (ros2 launch: the executable's basename)


@dataclass
class _Child:
    spec: ProcessSpec
    popen: subprocess.Popen
    tag: str
    fds: dict[int, bool] = field(default_factory=dict)  # fd -> is stderr
    partial: dict[int, bytearray] = field(default_factory=dict)
    stage: int = 0  # 0 running, 1 SIGINT sent, 2 SIGTERM sent, 3 SIGKILL sent
    deadline: float | None = None

    @property
    def pid(self) -> int:
        return self.popen.pid


def _signal_name(num: int) -> str:
    try:
        return signal.Signals(num).name
    except ValueError:
        return f"signal {num}"


def _interrupted(sig: int) -> str:
    """What launch says on a signal to itself (it has words for Ctrl-C; the others are said alike)."""
    return "user interrupted with ctrl-c (SIGINT)" if sig == signal.SIGINT else \
        f"user interrupted with {_signal_name(sig)}"


def _preexec(parent_pid: int):
    def setup() -> None:  # runs in the child between fork and exec
        # the stop is our SIGINT (then SIGTERM): a child must hear both even where the caller ignores
        # them (`nohup`, a `&` job of a script), as a disposition of SIG_IGN survives exec
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        if _PRCTL is not None:
            _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # the parent died before prctl took effect
            os._exit(1)
    return setup


class Launcher:
    """Runs a list of processes until they end or a shutdown; `run()` returns the exit code."""

    def __init__(self, specs: list[ProcessSpec], *, sigterm_timeout: float = 5.0,
                 sigkill_timeout: float = 5.0, keep_going: bool = True,
                 stdout: TextIO | None = None, stderr: TextIO | None = None,
                 env: Mapping[str, str] | None = None, use_reaper: bool = True) -> None:
        self.specs = specs
        self.sigterm_timeout = sigterm_timeout
        self.sigkill_timeout = sigkill_timeout
        self.keep_going = keep_going
        self.out = stdout or sys.stdout
        self.err = stderr or sys.stderr
        self.env = dict(os.environ if env is None else env)  # the children's base environment
        self.use_reaper = use_reaper
        self.children: list[_Child] = []
        self.all_pids: list[int] = []
        self.labels: dict[int, str] = {}  # pid -> label, of every process started
        self.tags: dict[int, str] = {}  # pid -> output tag (`exec-n`), of every process started
        self.failures: list[tuple[str, int]] = []
        self.ended: list[tuple[str, int]] = []  # (label, exit code) of every process that ended
        self.shutting_down = False
        self._reaper: subprocess.Popen | None = None
        self._signals: list[int] = []
        self._last_escalation = 0.0
        self._wake_w: int | None = None
        self._respawns: list[tuple[float, ProcessSpec, str]] = []  # (when, spec, its tag)
        self._count = 0  # processes started, for the `exec-n` tags
        self._sel = selectors.DefaultSelector()

    # -------------------------------------------------------------------------------- output
    def _write(self, stream: TextIO, text: str) -> None:
        try:
            stream.write(text)
            stream.flush()
        except (BrokenPipeError, ValueError):
            pass

    def log(self, msg: str, error: bool = False, source: str = "launch", level: str | None = None) -> None:
        """A line of the launcher's own, as launch's loggers write it: `[LEVEL] [source]: msg`."""
        self._write(self.out, f"[{level or ('ERROR' if error else 'INFO')}] [{source}]: {msg}\n")

    def _emit(self, child: _Child, fd: int, data: bytes, final: bool = False) -> None:
        buf = child.partial.setdefault(fd, bytearray())
        buf += data
        *lines, rest = bytes(buf).split(b"\n")
        if final and rest or len(rest) > 65536:
            lines.append(rest)
            rest = b""
        child.partial[fd] = bytearray(rest)
        for line in lines:
            self._write(self.out, f"[{child.tag}] {line.decode('utf-8', 'replace').rstrip(chr(13))}\n")

    def _read(self, child: _Child, fd: int, drain: bool = False) -> None:
        """Read what is available; on EOF (or `drain`), flush and stop watching the fd."""
        while True:
            try:
                data = os.read(fd, 65536)
            except BlockingIOError:
                if drain:
                    break
                return
            except OSError:
                data = b""
            if not data:
                break
            self._emit(child, fd, data)
            if not drain:
                return
        self._emit(child, fd, b"", final=True)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(fd)
        os.close(fd)
        child.fds.pop(fd, None)

    # --------------------------------------------------------------------------------- start
    def _start(self, spec: ProcessSpec, tag: str | None = None) -> None:
        """Start `spec`; a respawn passes the tag of the process it replaces (launch keeps it)."""
        if tag is None:
            self._count += 1
            tag = f"{spec.exec_name or spec.label}-{self._count}"
        env = dict(self.env)
        env.setdefault("PYTHONUNBUFFERED", "1")
        for k, v in spec.env.items():
            if v is None:
                env.pop(k, None)
            else:
                env[k] = v
        try:
            popen = subprocess.Popen(
                spec.cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                env=env, cwd=spec.cwd, close_fds=True, process_group=0, preexec_fn=_preexec(os.getpid()))
        except (OSError, subprocess.SubprocessError) as e:
            self.log(f"exception occurred while executing process: {e}", error=True, source=tag)
            self.failures.append((spec.label, 127))
            if not self.keep_going:
                self.begin_shutdown(signal.SIGINT, f"process[{tag}] failed to start: {_SHUTTING_DOWN}")
            return
        child = _Child(spec, popen, tag)
        for stream, is_err in ((popen.stdout, False), (popen.stderr, True)):
            fd = os.dup(stream.fileno())
            stream.close()
            os.set_blocking(fd, False)
            child.fds[fd] = is_err
            self._sel.register(fd, selectors.EVENT_READ, (child, fd))
        self.children.append(child)
        self.all_pids.append(child.pid)
        self.labels[child.pid] = spec.label
        self.tags[child.pid] = child.tag
        self._tell_reaper(f"{child.pid} {self._grace(spec):g}")
        self.log(f"process started with pid [{child.pid}]", source=child.tag)

    # ---------------------------------------------------------------------------------- reaper
    def _grace(self, spec: ProcessSpec) -> float:
        """How long a child may outlive a killed launch (its SIGTERM) before the reaper kills it."""
        return self.sigkill_timeout if spec.sigkill_timeout is None else spec.sigkill_timeout

    def _start_reaper(self) -> None:
        if not self.use_reaper:
            return
        try:
            self._reaper = subprocess.Popen(
                [sys.executable, "-I", "-S", reaper.__file__], stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL, stderr=self._fileno(self.err), close_fds=True,
                process_group=0, text=True)
        except OSError as e:
            self.log(f"cannot start the reaper ({e}); a child may outlive a killed launch", error=True)

    @staticmethod
    def _fileno(stream: TextIO) -> int | None:
        try:
            return stream.fileno()
        except (AttributeError, OSError, ValueError):  # e.g. io.StringIO
            return subprocess.DEVNULL

    def _tell_reaper(self, line: str) -> None:
        if self._reaper is None:
            return
        try:
            self._reaper.stdin.write(line + "\n")
            self._reaper.stdin.flush()
        except (OSError, ValueError):
            self._reaper = None

    def _stop_reaper(self) -> None:
        if self._reaper is None:
            return
        self._tell_reaper("exit")
        with contextlib.suppress(OSError, ValueError):
            self._reaper.stdin.close()
        try:
            self._reaper.wait(5.0)
        except subprocess.TimeoutExpired:
            self._reaper.kill()
            self._reaper.wait()
        self._reaper = None

    # ------------------------------------------------------------------------------ shutdown
    def _send(self, child: _Child, sig: int) -> None:
        if child.popen.poll() is None:
            self.log(f"sending signal '{_signal_name(sig)}' to process[{child.tag}]", source=child.tag)
        try:
            os.killpg(child.pid, sig)
        except (ProcessLookupError, PermissionError):  # the child left its group (setsid)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(child.pid, sig)
        now = time.monotonic()
        if sig == signal.SIGINT:
            child.stage = 1
            t = child.spec.sigterm_timeout
            child.deadline = now + (self.sigterm_timeout if t is None else t)
        elif sig == signal.SIGTERM:
            child.stage = 2
            t = child.spec.sigkill_timeout
            child.deadline = now + (self.sigkill_timeout if t is None else t)
        else:
            child.stage = 3
            child.deadline = None

    def _escalate(self, child: _Child, timed_out: bool) -> None:
        """The next signal to `child`: at its deadline (said as launch says it) or on a repeated Ctrl-C."""
        nxt = {0: signal.SIGTERM, 1: signal.SIGTERM, 2: signal.SIGKILL}.get(child.stage)
        if nxt is None:
            return
        if timed_out and child.stage:
            term = self.sigterm_timeout if child.spec.sigterm_timeout is None else child.spec.sigterm_timeout
            kill = self.sigkill_timeout if child.spec.sigkill_timeout is None else child.spec.sigkill_timeout
            after, got = (term, "SIGINT") if child.stage == 1 else (term + kill, "SIGTERM")
            self.log(f"process[{child.tag}] failed to terminate '{after:g}' seconds after receiving "
                     f"'{got}', escalating to '{_signal_name(nxt)}'", error=True, source=child.tag)
        self._send(child, nxt)

    def begin_shutdown(self, first_signal: int, reason: str) -> None:
        """Signal every child at once (each one's escalation runs on its own deadlines)."""
        if self.shutting_down:
            return
        self.shutting_down = True
        self._respawns.clear()
        self.log(reason, level="WARNING" if reason.startswith("user interrupted") else "INFO")
        for child in self.children:
            self._send(child, first_signal)

    def _on_signal(self, signum: int, frame: object) -> None:
        self._signals.append(signum)

    def _handle_signals(self) -> None:
        while self._signals:
            sig = self._signals.pop(0)
            if sig == signal.SIGCHLD:
                continue
            now = time.monotonic()
            if not self.shutting_down:
                first = signal.SIGINT if sig == signal.SIGINT else signal.SIGTERM
                self.begin_shutdown(first, _interrupted(sig))
                self._last_escalation = now
            elif now - self._last_escalation >= _REPEAT_DEBOUNCE_S:
                # A repeated Ctrl-C escalates; one signal delivered twice (e.g. by `timeout`, which
                # signals the child and then its own group) must not.
                self._last_escalation = now
                self.log(f"{_interrupted(sig)} again: escalating", level="WARNING")
                for child in self.children:
                    self._escalate(child, timed_out=False)

    # ------------------------------------------------------------------------------- exits
    def _reap(self) -> None:
        for child in list(self.children):
            rc = child.popen.poll()
            if rc is None:
                continue
            for fd in list(child.fds):
                self._read(child, fd, drain=True)
            self.children.remove(child)
            self._on_exit(child, rc)

    def _on_exit(self, child: _Child, rc: int) -> None:
        """Say how `child` ended as launch says it (a signal is a negative exit code there too)."""
        spec = child.spec
        self.ended.append((spec.label, rc))
        if rc == 0:
            self.log(f"process has finished cleanly [pid {child.pid}]", source=child.tag)
        else:
            self.log(f"process has died [pid {child.pid}, exit code {rc}, cmd '{' '.join(spec.cmd)}'].",
                     error=True, source=child.tag)
        if self.shutting_down:
            if child.stage == 3 or rc not in _CLEAN_STOP_CODES:
                self.failures.append((spec.label, rc))
            return
        if rc != 0 and not self.keep_going and not spec.respawn:
            self.failures.append((spec.label, rc))
        if spec.respawn:
            self._respawns.append((time.monotonic() + spec.respawn_delay, spec, child.tag))
        elif spec.on_exit_shutdown:
            self.begin_shutdown(signal.SIGINT, f"process[{child.tag}] was required: {_SHUTTING_DOWN}")
        elif rc != 0 and not self.keep_going:
            self.begin_shutdown(signal.SIGINT, f"process[{child.tag}] has died: {_SHUTTING_DOWN}")

    def exit_code(self) -> int:
        if not self.failures:
            return 0
        rc = self.failures[0][1]
        if rc < 0:
            return min(128 - rc, 255)
        return min(rc, 255) if rc > 0 else 1

    # -------------------------------------------------------------------------------- loop
    def _loop(self, wake_fd: int) -> None:
        while True:
            self._handle_signals()
            now = time.monotonic()
            for child in self.children:
                if child.deadline is not None and now >= child.deadline:
                    self._escalate(child, timed_out=True)
            due = [r for r in self._respawns if r[0] <= now]
            for r in due:
                self._respawns.remove(r)
                if not self.shutting_down:
                    self._start(r[1], tag=r[2])
            if not self.children and not self._respawns:
                return
            waits = [c.deadline - now for c in self.children if c.deadline is not None]
            waits += [t - now for t, _, _ in self._respawns]
            timeout = max(0.0, min([0.5] + waits))
            for key, _ in self._sel.select(timeout):
                if key.data is None:
                    with contextlib.suppress(BlockingIOError):
                        while os.read(wake_fd, 512):
                            pass
                else:
                    child, fd = key.data
                    if fd in child.fds:
                        self._read(child, fd)
            self._reap()

    def stop(self) -> None:
        """Ask a running launcher to shut down, as Ctrl-C would (safe from any thread)."""
        self._signals.append(signal.SIGINT)
        if self._wake_w is not None:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"\0")

    def run(self) -> int:
        """Start everything and supervise until all processes have ended; returns the exit code.

        In the main thread it also handles SIGINT/SIGTERM/SIGHUP; in another thread use `stop()`.
        """
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_r, False)
        os.set_blocking(wake_w, False)
        self._wake_w = wake_w
        self._sel.register(wake_r, selectors.EVENT_READ, None)
        in_main = threading.current_thread() is threading.main_thread()
        old_wakeup, old = -1, {}
        if in_main:
            old_wakeup = signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
            old = {s: signal.signal(s, self._on_signal)
                   for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD)}
        try:
            self._start_reaper()
            for spec in self.specs:
                self._handle_signals()
                if self.shutting_down:
                    break
                self._start(spec)
            self._loop(wake_r)
        finally:
            for child in self.children:  # only after an exception: do not leave anything behind
                self._send(child, signal.SIGKILL)
                child.popen.wait()
            for pid in self.all_pids:  # stray grandchildren left in our children's groups
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(pid, signal.SIGKILL)
            self._stop_reaper()
            if in_main:
                for s, h in old.items():
                    signal.signal(s, h)
                signal.set_wakeup_fd(old_wakeup)
            self._wake_w = None
            self._sel.close()
            os.close(wake_r)
            os.close(wake_w)
        return self.exit_code()

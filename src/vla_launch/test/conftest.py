"""Fixtures of the launch tool tests: `vla launch` as a subprocess, its output, its children's pids."""
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

VLA = [sys.executable, "-m", "vla_launch.cli"]
STARTED = re.compile(r"process started with pid \[(\d+)\]")


class LaunchRun:
    """`vla launch ...` in the background; every output line is kept with its stream."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(VLA + ["launch", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.lines: list[tuple[str, str]] = []
        self._closed = 0
        self._q: queue.Queue = queue.Queue()
        for stream, name in ((self.proc.stdout, "out"), (self.proc.stderr, "err")):
            threading.Thread(target=self._pump, args=(stream, name), daemon=True).start()

    def _pump(self, stream, name: str) -> None:
        for line in stream:
            self._q.put((name, line.rstrip("\n")))
        self._q.put((name, None))

    def _drain(self, timeout: float) -> bool:
        try:
            item = self._q.get(timeout=timeout)
        except queue.Empty:
            return False
        if item[1] is None:
            self._closed += 1
        else:
            self.lines.append(item)
        return True

    def wait_for(self, pattern: str, timeout: float = 30.0, count: int = 1) -> list[re.Match]:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while True:
            found = [m for _, line in self.lines if (m := rx.search(line))]
            if len(found) >= count:
                return found
            if time.monotonic() > deadline:
                raise AssertionError(f"no {count}x {pattern!r} in {timeout} s; output:\n{self.text()}")
            self._drain(0.1)

    def finish(self, timeout: float = 30.0) -> int:
        rc = self.proc.wait(timeout=timeout)
        while self._closed < 2 and self._drain(5.0):
            pass
        return rc

    def send(self, sig: int = signal.SIGINT) -> None:
        self.proc.send_signal(sig)

    def text(self, stream: str | None = None) -> str:
        return "\n".join(line for s, line in self.lines if stream in (None, s))

    def child_pids(self) -> list[int]:
        return [int(m.group(1)) for _, line in self.lines if (m := STARTED.search(line))]

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def alive(pid: int) -> bool:
    """True if pid exists and is not a zombie (orphans of a killed launch may wait for pid 1)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def wait_dead(pids: list[int], timeout: float = 10.0) -> list[int]:
    """The pids still alive after `timeout`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = [p for p in pids if alive(p)]
        if not left:
            return []
        time.sleep(0.05)
    return [p for p in pids if alive(p)]


def kill_all(pids: list[int]) -> None:
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass


class _Launcher:
    """The `launch` fixture: start runs with `launch(*args)`; every run and child is killed at teardown."""

    alive = staticmethod(alive)
    wait_dead = staticmethod(wait_dead)

    def __init__(self) -> None:
        self.runs: list[LaunchRun] = []

    def __call__(self, *args: str) -> LaunchRun:
        run = LaunchRun(*args)
        self.runs.append(run)
        return run

    def cleanup(self) -> None:
        for run in self.runs:
            run.kill()
            kill_all(run.child_pids())


@pytest.fixture
def launch():
    launcher = _Launcher()
    yield launcher
    launcher.cleanup()


@pytest.fixture
def fixtures_dir():
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "fixtures")

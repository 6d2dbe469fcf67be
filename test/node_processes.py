"""Node processes for the top-level tests that start installed nodes: one session (process group) per
node, output to a log file, stopped with SIGINT (a node's clean stop) and then SIGTERM / SIGKILL.

`close()` kills whatever is still running, so a failing test leaves no process behind.
"""
from __future__ import annotations

import os
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path


@dataclass
class NodeProcess:
    label: str
    popen: subprocess.Popen
    log_path: Path

    def alive(self) -> bool:
        return self.popen.poll() is None

    def tail(self, lines: int = 25) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def signal_group(self, signum: int) -> None:
        try:
            os.killpg(self.popen.pid, signum)
        except ProcessLookupError:
            pass


class NodeProcesses:
    """Starts commands as node processes and stops them, in reverse start order."""

    def __init__(self, log_dir: Path, env: dict[str, str]) -> None:
        self.log_dir = Path(log_dir)
        self.env = env
        self.procs: dict[str, NodeProcess] = {}

    def start(self, label: str, argv: list[str], env: dict[str, str] | None = None) -> NodeProcess:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log_path = self.log_dir / f"{label}.log"
        with open(log_path, "ab") as log:  # the child keeps its own copy of the descriptor
            popen = subprocess.Popen(argv, env=env or self.env, stdin=subprocess.DEVNULL, stdout=log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        proc = NodeProcess(label, popen, log_path)
        self.procs[label] = proc
        return proc

    def stop(self, label: str, timeout: float = 10.0) -> int | None:
        """SIGINT, then SIGTERM and SIGKILL each after `timeout` s; the exit code (negative: a signal)."""
        proc = self.procs[label]
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if not proc.alive():
                break
            proc.signal_group(signum)
            try:
                proc.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                continue
        proc.signal_group(signal.SIGKILL)  # grandchildren left in the group
        return proc.popen.returncode

    def stop_all(self, timeout: float = 10.0) -> dict[str, int | None]:
        return {label: self.stop(label, timeout) for label in reversed(list(self.procs))}

    def describe(self) -> str:
        """Every process's state and last log lines, for assertion messages."""
        parts = []
        for p in self.procs.values():
            state = "running" if p.alive() else f"exit code {p.popen.returncode}"
            parts.append(f"--- {p.label} ({state}), {p.log_path}:\n{p.tail()}")
        return "\n".join(parts)

    def close(self) -> None:
        self.stop_all(timeout=3.0)

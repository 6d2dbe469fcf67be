"""A Ray cluster of several nodes on this machine, for tests: each node a `ray start --block` process of
its own (its own process group, temp dir and ports, one CPU), joined with a token of the test's own.

Stopped by killing those process groups, never with `ray stop` (which ends every Ray on the machine,
other sessions' included). Each node waits for "Ray runtime started" in its output, a condition, with
a generous bound only against a hang.
"""
from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

START_TIMEOUT_S = 240.0  # a node's start on a loaded 2-core machine (30 s seen at load 20)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # this node's processes, and only them
    except ProcessLookupError:
        pass
    proc.wait(30)


class RayCluster:
    """`with RayCluster(2) as c:` gives `c.address` and `c.env` (the environment a driver joins with)."""

    def __init__(self, nodes: int = 2, cpus: int = 1) -> None:
        self.n, self.cpus = nodes, cpus
        self.port = free_port()
        self.env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16),
                        RAY_USAGE_STATS_ENABLED="0")
        self.procs: list[subprocess.Popen] = []
        self.dirs: list[Path] = []

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def _command(self, temp: Path, i: int) -> list[str]:
        ports = {f"--{p}-port": free_port() for p in ("node-manager", "object-manager", "metrics-export",
                                                        "runtime-env-agent", "dashboard-agent-listen",
                                                        "dashboard-agent-grpc")}
        first = 20000 + (self.port % 200) * 100 + 40 * i  # a worker-port range of this node's own
        cmd = ["ray", "start", "--block", f"--num-cpus={self.cpus}", "--num-gpus=0", "--disable-usage-stats",
               f"--temp-dir={temp}", "--object-store-memory=150000000",
               f"--min-worker-port={first}", f"--max-worker-port={first + 39}",
               *(f"{k}={v}" for k, v in ports.items())]
        if i == 0:
            return cmd + ["--head", f"--port={self.port}", "--include-dashboard=false"]
        return cmd + [f"--address={self.address}"]

    def _start_node(self, i: int, tries: int = 5) -> None:
        """Ray gives its raylet 30 s to register (hard-coded); a node that misses it on a loaded
        machine is started again, up to `tries` times."""
        for attempt in range(tries):
            try:
                return self._start_node_once(i)
            except RuntimeError:
                proc = self.procs.pop()
                _kill_group(proc)
                if attempt == tries - 1:
                    raise

    def _start_node_once(self, i: int) -> None:
        temp = Path(tempfile.mkdtemp(prefix="vray", dir="/tmp"))  # short: Unix socket paths live here
        self.dirs.append(temp)
        out = open(temp / "node.log", "w")
        proc = subprocess.Popen(self._command(temp, i), env=self.env, stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.procs.append(proc)
        deadline = time.monotonic() + START_TIMEOUT_S
        while "Ray runtime started" not in (temp / "node.log").read_text():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"Ray node {i} did not start:\n{(temp / 'node.log').read_text()[-3000:]}")
            time.sleep(0.2)  # polling the node's own output for the line that says it is up

    def __enter__(self) -> RayCluster:
        try:
            for i in range(self.n):
                self._start_node(i)
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        for proc in reversed(self.procs):
            _kill_group(proc)
        self.procs.clear()
        for d in self.dirs:
            shutil.rmtree(d, ignore_errors=True)

    def leftover(self) -> list[str]:
        """Processes still running that belong to this cluster (named by its temp dirs)."""
        out = subprocess.run(["pgrep", "-af", "|".join(str(d) for d in self.dirs)], capture_output=True,
                             text=True).stdout
        return [ln for ln in out.splitlines() if "pgrep" not in ln]

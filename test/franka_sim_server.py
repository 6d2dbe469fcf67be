"""franka-sim (the libfranka-protocol FR3 simulator) in a private network namespace: test support for
the franka-sim tests and bench/bench_libfranka.py, not part of any package. Plain Python; starts
processes, imports nothing of franka-sim (it lives in its own venv, .venv-franka-sim, made by
scripts/setup_franka_sim.sh).

franka-sim binds 0.0.0.0:1337 and pylibfranka only ever connects to port 1337, so each server gets a
network namespace of its own with only `lo` in it: nothing outside can reach it, and concurrent test
runs do not collide. The loop process joins the same namespace through `prefix()` (the bridge's
`loop_prefix`). Needs root (or CAP_NET_ADMIN) and iproute2; `unavailable()` says what is missing.
"""

from __future__ import annotations

import itertools
import os
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

READY_LINE = "ready for new client"
_names = itertools.count()


def sim_venv() -> Path:
    """$FRANKA_SIM_VENV, else .venv-franka-sim in the repository this file is in."""
    env = os.environ.get("FRANKA_SIM_VENV")
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        if (parent / "scripts" / "setup_franka_sim.sh").exists():
            return parent / ".venv-franka-sim"
    return Path.cwd() / ".venv-franka-sim"


def unavailable() -> str | None:
    """Why a franka-sim server and a pylibfranka client cannot run here, or None if they can."""
    try:
        import pylibfranka  # noqa: F401
    except ImportError:
        return "pylibfranka==0.21.3 is not installed in this venv"
    venv = sim_venv()
    if not (venv / "bin" / "run-franka-sim-server").exists():
        return f"franka-sim is not installed in {venv} (run scripts/setup_franka_sim.sh)"
    if not (venv / "fr3_mjcf" / "fr3.xml").exists():
        return f"{venv}/fr3_mjcf/fr3.xml is missing (run scripts/setup_franka_sim.sh)"
    if shutil.which("ip") is None:
        return "iproute2 ('ip') is not installed: no private network namespace for franka-sim"
    name = f"vla-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot create a network namespace ({made.stderr.strip()}): needs root or CAP_NET_ADMIN"
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return None


class Netns:
    """A private network namespace with only `lo` up; removed on close."""

    def __init__(self, name: str | None = None):
        self.name = name or f"vla-fsim-{os.getpid()}-{next(_names)}"
        subprocess.run(["ip", "netns", "add", self.name], check=True, capture_output=True)
        subprocess.run(["ip", "netns", "exec", self.name, "ip", "link", "set", "lo", "up"], check=True,
                       capture_output=True)

    def prefix(self) -> list[str]:
        return ["ip", "netns", "exec", self.name]

    def close(self) -> None:
        subprocess.run(["ip", "netns", "del", self.name], capture_output=True)


class FrankaSimServer:
    """One run-franka-sim-server in `netns`; `start()` waits until it accepts a client.
    Flags: enforce_motion_limits / enforce_comm_constraints abort motions as the FCI does; `gripper`
    serves franka-sim's own Franka Hand on TCP 1338 (its kinematic model: a command sets the width at
    once), with a virtual object `gripper_object_width` m wide between the fingers (None: nothing to
    grasp); without it the server runs --no-gripper."""

    def __init__(self, netns: Netns, enforce_motion_limits: bool = True,
                 enforce_comm_constraints: bool = False, log_dir: str | None = None, priority: int = 0,
                 gripper: bool = False, gripper_object_width: float | None = None):
        self.netns = netns
        self.priority = priority        # SCHED_FIFO (chrt -f): keeps its 1 kHz on a loaded machine
        self.venv = sim_venv()
        hand = [] if gripper else ["--no-gripper"]
        if gripper and gripper_object_width is not None:
            hand = ["--gripper-object-width", repr(float(gripper_object_width))]
        self.flags = [*hand, ("--" if enforce_motion_limits else "--no-") + "enforce-motion-limits",
                      ("--" if enforce_comm_constraints else "--no-") + "enforce-comm-constraints"]
        self.log_dir = log_dir or tempfile.mkdtemp(prefix="franka-sim-")
        self.proc: subprocess.Popen | None = None
        self.log_path = ""
        self.starts = 0

    def start(self, timeout: float = 30.0) -> None:
        self.starts += 1
        self.log_path = os.path.join(self.log_dir, f"server-{self.starts}.log")
        env = dict(os.environ, FR3_MJCF=str(self.venv / "fr3_mjcf" / "fr3.xml"))
        # The server's venv has its own Python: do not hand it this one's paths.
        for key in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV"):
            env.pop(key, None)
        with open(self.log_path, "w") as log:
            chrt = ["chrt", "-f", str(self.priority)] if self.priority > 0 else []
            self.proc = subprocess.Popen(
                [*self.netns.prefix(), *chrt, str(self.venv / "bin" / "run-franka-sim-server"), *self.flags],
                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if READY_LINE in self.log():
                return
            if self.proc.poll() is not None:
                code = self.proc.returncode
                raise RuntimeError(f"franka-sim exited with code {code}:\n{self.log()[-2000:]}")
            time.sleep(0.025)
        self.stop()
        raise RuntimeError(f"franka-sim not ready after {timeout:g} s:\n{self.log()[-2000:]}")

    def log(self) -> str:
        try:
            with open(self.log_path, errors="replace") as f:
                return f.read()
        except FileNotFoundError:
            return ""

    def kill(self) -> None:
        """SIGKILL (the robot vanishes without closing the connection)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait()

    def stop(self, timeout: float = 5.0) -> None:
        """SIGINT (clean shutdown), SIGKILL after `timeout`."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()


@contextmanager
def running(enforce_comm_constraints: bool = True, priority: int = 50, gripper: bool = False,
            gripper_object_width: float | None = None) -> Iterator[FrankaSimServer]:
    """A started server in a private network namespace (motion limits enforced; with `gripper`, its
    hand server too, see FrankaSimServer), stopped and the namespace removed after; skips, or fails
    where VLA_REQUIRE_FRANKA_SIM=1, when it cannot run."""
    from require import missing

    reason = unavailable()
    if reason:
        missing("FRANKA_SIM", reason)
    ns = Netns()
    server = FrankaSimServer(ns, enforce_motion_limits=True,
                             enforce_comm_constraints=enforce_comm_constraints, priority=priority,
                             gripper=gripper, gripper_object_width=gripper_object_width)
    try:
        server.start()
        yield server
    finally:
        server.stop()
        ns.close()

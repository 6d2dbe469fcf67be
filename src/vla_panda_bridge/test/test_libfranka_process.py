"""The loop process as the bridge runs it (real pylibfranka, no robot: a private network namespace in
which nothing listens, so every connection is refused at once): it reports the refusal and retries,
a loop process that dies is restarted, and one whose bridge dies exits and removes the slots."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from franka_sim_server import Netns
from require import missing
from vla_panda_bridge.libfranka_loop import LoopSettings, LoopStatus
from vla_panda_bridge.libfranka_process import LoopProcess
from vla_panda_bridge.libfranka_slots import Slots

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def netns():
    try:
        import pylibfranka  # noqa: F401
    except ImportError:
        missing("FRANKA_SIM", "pylibfranka==0.21.3 is not installed")
    try:
        ns = Netns()
    except (OSError, subprocess.CalledProcessError) as exc:
        missing("NETNS", f"no network namespace: {exc}")
    yield ns
    ns.close()


def _settings() -> LoopSettings:
    return LoopSettings(robot={"robot_ip": "127.0.0.1", "realtime": "ignore"})


def _wait(cond, timeout: float = 20.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def test_a_refused_connection_is_reported_and_a_dead_loop_restarted(netns):
    p = LoopProcess(_settings(), loop_prefix=netns.prefix())
    p.start()
    try:
        assert _wait(lambda: "Connection to FCI refused" in p.status().text), p.status()
        assert p.status().code == LoopStatus.CONNECTING and p.read() is None
        first = p.pid
        os.kill(first, signal.SIGKILL)
        assert _wait(lambda: "exited" in p.poll())
        assert _wait(lambda: "restarted" in p.poll())
        assert p.pid != first and p.restarts == 1
        assert _wait(lambda: "Connection to FCI refused" in p.status().text and p.poll() == "")
    finally:
        # It leaves by itself when asked; the bound only against a hang: a loop without real-time
        # priority (none here) took over the bridge's 1.5 s to exit at load 45 (the bridge then kills it)
        assert p.close(timeout=20.0)


_BRIDGE = """
import sys, time
from vla_panda_bridge.libfranka_loop import LoopSettings
from vla_panda_bridge.libfranka_process import LoopProcess
from vla_panda_bridge.libfranka_slots import Slots
p = LoopProcess(LoopSettings(robot={"robot_ip": "127.0.0.1", "realtime": "ignore"}), loop_prefix=sys.argv[1:])
p.start()
print(p.pid, p.slots.path, flush=True)
time.sleep(600)
"""


def test_a_loop_whose_bridge_died_exits_and_removes_the_slots(netns):
    bridge = subprocess.Popen([sys.executable, "-c", _BRIDGE, *netns.prefix()], stdout=subprocess.PIPE,
                              text=True)
    try:
        pid, path = bridge.stdout.readline().split()
        pid = int(pid)
        assert os.path.exists(path)
        view = Slots.attach(path)
        try:                                               # the loop is up, retrying its connection
            assert _wait(lambda: (s := view.read_state()) is not None and int(s.pid) == pid
                         and int(s.status) == LoopStatus.CONNECTING)
        finally:
            view.close()
        bridge.kill()
        bridge.wait()

        def gone() -> bool:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return True
            return False
        assert _wait(gone, 10.0)
        assert not os.path.exists(path)
    finally:
        if bridge.poll() is None:
            bridge.kill()

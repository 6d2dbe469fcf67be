"""`driver: auto` with the real pylibfranka (and panda-py) against a fake FCI that answers the Connect
handshake with "incompatible version": the driver is chosen from the protocol the robot names, and an
unknown one is refused naming it. Client and fake run in a private network namespace (pylibfranka
always connects to port 1337). Skipped where namespaces or pylibfranka are missing."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
from franka_sim_server import Netns
from require import missing

pytestmark = pytest.mark.slow

# Answers every Connect on 127.0.0.1:1337 with status kIncompatibleLibraryVersion and `version`
# (libfranka's header: command, command_id, size as uint32; response: status uint8, version uint16).
FAKE_FCI = """
import socket, struct, sys
version = int(sys.argv[1])
srv = socket.socket()
srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
srv.bind(("127.0.0.1", 1337))
srv.listen(4)
print("listening", flush=True)
while True:
    conn, _ = srv.accept()
    data = b""
    while len(data) < 16:
        chunk = conn.recv(16 - len(data))
        if not chunk:
            break
        data += chunk
    if len(data) == 16:
        command, command_id, size = struct.unpack("<III", data[:12])
        conn.sendall(struct.pack("<III", command, command_id, 15) + struct.pack("<BH", 1, version))
    conn.close()
"""

CLIENT = """
import json
from vla_panda_bridge.libfranka_driver import DriverSettings, RobotError
from vla_panda_bridge.libfranka_open import open_driver
try:
    d = open_driver("auto", DriverSettings(robot_ip="127.0.0.1"))
    print(json.dumps({"driver": d.name}))
except RobotError as exc:
    print(json.dumps({"kind": exc.kind, "text": exc.text}))
"""


def _available() -> str | None:
    try:
        import panda_py  # noqa: F401
        import pylibfranka  # noqa: F401
    except ImportError as exc:
        return f"{exc.name} is not installed"
    try:
        Netns().close()
    except (OSError, subprocess.CalledProcessError) as exc:
        return f"no network namespace: {exc}"
    return None


def _auto_against(version: int) -> dict:
    ns = Netns()
    fake = subprocess.Popen([*ns.prefix(), sys.executable, "-c", FAKE_FCI, str(version)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert fake.stdout.readline().strip() == "listening"
        t0 = time.monotonic()
        out = subprocess.run([*ns.prefix(), sys.executable, "-c", CLIENT], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 0, out.stderr
        result = json.loads(out.stdout.strip().splitlines()[-1])
        result["seconds"] = time.monotonic() - t0
        return result
    finally:
        fake.kill()
        fake.wait()
        ns.close()


@pytest.fixture(scope="module")
def ready():
    reason = _available()
    if reason:
        missing("FRANKA_SIM", reason)


def test_a_robot_answering_with_the_pandas_protocol_gets_panda_py(ready):
    r = _auto_against(5)
    # The fake refuses everyone, so panda-py fails too, with its own message: it was the one auto
    # picked after pylibfranka heard "5".
    assert r["kind"] == "fatal"
    assert "IncompatibleVersionError" in r["text"] and "panda-py" in r["text"], r["text"]


def test_an_unknown_protocol_is_refused_naming_it(ready):
    r = _auto_against(7)
    assert r["kind"] == "fatal"
    assert "protocol 7" in r["text"] and "server version: 7, library version: 10" in r["text"], r["text"]

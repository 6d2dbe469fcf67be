"""Helpers of the station's flood tests and bench (issue 32, item 7): the station and the bridge as
processes, the fastest junk a local client can send, a DDS peer's huge status texts, and e-stop
presses from another page timed to the bridge's latch.

Run as a script it is the flooder: ``python station_flood.py ADDRESS [--reconnect]`` opens a WebSocket
the way a page does (with the token), then writes pre-built junk frames as fast as the socket takes
them and never reads; with ``--reconnect`` it opens a new socket each time the station closes one. It
prints its counts when it gets SIGTERM.
"""
from __future__ import annotations

import base64
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

JUNK = [b'{"type": "input", "seq": "x"}', b"not json at all", b'{"type": "launch_missiles"}',
        b'[' * 40 + b']' * 40, b'{"type": "select", "by": "index", "index": 1' + b"0" * 40 + b"}"]


def frame(payload: bytes) -> bytes:
    """A masked client text frame (RFC 6455), the mask all zeros: what the bytes cost the station to
    read is the same."""
    n = len(payload)
    head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big"))
    return head + b"\0\0\0\0" + payload


def handshake(address: str, path_query: str = "") -> socket.socket:
    """An open WebSocket to the station (its token from the address), as a raw socket."""
    u = urlsplit(address)
    s = socket.create_connection((u.hostname, u.port), timeout=10)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /ws?{u.query}{path_query} HTTP/1.1\r\nHost: {u.netloc}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
               f"Origin: http://{u.netloc}\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = s.recv(1)
        if not chunk:
            raise ConnectionError("closed during the handshake")
        head += chunk
    if b" 101 " not in head.split(b"\r\n")[0]:
        raise ConnectionError(head.split(b"\r\n")[0].decode(errors="replace"))
    return s


def flood(address: str, reconnect: bool) -> None:
    block = b"".join(frame(j) for j in JUNK) * 400      # ~60 KB of junk per write
    per_block = len(JUNK) * 400
    sent = connections = refused = 0
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    while not stop.is_set():
        try:
            s = handshake(address)
        except OSError:
            refused += 1
            continue
        connections += 1
        s.settimeout(None)
        try:
            while not stop.is_set():
                s.sendall(block)
                sent += per_block
        except OSError:
            pass
        finally:
            s.close()
        if not reconnect:
            break
    print(json.dumps({"sent": sent, "connections": connections, "refused": refused}), flush=True)


class Flooder:
    """The flooder in a process of its own (it must not share this process's GIL)."""

    def __init__(self, address: str, reconnect: bool, log: Path):
        self.log = log
        with open(log, "wb") as out:
            self.proc = subprocess.Popen([sys.executable, __file__, address] + (["--reconnect"] if reconnect
                                                                                 else []),
                                         stdout=out, stderr=subprocess.STDOUT, start_new_session=True)

    def stop(self) -> dict:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        lines = [x for x in self.log.read_text().splitlines() if x.startswith("{")]
        return json.loads(lines[-1]) if lines else {}


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for {pid}")


class NodeProcess:
    """A node's executable run directly (its pid is the node's), output in a log file."""

    def __init__(self, package: str, executable: str, params: dict, log: Path):
        from vla_launch.run import find_executable

        args = [find_executable(package, executable), "--ros-args"]
        for k, v in params.items():
            args += ["-p", f"{k}:={v}"]
        self.log = log
        with open(log, "wb") as out:
            self.proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         start_new_session=True)

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return self.proc.returncode


def station_and_bridge(tmp: Path) -> tuple[NodeProcess, NodeProcess]:
    """The station (port 0, its own token and settings files) and the bridge without an arm
    (ros2_control backend: nothing to move, but its e-stop latches and says so at once)."""
    station = NodeProcess("vla_operator", "operator_station", {
        "port": 0, "token_file": tmp / "token", "settings_file": tmp / "settings.json"}, tmp / "station.log")
    bridge = NodeProcess("vla_panda_bridge", "panda_bridge", {
        "backend": "ros2_control", "control_rate": 100, "state_rate": 10.0}, tmp / "bridge.log")
    return station, bridge


def address_of(station: NodeProcess) -> str | None:
    import re

    found = re.search(r"operator station is at (http://\S+)", station.text())
    return found.group(1) if found else None


class EstopPage:
    """The operator's open page (websocket-client), which drives: it presses the e-stop and releases it,
    and keeps reading everything the station sends."""

    def __init__(self, address: str):
        import websocket

        u = urlsplit(address)
        self.ws = websocket.create_connection(f"ws://{u.netloc}/ws?{u.query}", origin=f"http://{u.netloc}",
                                              timeout=30)
        self.got = 0
        self.replies: list[dict] = []
        self.view_stale = None                       # the latest state's view_stale
        self.view_changes: list[tuple[float, bool]] = []   # (wall time here, view_stale) on each change
        self.closed = False
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        import websocket

        while True:
            try:
                raw = self.ws.recv()
            except (websocket.WebSocketException, OSError):
                break
            if raw in ("", b""):
                break
            self.got += 1
            if isinstance(raw, str) and raw.startswith('{"type": "reply"'):
                self.replies.append(json.loads(raw))
            elif isinstance(raw, str) and raw.startswith('{"type": "state"'):
                stale = json.loads(raw).get("view_stale")
                if stale != self.view_stale:
                    self.view_changes.append((time.time(), stale))
                self.view_stale = stale
        self.closed = True

    def estop(self) -> float:
        """Press; the wall time just before the message went out."""
        t = time.time()
        self.ws.send('{"type": "estop"}')
        return t

    def release(self) -> None:
        self.ws.send('{"type": "release_estop", "confirm": true}')

    def close(self) -> None:
        try:
            self.ws.close(timeout=1)
        except Exception:
            pass


def latch_node(context):
    """A node that keeps the publish stamps (wall clock) of the bridge's status when its e-stop
    latches, and whether it is latched now."""
    from rclpy.node import Node

    from vla_interfaces.msg import SafetyStatus

    class Latches(Node):
        def __init__(self):
            super().__init__("station_flood_latches", context=context)
            self.stamps: list[float] = []
            self.latched = None
            self.create_subscription(SafetyStatus, "panda_bridge/status", self._status, 50)

        def _status(self, msg, info):
            if msg.estop_active and not self.latched:
                self.stamps.append(info["source_timestamp"] * 1e-9)
            self.latched = msg.estop_active
    return Latches()


def estop_ready(h, page: EstopPage, latches, timeout: float = 60.0) -> bool:
    """Once the station has found the bridge's e-stop service: a press latches it (then released)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        n = len(page.replies)
        page.estop()
        h.spin_until(lambda n=n: len(page.replies) > n, 10.0)
        if page.replies[n:] and page.replies[n]["ok"]:
            page.release()
            return h.spin_until(lambda n=n: latches.latched is False and len(page.replies) > n + 1, 10.0)
        h.spin_for(0.5)
    return False


def press_and_time(h, page: EstopPage, latches, presses: int, timeout: float = 30.0,
                   direct=None) -> list[float] | tuple[list[float], list[float]]:
    """e-stop presses, each released after its latch; seconds from the press to the bridge's latch.
    With ``direct`` (a SetBool client of the bridge's ~/estop in this process), each press of the page
    is followed by one straight to the bridge: the same latch, without the station, under the same load
    at the same moment (the baseline a latency bound needs on a shared machine); both lists then."""
    out, base = [], []
    for _ in range(presses):
        out.append(_press(h, latches, page.estop, page.release, timeout))
        if direct is not None:
            from std_srvs.srv import SetBool

            def call(on: bool):
                t = time.time()
                direct.call_async(SetBool.Request(data=on))
                return t
            base.append(_press(h, latches, lambda: call(True), lambda: call(False), timeout))
    return (out, base) if direct is not None else out


def _press(h, latches, press, release, timeout: float) -> float:
    n = len(latches.stamps)
    t0 = press()
    if not h.spin_until(lambda: len(latches.stamps) > n, timeout):
        raise AssertionError("the e-stop did not latch the bridge")
    release()
    if not h.spin_until(lambda: latches.latched is False, timeout):
        raise AssertionError("the e-stop was not released")
    return latches.stamps[n] - t0


if __name__ == "__main__":
    flood(sys.argv[1], "--reconnect" in sys.argv[2:])

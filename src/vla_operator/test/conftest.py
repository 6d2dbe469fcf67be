"""Helpers of the station's tests: a page without a browser (a WebSocket client that keeps what it got),
and the station node in process with its own port and files."""
from __future__ import annotations

import json
import threading
import time
from urllib.parse import parse_qs, urlsplit

import pytest


class Page:
    """One page's socket (websocket-client): a thread keeps every JSON message and counts the frames'
    JPEGs. ``read=False``: a page that never reads (its socket fills up)."""

    def __init__(self, address: str, query: str = "", origin: str | None = None, host: str | None = None):
        import websocket  # websocket-client (a selenium dependency)

        u = urlsplit(address)
        token = parse_qs(u.query).get("token", [""])[0]
        q = "&".join(x for x in (f"token={token}" if token else "", query) if x)
        self.ws = websocket.create_connection(f"ws://{u.netloc}/ws" + (f"?{q}" if q else ""),
                                              origin=origin or f"http://{u.netloc}", host=host,
                                              timeout=30, suppress_origin=origin == "")
        self.got: list[dict] = []
        self.jpegs = 0
        self.invalid = 0            # messages a browser could not parse
        self.closed = False
        self.cv = threading.Condition()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import websocket

        while True:
            try:
                raw = self.ws.recv()
            except (websocket.WebSocketException, OSError):
                raw = ""
            with self.cv:
                if raw == "":          # closed (websocket-client's answer to a close frame)
                    self.closed = True
                    self.cv.notify_all()
                    return
                if isinstance(raw, bytes):
                    self.jpegs += 1
                else:
                    try:                    # as a browser's JSON.parse: no NaN, no Infinity
                        self.got.append(json.loads(raw, parse_constant=_not_json))
                    except ValueError:
                        self.invalid += 1
                        self.got.append(json.loads(raw))
                self.cv.notify_all()

    def send(self, msg: dict | str) -> None:
        self.ws.send(msg if isinstance(msg, str) else json.dumps(msg))

    def wait(self, pred, timeout: float = 30.0) -> bool:
        """A condition on this page (called with the page), with a generous timeout against a hang."""
        with self.cv:
            return self.cv.wait_for(lambda: pred(self), timeout)

    def of(self, kind: str) -> list[dict]:
        with self.cv:
            return [m for m in self.got if m["type"] == kind]

    def last(self, kind: str) -> dict | None:
        found = self.of(kind)
        return found[-1] if found else None

    def close(self) -> None:
        try:
            self.ws.close(timeout=1)
        except Exception:
            pass
        self.thread.join(5.0)


def _not_json(constant: str):
    raise ValueError(f"{constant} is not JSON")


@pytest.fixture
def page_class():
    return Page


def wait_for(pred, timeout: float = 30.0) -> bool:
    """A condition (another thread's doing), with a generous timeout against a hang."""
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            return False
        threading.Event().wait(0.005)
    return True


@pytest.fixture
def station_node(tmp_path):
    """make(**params) -> the StationNode in process (port 0, its own settings file), spun by a harness."""
    from rclpy.parameter import Parameter
    from vla_common.ros.testing import RosHarness
    from vla_operator.station_node import StationNode

    h = RosHarness()

    def make(**params):
        overrides = [Parameter("port", value=0),
                     Parameter("settings_file", value=str(tmp_path / "settings.json")),
                     Parameter("token_file", value=str(tmp_path / "token")),
                     Parameter("controller", value="no_such_controller_for_this_test"),
                     *(Parameter(k, value=v) for k, v in params.items())]
        return h.add(StationNode(context=h.context, parameter_overrides=overrides))
    make.harness = h
    yield make
    h.shutdown()

"""The server's side of the link without a browser or ROS: what it publishes and under which lock, and
what a page may cost it (issue 32: floods, pages that never read, requests that fail)."""
import json
import threading

import pytest
from vla_operator.server import Limits, Peer, Station


def test_inputs_are_published_in_order_under_the_link_lock(tmp_path):
    """The node's timer publishes from the same link under the same lock: a value read and published
    together can never land after a newer one (a held value after the release's zero)."""
    published = []

    def publish(axis: float) -> None:
        assert station.lock.locked(), "published outside the link's lock"
        published.append(axis)

    now = [10.0]
    station = Station(tmp_path, "127.0.0.1", 0, "", publish, lambda msg, reply: None, clock=lambda: now[0])
    peer = Peer(station.link.connect(now[0]).cid, None, None, Limits())
    for seq, axis in enumerate((0.0, 0.6, 0.0)):
        now[0] += 0.05
        station._on_message(peer, json.dumps({"type": "input", "seq": seq, "t": seq * 50.0, "axis": axis}))
    assert published == [0.0, 0.0, 0.6, 0.0]   # the press after neutral: that neutral again first


# ---------------------------------------------------------------------- what a page may cost (issue 32)
TOKEN = "a-token-for-the-server-tests"


@pytest.fixture
def served(tmp_path):
    """make(limits, request) -> a running Station (no ROS) and the requests it handed to the node."""
    web = tmp_path / "web"
    web.mkdir()
    (web / "index.html").write_text("<!doctype html><title>station</title>")
    made = []

    def make(limits=None, request=None):
        requests = []
        station = Station(web, "127.0.0.1", 0, TOKEN, lambda axis: None,
                          request or (lambda msg, reply: (requests.append(msg), reply({"what": msg["type"],
                                                                                          "ok": True}))),
                          limits=limits or Limits())
        station.start()
        made.append(station)
        return station, requests
    yield make
    for s in made:
        s.stop()


def address(station: Station) -> str:
    return f"http://127.0.0.1:{station.access.port}/?token={TOKEN}"


def test_a_flooding_page_is_closed_and_another_pages_estops_all_reach_the_node(served, page_class):
    from station_flood import JUNK, frame, handshake

    station, requests = served()
    page = page_class(address(station))
    flood = handshake(address(station))
    try:
        assert page.wait(lambda p: p.of("hello"))
        block, pressed = b"".join(frame(j) for j in JUNK) * 200, 0
        with pytest.raises(OSError):            # the station closes it: the writes fail
            for _ in range(10_000):
                page.send({"type": "estop"})
                pressed += 1
                flood.sendall(block)
        assert station.counters["closed_flooding"] == 1 and station.link.counters.received > 100
        assert page.wait(lambda p: sum(m.get("what") == "estop" for m in p.of("reply")) == pressed)
        assert sum(r["type"] == "estop" for r in requests) == pressed and not page.closed
    finally:
        flood.close()
        page.close()


def test_past_its_budget_a_pages_messages_are_refused_unread_but_its_estop_is_not(served):
    station, requests = served(Limits(max_rate=5.0, refusal_rate=1.0, max_refusals=1000.0))
    now = [10.0]
    station.clock = lambda: now[0]
    peer = Peer(station.link.connect(now[0]).cid, None, None, station.limits)
    for _ in range(5):
        assert station._on_message(peer, json.dumps({"type": "heartbeat"}))
    station._on_message(peer, json.dumps({"type": "gripper"}))
    assert station.counters["over_budget"] == 1 and requests == []
    station._on_message(peer, json.dumps({"type": "estop"}))
    assert requests == [{"type": "estop"}]


def test_a_page_that_never_reads_is_closed_and_what_waits_for_it_stays_bounded(served):
    from station_flood import handshake

    station, _ = served(Limits(send_timeout=0.5))
    silent = handshake(address(station))
    silent.setsockopt(__import__("socket").SOL_SOCKET, __import__("socket").SO_RCVBUF, 4096)
    try:
        jpeg, i = bytes(200_000), 0

        def offer() -> bool:                        # frames and states as a camera and nodes send them
            nonlocal i
            i += 1
            station.set_frame(jpeg, {"received": 0.0, "n": i})
            station.set_state({"text": "x" * 60_000, "n": i})
            assert all(len(p.outbox) <= 64 + 8 + 2 for p in list(station._peers.values()))
            return station.counters["closed_slow"] == 1
        assert wait(offer, interval=0.001)          # the page read none of it: closed
        assert wait(lambda: not station._peers) and i > 10
    finally:
        silent.close()


def test_a_request_that_fails_in_the_node_is_answered_and_the_link_survives(served, page_class):
    def request(msg, reply):
        if msg["type"] == "select":
            raise AssertionError("out of the message's range")   # what an int32 field raised
        reply({"what": msg["type"], "ok": True})
    station, _ = served(request=request)
    page = page_class(address(station))
    try:
        page.send({"type": "select", "by": "policy"})
        assert page.wait(lambda p: p.of("reply"))
        assert page.last("reply") == {"type": "reply", "what": "select", "ok": False,
                                      "message": "the station could not do this (AssertionError)"}
        page.send({"type": "redetect"})
        assert page.wait(lambda p: len(p.of("reply")) == 2) and not page.closed
    finally:
        page.close()


def wait(pred, timeout: float = 30.0, interval: float = 0.01) -> bool:
    """A condition, with a generous timeout only against a hang."""
    import time
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            return False
        threading.Event().wait(interval)
    return True


def test_a_slow_request_never_holds_up_another_pages_estop(served, page_class):
    """A request that takes long in the node (a settings file synced to a slow disk, a service call)
    runs off the thread that reads the pages: an e-stop read meanwhile reaches the node at once. More
    than max_pending such requests waiting are refused as busy."""
    release, estops = threading.Event(), threading.Event()

    def request(msg, reply):
        if msg["type"] == "estop":
            estops.set()
        else:
            release.wait(30.0)              # the slow one
        reply({"what": msg["type"], "ok": True})
    station, _ = served(Limits(max_pending=2), request=request)
    driver, other = page_class(address(station)), page_class(address(station))
    try:
        assert driver.wait(lambda p: p.of("hello")) and other.wait(lambda p: p.of("hello"))
        for _ in range(3):
            driver.send({"type": "settings", "values": {"speed_scale": 0.5}})
        assert driver.wait(lambda p: any("busy" in m.get("message", "") for m in p.of("reply")))
        other.send({"type": "estop"})
        assert estops.wait(30.0) and not release.is_set()     # while the slow ones still wait
        release.set()
        assert driver.wait(lambda p: sum(m.get("ok") is True for m in p.of("reply")) == 2)
    finally:
        release.set()
        driver.close()
        other.close()

"""The station's web server (aiohttp, no rclpy): the page's files, and one WebSocket per page that
carries input in, and frames, detections and status out. The safety rules are :mod:`.link`'s, who may
open it :mod:`.access`'s, what a page may cost :mod:`.outbox`'s; this module moves bytes. It runs its
own event loop in a thread; the node talks to it through ``publish_axis`` / ``request`` callbacks and
``set_frame`` / ``set_state`` / ``reply``, which are thread-safe.

Everything reachable from the network is untrusted, so every page is bounded (issue 32):
- what goes out to a page waits in its own :class:`Outbox` (the newest state and frame replace older
  ones, replies and refusals are few), sent by one task per page as the page reads; a send that stays
  blocked for ``send_timeout`` closes the page;
- what comes in is budgeted: beyond ``max_rate`` messages/s a page's messages are refused unread (an
  e-stop is always handled), and a page refused more than ``max_refusals`` in a burst (``refusal_rate``
  per s after it) is closed at once, what it had sent and not yet handled dropped with it;
- a page's handler lets the others' messages through every few of its own, so a flood from one socket
  never holds back another page's e-stop, which goes to the bridge from this thread as it arrives;
  every other request runs on a thread of its own (at most ``max_pending`` waiting), so none delays
  the reading of an e-stop;
- a connection that has not sent a whole request within ``request_timeout`` is closed.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from aiohttp import WSMsgType, web

from vla_operator.access import Access
from vla_operator.link import Link, LinkParams
from vla_operator.outbox import Budget, Outbox
from vla_operator.schema import MODELS, parse

LOG = logging.getLogger("vla_operator.server")
OVER_BUDGET = "too many messages: the station handles this page's next ones when it slows down"
OVER_BUDGET_TEXT = json.dumps({"type": "refused", "reason": OVER_BUDGET, "what": ""})


@dataclass(frozen=True)
class Limits:
    """What one page may cost. A page sends at most ~100 messages/s (its input resent every 40 ms, a
    gamepad's changes, a heartbeat every 200 ms); a loaded machine can make all its inputs late
    (refused, stale) for a while."""

    max_rate: float = 300.0        # messages/s a page may send (and as many at once)
    refusal_rate: float = 50.0     # refusals/s a page may earn after a burst of ...
    max_refusals: float = 100.0    # ... this many; past them it is closed
    max_pages: int = 16            # pages open at once
    send_timeout: float = 10.0     # s a send to a page may stay blocked before it is closed
    request_timeout: float = 10.0  # s to send a whole HTTP request (and to stay idle between two)
    yield_every: int = 8           # a page's messages handled before the other pages' get a turn
    max_pending: int = 32          # requests waiting for the node (beyond: refused, busy)


@dataclass(eq=False)
class Peer:
    cid: int
    ws: web.WebSocketResponse | None
    transport: asyncio.Transport | None
    limits: Limits
    outbox: Outbox = field(default_factory=Outbox)
    messages: Budget = field(init=False)     # what it may send
    refusals: Budget = field(init=False)     # how often it may be refused before it is closed
    flooding: bool = False

    def __post_init__(self):
        self.messages = Budget(self.limits.max_rate, self.limits.max_rate)
        self.refusals = Budget(self.limits.refusal_rate, self.limits.max_refusals)


class Station:
    def __init__(self, web_dir: Path, bind: str, port: int, token: str,
                 publish_axis: Callable[[float], None],
                 request: Callable[[dict, Callable[[dict], None]], None],
                 params: LinkParams | None = None, clock: Callable[[], float] = time.monotonic,
                 names: tuple[str, ...] = (), limits: Limits | None = None):
        """``names``: the caregiver's names for this station besides its addresses (the Host check)."""
        self.web_dir, self.bind, self.port, self.token = web_dir, bind, port, token
        self.publish_axis, self.request, self.clock = publish_axis, request, clock
        self.names, self.limits = tuple(names), limits or Limits()
        self.access = Access(bind, port, token, self.names)
        self.link = Link(params or LinkParams())
        self.lock = threading.Lock()          # the link, and the order of what is published from it,
        #                                       shared with the node's timer
        self._peers: dict[int, Peer] = {}     # the loop's thread only
        self._frame: tuple[dict, bytes] | None = None    # the newest, handed over from the node
        self._state: dict | None = None
        self._scheduled = {"frame": False, "state": False}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self.address = ""
        self.frames_sent = 0
        self._dropped_before = 0              # by pages closed since
        self.counters = {"over_budget": 0, "closed_flooding": 0, "closed_slow": 0, "refused_full": 0,
                         "errors": 0, "busy": 0}
        # The node's requests other than the e-stop run here, one at a time and in order: a slow one (a
        # settings file written and synced, a service call) never holds up the thread that reads the
        # pages, so an e-stop is read and sent to the bridge while it runs.
        self._requests = ThreadPoolExecutor(1, thread_name_prefix="operator-requests")
        self._pending = 0                     # requests handed to that thread and not finished
        files = web_dir.iterdir() if web_dir.is_dir() else ()
        self._files = {f.name for f in files if f.suffix in (".js", ".css")}

    # ------------------------------------------------------------------ life cycle
    def start(self, timeout: float = 10.0) -> str:
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="operator-station",
                                        daemon=True)
        self._thread.start()
        if not ready.wait(timeout) or not self.address:
            raise RuntimeError(f"the operator station could not listen on {self.bind}:{self.port}")
        return self.address

    def _run(self, ready: threading.Event) -> None:
        self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(self._loop)
        app = web.Application(client_max_size=4096, middlewares=[self._host_guard])
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        # keepalive_timeout runs from the connection's start until a whole request is in: a half-open
        # request (headers never finished) is closed after it, as is an idle keep-alive connection
        self._runner = web.AppRunner(app, access_log=None, keepalive_timeout=self.limits.request_timeout,
                                     shutdown_timeout=1.0)
        try:
            self._loop.run_until_complete(self._runner.setup())
            site = web.TCPSite(self._runner, self.bind, self.port)
            self._loop.run_until_complete(site.start())
            port = self._runner.addresses[0][1]
            self.access = Access(self.bind, port, self.token, self.names)
            host = f"[{self.bind}]" if ":" in self.bind else self.bind
            self.address = f"http://{host}:{port}/" + (f"?token={self.token}" if self.token else "")
        finally:
            ready.set()
        if self.address:
            self._loop.run_forever()

    def stop(self) -> None:
        """Close the pages and the server; a second call (on_shutdown, then destroy_node) does nothing."""
        if self._loop is None or not self._loop.is_running():
            return

        async def close():
            for peer in list(self._peers.values()):
                self._drop_connection(peer)     # at once: a page that does not read cannot hold us
            await self._runner.cleanup()
        try:
            asyncio.run_coroutine_threadsafe(close(), self._loop).result(2.0)
        except Exception:  # noqa: BLE001 - shutting down: the loop may be gone already
            pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(2.0)
        self._requests.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------------ from the node (any thread)
    def set_frame(self, jpeg: bytes, meta: dict) -> None:
        """The latest frame; each page gets the newest one when it is ready for one (never a backlog)."""
        self._frame = (meta, jpeg)
        self._schedule("frame", self._post_frame)

    def set_state(self, state: dict) -> None:
        """Status for every page (the nodes' status in words): the newest replaces any not yet sent."""
        self._state = dict(state)
        self._schedule("state", self._post_state)

    def reply(self, cid: int, reply: dict) -> None:
        self._call(self._post, cid, {"type": "reply", **reply})

    def wants_frames(self) -> bool:
        return bool(self._peers)

    def dropped(self) -> int:
        """Messages not sent because a page did not read them (newer ones replaced them)."""
        return self._dropped_before + sum(p.outbox.dropped for p in list(self._peers.values()))

    def _schedule(self, kind: str, post: Callable[[], None]) -> None:
        """One pending hand-over to the loop per kind, however fast the node calls."""
        if not self._scheduled[kind]:
            self._scheduled[kind] = True
            self._call(post)

    def _call(self, fn, *args) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(fn, *args)
            except RuntimeError:   # the loop closed meanwhile (shutting down)
                pass

    # ------------------------------------------------------------------ to the pages (loop thread)
    def _post_state(self) -> None:
        self._scheduled["state"] = False
        if self._state is not None:
            text = to_json({"type": "state", **self._state})    # once for every page
            for peer in self._peers.values():
                peer.outbox.latest("state", text)

    def _post_frame(self) -> None:
        self._scheduled["frame"] = False
        if self._frame is not None:
            for peer in self._peers.values():
                peer.outbox.latest("frame", self._frame)

    def _post(self, cid: int, msg: dict) -> None:
        peer = self._peers.get(cid)
        if peer is not None:
            peer.outbox.put(to_json(msg))

    def _broadcast_roles(self, taken_from: int | None = None) -> None:
        """Every page's role; the page that drove before a watcher took control is told so."""
        for cid, c in list(self.link.clients.items()):
            self._post(cid, {"type": "role", "driver": c.driver, "may_drive": c.may_drive,
                             "driver_present": self.link.driver() is not None,
                             "taken": cid == taken_from})

    async def _sender(self, peer: Peer) -> None:
        """Sends a page's outbox as the page reads; a send blocked for send_timeout closes the page."""
        while (item := await peer.outbox.next()) is not None:
            kind, payload = item
            try:
                async with asyncio.timeout(self.limits.send_timeout):
                    if kind == "frame":
                        meta, jpeg = payload
                        age = (time.monotonic() - meta["received"]) * 1000.0
                        await peer.ws.send_str(to_json({**meta, "type": "frame", "age_ms": age}))
                        await peer.ws.send_bytes(jpeg)
                        self.frames_sent += 1
                    else:
                        await peer.ws.send_str(payload)
            except TimeoutError:
                self.counters["closed_slow"] += 1
                self._drop_connection(peer)
                return
            except (ConnectionError, RuntimeError):
                return

    def _drop_connection(self, peer: Peer) -> None:
        """Close a page's connection now, and forget what it sent that was not handled yet."""
        peer.outbox.close()
        if peer.transport is not None and not peer.transport.is_closing():
            peer.transport.abort()
        # aiohttp parses what arrived ahead of the handler (up to 128 KiB of payload: thousands of
        # small messages from a flood), in a queue that only the cyclic garbage collector would free
        # otherwise. Such full collections took 30-100 ms each under a flood, and an e-stop arriving
        # then waited as long (issue 32). Private to aiohttp 3.14 (pinned); absent, nothing is done.
        queued = getattr(getattr(peer.ws, "_reader", None), "_buffer", None)
        if queued is not None:
            queued.clear()

    # ------------------------------------------------------------------ HTTP
    @web.middleware
    async def _host_guard(self, request: web.Request, handler) -> web.StreamResponse:
        """Every request, files and the WebSocket alike, must name this station in its Host (DNS
        rebinding: see :mod:`.access`)."""
        refusal = self.access.host_refusal(request.headers.get("Host"))
        if refusal:
            return web.Response(status=403, text=refusal)
        return await handler(request)

    async def _index(self, request: web.Request) -> web.StreamResponse:
        refusal = self.access.page_refusal(request.headers.get("Host"), request.query.get("token", ""))
        if refusal:
            return web.Response(status=403, text=refusal)
        return web.FileResponse(self.web_dir / "index.html", headers={
            "Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'; "
                                       "frame-ancestors 'none'",
        })

    async def _static(self, request: web.Request) -> web.StreamResponse:
        """Only the page's own files, by name (no paths: nothing else on the disk is reachable)."""
        name = request.match_info["name"]
        if name not in self._files:
            raise web.HTTPNotFound()
        ctype = {".js": "text/javascript", ".css": "text/css"}[Path(name).suffix]
        return web.FileResponse(self.web_dir / name,
                                headers={"Content-Type": ctype, "Cache-Control": "no-store"})

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        refusal = self.access.handshake_refusal(request.headers.get("Host"), request.headers.get("Origin"),
                                                request.query.get("token", ""))
        if refusal:
            return web.Response(status=403, text=refusal)
        if len(self._peers) >= self.limits.max_pages:
            self.counters["refused_full"] += 1
            return web.Response(status=503, text=f"{self.limits.max_pages} pages are open: close one")
        # no compression: the frames are JPEGs, and deflating the rest costs more than it saves here
        ws = web.WebSocketResponse(heartbeat=None, compress=False,
                                   max_msg_size=self.link.params.max_message_bytes * 4)
        await ws.prepare(request)
        with self.lock:   # ?watch=1: a page that only shows (a display, the demo's recording)
            client = self.link.connect(self.clock(), may_drive=request.query.get("watch") != "1")
            driver_present = self.link.driver() is not None
        peer = Peer(client.cid, ws, request.transport, self.limits)
        self._peers[peer.cid] = peer
        self._post(peer.cid, {"type": "hello", "client": peer.cid, "driver": client.driver,
                              "driver_present": driver_present, "stale_after": self.link.params.stale_after})
        if self._state is not None:
            peer.outbox.latest("state", to_json({"type": "state", **self._state}))
        sender = asyncio.ensure_future(self._sender(peer))
        try:
            await self._receive(peer)
        finally:
            self._peers.pop(peer.cid, None)
            self._dropped_before += peer.outbox.dropped
            if peer.flooding:
                self._drop_connection(peer)    # at once: a flooder's close handshake is not waited for
            else:
                peer.outbox.close()
            sender.cancel()
            with self.lock:
                if self.link.disconnect(peer.cid):
                    self.publish_axis(0.0)
            self._broadcast_roles()
        return ws

    async def _receive(self, peer: Peer) -> None:
        n = 0
        async for m in peer.ws:
            if m.type not in (WSMsgType.TEXT, WSMsgType.BINARY) or not self._on_message(peer, m.data):
                return
            n += 1
            if n % self.limits.yield_every == 0:
                await asyncio.sleep(0)   # the other pages' messages (an e-stop) get their turn

    # ------------------------------------------------------------------ from a page
    def _on_message(self, peer: Peer, data: str | bytes) -> bool:
        """Handle one message; False when the page is closed for what it sent."""
        now = self.clock()
        if not peer.messages.take(now) and not _is_estop(data):
            self.counters["over_budget"] += 1
            self.link.counters.received += 1
            return self._refuse(peer, OVER_BUDGET, "")
        # Decided and published under the link's lock, as the node's timer does: otherwise the timer
        # could publish a held value it read just before a release, after the release's zero (a blip
        # of motion after the operator let go, seen on a loaded machine).
        with self.lock:
            verdict = self.link.on_message(peer.cid, data, now)
            if verdict.publish:
                self.link.published(now)
                if verdict.from_neutral:
                    self.publish_axis(0.0)
                self.publish_axis(self.link.value(now))
        if verdict.request is not None:
            self._dispatch(peer, verdict.request)
        if verdict.error:   # with the refused message's type, when it is one (the page shows it there)
            return self._refuse(peer, verdict.error, self._kind(data))
        return True

    def _dispatch(self, peer: Peer, request: dict) -> None:
        if request["type"] == "claim":
            self._broadcast_roles(taken_from=request["taken_from"])
        elif request["type"] == "estop":
            self._run_request(peer.cid, request)      # to the bridge from here, now, ahead of all else
        elif self._pending >= self.limits.max_pending:
            self.counters["busy"] += 1
            self._post(peer.cid, {"type": "reply", "what": request["type"], "ok": False,
                                  "message": "the station is busy: try again in a moment"})
        else:
            self._pending += 1
            self._requests.submit(self._run_request, peer.cid, request)

    def _run_request(self, cid: int, request: dict) -> None:
        """One request to the node; its failure is answered and never closes the page's link."""
        try:
            self.request(request, lambda reply: self.reply(cid, reply))
        except Exception as e:  # noqa: BLE001
            self.counters["errors"] += 1
            LOG.exception("request %s failed", request["type"])
            self.reply(cid, {"what": request["type"], "ok": False,
                             "message": f"the station could not do this ({type(e).__name__})"})
        finally:
            if request["type"] != "estop":
                self._call(self._request_done)

    def _request_done(self) -> None:
        self._pending -= 1

    def _refuse(self, peer: Peer, reason: str, what: str) -> bool:
        """Tell the page why (only the last few refusals wait for a page that does not read); close a
        page past its refusal budget."""
        peer.outbox.refuse(OVER_BUDGET_TEXT if reason is OVER_BUDGET else
                           json.dumps({"type": "refused", "reason": reason, "what": what}))
        if peer.refusals.take(self.clock()):
            return True
        self.counters["closed_flooding"] += 1
        peer.flooding = True
        return False

    def _kind(self, data: str | bytes) -> str:
        if len(data) > self.link.params.max_message_bytes:
            return ""
        msg = parse(data)
        return msg["type"] if isinstance(msg, dict) and msg["type"] in MODELS else ""   # ours only


def to_json(obj) -> str:
    """JSON a browser parses: a NaN or an infinity (from any DDS peer's message) becomes null. Python's
    json writes them as NaN and Infinity, which JSON.parse refuses: the page would drop that state."""
    try:
        return json.dumps(obj, allow_nan=False)
    except ValueError:
        return json.dumps(_finite(obj), allow_nan=False)


def _finite(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def _is_estop(data: str | bytes) -> bool:
    """An e-stop, whatever the page's budget (a small message of type estop; cheap for any other)."""
    if len(data) > 64 or ("estop" if isinstance(data, str) else b"estop") not in data:
        return False
    msg = parse(data)
    return isinstance(msg, dict) and msg["type"] == "estop"

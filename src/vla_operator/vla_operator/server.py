"""The station's web server (aiohttp, no rclpy): the page's files, and one WebSocket per page that
carries input in, and frames, detections and status out. The safety rules are :mod:`.link`'s; this
module only moves bytes. It runs its own event loop in a thread; the node talks to it through
``publish_axis`` / ``request`` callbacks and ``set_frame`` / ``set_state``, which are thread-safe."""
from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable
from pathlib import Path

from aiohttp import WSMsgType, web

from vla_operator.access import Access
from vla_operator.link import Link, LinkParams
from vla_operator.schema import MODELS, parse


class Station:
    def __init__(self, web_dir: Path, bind: str, port: int, token: str,
                 publish_axis: Callable[[float], None],
                 request: Callable[[dict, Callable[[dict], None]], None],
                 params: LinkParams | None = None, clock: Callable[[], float] = time.monotonic,
                 names: tuple[str, ...] = (), request_timeout: float = 10.0):
        """``names``: the caregiver's names for this station besides its addresses (the Host check);
        ``request_timeout``: s a connection may take to send a whole request (and stay idle)."""
        self.web_dir, self.bind, self.port, self.token = web_dir, bind, port, token
        self.names, self.request_timeout = tuple(names), request_timeout
        self.access = Access(bind, port, token, self.names)
        self.publish_axis, self.request, self.clock = publish_axis, request, clock
        self.link = Link(params or LinkParams())
        self.lock = threading.Lock()          # the link, and the order of what is published from it,
        #                                       shared with the node's timer
        self._sockets: dict[int, web.WebSocketResponse] = {}
        self._frame: tuple[int, bytes, dict] = (0, b"", {})
        self._state: dict = {}
        self._events: dict[int, asyncio.Event] = {}  # per page: a newer frame is there
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self.address = ""
        self.frames_sent = 0
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
        self._runner = web.AppRunner(app, access_log=None, keepalive_timeout=self.request_timeout)
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
            for ws in list(self._sockets.values()):
                await ws.close()
            await self._runner.cleanup()
        try:
            asyncio.run_coroutine_threadsafe(close(), self._loop).result(2.0)
        except Exception:  # shutting down: the loop may be gone already
            pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(2.0)

    # ------------------------------------------------------------------ from the node
    def set_frame(self, jpeg: bytes, meta: dict) -> None:
        """The latest frame; pages get it when they are ready for one (never a backlog)."""
        self._frame = (self._frame[0] + 1, jpeg, meta)
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        for e in self._events.values():
            e.set()

    def set_state(self, state: dict) -> None:
        """Status for every page (the nodes' status in words); sent at once."""
        self._state = state
        self._broadcast({"type": "state", **state})

    def reply(self, cid: int, reply: dict) -> None:
        self._send(cid, {"type": "reply", **reply})

    def wants_frames(self) -> bool:
        return bool(self._sockets)

    def _broadcast(self, msg: dict) -> None:
        for cid in list(self._sockets):
            self._send(cid, msg)

    def _send(self, cid: int, msg: dict) -> None:
        ws, loop = self._sockets.get(cid), self._loop
        if ws is not None and loop is not None:
            asyncio.run_coroutine_threadsafe(_send_quietly(ws, json.dumps(msg)), loop)

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
        ws = web.WebSocketResponse(heartbeat=None, max_msg_size=self.link.params.max_message_bytes * 4)
        await ws.prepare(request)
        with self.lock:   # ?watch=1: a page that only shows (a display, the demo's recording)
            client = self.link.connect(self.clock(), may_drive=request.query.get("watch") != "1")
        cid = client.cid
        self._sockets[cid] = ws
        await ws.send_str(json.dumps({"type": "hello", "client": cid, "driver": client.driver,
                                      "driver_present": self.link.driver() is not None,
                                      "stale_after": self.link.params.stale_after}))
        if self._state:
            await ws.send_str(json.dumps({"type": "state", **self._state}))
        self._events[cid] = asyncio.Event()
        sender = asyncio.ensure_future(self._send_frames(ws, self._events[cid]))
        try:
            async for m in ws:
                if m.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                    self._on_message(cid, m.data)
                else:
                    break
        finally:
            sender.cancel()
            self._sockets.pop(cid, None)
            self._events.pop(cid, None)
            with self.lock:
                if self.link.disconnect(cid):
                    self.publish_axis(0.0)
            self._broadcast_roles()
        return ws

    def _on_message(self, cid: int, data: str | bytes) -> None:
        now = self.clock()
        # Decided and published under the link's lock, as the node's timer does: otherwise the timer
        # could publish a held value it read just before a release, after the release's zero (a blip
        # of motion after the operator let go, seen on a loaded machine).
        with self.lock:
            verdict = self.link.on_message(cid, data, now)
            if verdict.publish:
                self.link.published(now)
                if verdict.from_neutral:
                    self.publish_axis(0.0)
                self.publish_axis(self.link.value(now))
        if verdict.error:   # with the refused message's type, when it had one (the page shows it there)
            self._send(cid, {"type": "refused", "reason": verdict.error, "what": self._kind(data)})
        if verdict.request is not None:
            if verdict.request["type"] == "claim":
                self._broadcast_roles(taken_from=verdict.request["taken_from"])
            else:
                self.request(verdict.request, lambda reply: self.reply(cid, reply))

    def _kind(self, data: str | bytes) -> str:
        if len(data) > self.link.params.max_message_bytes:
            return ""
        msg = parse(data)
        return msg["type"] if isinstance(msg, dict) and msg["type"] in MODELS else ""   # ours only

    def _broadcast_roles(self, taken_from: int | None = None) -> None:
        """Every page's role; the page that drove before a watcher took control is told so."""
        for cid, c in list(self.link.clients.items()):
            self._send(cid, {"type": "role", "driver": c.driver, "may_drive": c.may_drive,
                             "driver_present": self.link.driver() is not None,
                             "taken": cid == taken_from})

    async def _send_frames(self, ws: web.WebSocketResponse, event: asyncio.Event) -> None:
        sent = 0
        while not ws.closed:
            await event.wait()
            event.clear()
            version, jpeg, meta = self._frame
            if version == sent or not jpeg:
                continue
            sent = version
            meta = {**meta, "type": "frame", "age_ms": (time.monotonic() - meta["received"]) * 1000.0}
            await ws.send_str(json.dumps(meta))
            await ws.send_bytes(jpeg)   # waits while the page's socket is full: frames that come
            self.frames_sent += 1       # meanwhile replace each other, only the latest is sent next


async def _send_quietly(ws: web.WebSocketResponse, text: str) -> None:
    if not ws.closed:
        try:
            await ws.send_str(text)
        except (ConnectionError, RuntimeError):
            pass

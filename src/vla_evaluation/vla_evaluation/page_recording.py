"""`vla_evaluation demo --record-page out/station.mp4`: a video of the operator station's page while the
demo runs, as the person at the robot would see it.

Debian's headless Chromium opens the page (watch-only: the simulated user drives) and streams its
rendered frames through the DevTools protocol (Page.startScreencast: JPEG frames with their time, each
acknowledged), which OpenCV writes into an mp4 at a fixed rate, repeating a frame while the page did
not change, so the video plays in real time. Nothing is downloaded; the browser is the distribution's
(`make setup` installs it) and runs in a process group of its own that `stop()` ends.
"""
from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from urllib.request import urlopen

import cv2
import numpy as np

CHROMIUM = ("/usr/lib/chromium/chromium", "chromium", "chromium-browser")   # the real binary first
DEVTOOLS = re.compile(r"DevTools listening on (ws://\S+)")


class RecordingError(RuntimeError):
    """The page could not be recorded; the message says why."""


def find_chromium() -> str:
    for name in CHROMIUM:
        path = name if os.path.isabs(name) else shutil.which(name)
        if path and os.access(path, os.X_OK):
            return path
    raise RecordingError("--record-page needs Chromium (Debian's chromium package: run make setup)")


class PageRecorder:
    """Records `url` into `path` (mp4) from start() to stop(); `frames` counts the page's frames."""

    def __init__(self, url: str, path: Path, size: tuple[int, int] = (1024, 1100), fps: float = 10.0):
        self.url, self.path, self.size, self.fps = url, Path(path), size, fps
        self.frames = 0        # frames the page sent
        self.written = 0       # frames in the video (fixed rate)
        self._proc: subprocess.Popen | None = None
        self._profile = ""
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._writer: cv2.VideoWriter | None = None

    def start(self, timeout: float = 30.0) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._profile = tempfile.mkdtemp(prefix="vla-record-page-")
        w, h = self.size
        self._proc = subprocess.Popen(
            [find_chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
             "--hide-scrollbars", "--mute-audio", f"--window-size={w},{h}",
             f"--user-data-dir={self._profile}", "--remote-debugging-port=0", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            start_new_session=True)
        browser_ws = self._devtools_address(timeout)
        port = int(re.search(r":(\d+)/", browser_ws).group(1))
        started = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(port, started), name="record-page",
                                        daemon=True)
        self._thread.start()
        if not started.wait(timeout) or self._error is not None:
            self.stop()
            raise RecordingError(f"could not record the page {self.url}: {self._error or 'no answer'}")

    def _devtools_address(self, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        lines: list[str] = []
        while time.monotonic() < deadline:
            line = self._proc.stderr.readline().decode(errors="replace")
            if not line and self._proc.poll() is not None:
                break
            lines.append(line)
            m = DEVTOOLS.search(line)
            if m:
                # keep reading its stderr (a full pipe would stall the browser)
                threading.Thread(target=self._drain, daemon=True).start()
                return m.group(1)
        self.stop()
        raise RecordingError("Chromium did not start: " + "".join(lines[-5:]).strip())

    def _drain(self) -> None:
        for _ in iter(self._proc.stderr.readline, b""):
            pass

    def _run(self, port: int, started: threading.Event) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._loop.run_until_complete(self._record(port, started))
        except BaseException as e:   # reported by start() or stop()
            self._error = e
            started.set()
        finally:
            self._loop.close()

    async def _record(self, port: int, started: threading.Event) -> None:
        import aiohttp  # the station's own server library

        self._stop = asyncio.Event()
        targets = json.loads(await asyncio.to_thread(
            lambda: urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read()))
        page = next(t for t in targets if t.get("type") == "page")
        async with aiohttp.ClientSession() as session, session.ws_connect(
                page["webSocketDebuggerUrl"], max_msg_size=64 * 1024 * 1024) as ws:
            ids = iter(range(1, 1 << 30))

            async def send(method: str, **params) -> None:
                await ws.send_str(json.dumps({"id": next(ids), "method": method, "params": params}))

            await send("Page.enable")
            await send("Page.navigate", url=self.url)
            await send("Page.startScreencast", format="jpeg", quality=80, maxWidth=self.size[0],
                       maxHeight=self.size[1])
            started.set()
            t0 = None
            last: np.ndarray | None = None
            stop = asyncio.ensure_future(self._stop.wait())
            while not self._stop.is_set():
                recv = asyncio.ensure_future(ws.receive())
                await asyncio.wait({recv, stop}, return_when=asyncio.FIRST_COMPLETED)
                if not recv.done():
                    recv.cancel()
                    break
                msg = recv.result()
                if msg.type != aiohttp.WSMsgType.TEXT:
                    break
                m = json.loads(msg.data)
                if m.get("method") != "Page.screencastFrame":
                    continue
                p = m["params"]
                await send("Page.screencastFrameAck", sessionId=p["sessionId"])
                img = cv2.imdecode(np.frombuffer(base64.b64decode(p["data"]), np.uint8), cv2.IMREAD_COLOR)
                if img is None:
                    continue
                self.frames += 1
                now = time.monotonic()
                t0 = now if t0 is None else t0
                last = self._write_until(last, now - t0)
                last = img
            stop.cancel()
            if last is not None and t0 is not None:
                self._write_until(last, time.monotonic() - t0 + 1.0 / self.fps)

    def _write_until(self, img: np.ndarray | None, t: float) -> np.ndarray | None:
        """Repeat `img` (the page until now) up to time t of the video."""
        if img is None:
            return None
        if self._writer is None:
            fourcc = cv2.VideoWriter_fourcc(*"mp4v")
            self._writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, self.size)
        img = fit(img, self.size)
        while self.written < int(t * self.fps) + 1:
            self._writer.write(img)
            self.written += 1
        return img

    def stop(self) -> Path | None:
        """End the recording and the browser; the video's path (None when no frame came)."""
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        if self._thread is not None:
            self._thread.join(10.0)
        if self._proc is not None and self._proc.poll() is None:
            try:
                os.killpg(self._proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._proc.wait(10)
        if self._profile:
            shutil.rmtree(self._profile, ignore_errors=True)
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        return self.path if self.written else None


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (for the station the demo starts)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def recording(path: Path | None, port: int | None, log=print, timeout: float = 60.0):
    """Record the station's page on `port` into `path` for the block's duration (nothing when path is
    None). Waits for the station to serve its page first (it starts beside the graph)."""
    if path is None or port is None:
        yield None
        return
    url = f"http://127.0.0.1:{port}/?watch=1"
    deadline = time.monotonic() + timeout
    while True:
        try:
            urlopen(url, timeout=5).close()
            break
        except OSError as e:
            if time.monotonic() > deadline:
                raise RecordingError(f"the operator station did not serve {url}: {e}") from None
            time.sleep(0.25)   # the station's node is still starting
    rec = PageRecorder(url, Path(path))
    rec.start()
    log(f"[demo] recording the operator station's page ({url}) into {path}")
    try:
        yield rec
    finally:
        written = rec.stop()
        log(f"[demo] page recording: {rec.frames} page frames, {rec.written / rec.fps:.0f} s"
            + (f" in {written}" if written else " (nothing recorded)"))


def fit(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`img` scaled to fit `size` (w, h), its aspect kept, centred on black: the video is the size asked
    for, whatever size the browser's screencast frames come in (the first ones may differ from the
    window's: seen 548x480 for a 640x480 window, now and then)."""
    w, h = size
    if img.shape[1] == w and img.shape[0] == h:
        return img
    scale = min(w / img.shape[1], h / img.shape[0])
    sw, sh = max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale))
    out = np.zeros((h, w, 3), np.uint8)
    x0, y0 = (w - sw) // 2, (h - sh) // 2
    out[y0:y0 + sh, x0:x0 + sw] = cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA)
    return out

"""The live view's JPEG encoder (no rclpy): a thread of its own that encodes only the latest frame.

Why a thread: encoding 640x480 takes several ms; on the node's executor it delayed the station's
50 Hz Joy stream (the controller stops after 0.1 s without Joy and then waits for neutral: a press
that came right after such a gap did nothing) and a backlog of frames was encoded one after the other.
Here the executor only hands the latest image over; OpenCV releases the GIL while it converts and
encodes, so the encoding runs beside the node's callbacks and the web server. Frames that come while
one is being encoded replace each other: only the newest is encoded, so there is never a backlog.
The thread runs at background priority (vla_common.priority): the station's web thread, which
receives the operator's input, runs before it.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
from vla_common.priority import run_in_background


class FrameEncoder:
    def __init__(self, deliver: Callable[[bytes, dict], None], quality: int = 80):
        self.deliver, self.quality = deliver, quality
        self.received = self.encoded = self.skipped = 0
        self._latest: tuple[object, int, int, str, dict] | None = None
        self._cv = threading.Condition()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="operator-frames", daemon=True)
        self._thread.start()

    def submit(self, data, width: int, height: int, encoding: str, meta: dict) -> None:
        """The newest frame (``data``: any buffer of height x width x 3 bytes, rgb8 or bgr8); one not
        yet encoded is dropped."""
        with self._cv:
            self.received += 1
            if self._latest is not None:
                self.skipped += 1
            self._latest = (data, width, height, encoding, {**meta, "received": time.monotonic()})
            self._cv.notify()

    def stop(self) -> None:
        with self._cv:
            self._stopped = True
            self._cv.notify()
        self._thread.join(2.0)

    def _run(self) -> None:
        run_in_background()
        while True:
            with self._cv:
                while self._latest is None and not self._stopped:
                    self._cv.wait()
                if self._stopped:
                    return
                frame, self._latest = self._latest, None
            jpeg = self.encode(*frame[:4])
            if jpeg is not None:
                self.encoded += 1
                self.deliver(jpeg, frame[4])

    def encode(self, data, width: int, height: int, encoding: str) -> bytes | None:
        img = np.frombuffer(data, np.uint8)
        if img.size != width * height * 3:
            return None
        img = img.reshape(height, width, 3)
        if encoding == "rgb8":
            img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
        ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        return jpeg.tobytes() if ok else None

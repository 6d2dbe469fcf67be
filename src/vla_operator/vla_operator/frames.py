"""The live view's JPEG encoder (no rclpy): a thread of its own that encodes only the latest frame.

Why a thread: encoding 640x480 takes several ms; on the node's executor it delayed the station's
50 Hz Joy stream (the controller stops after 0.1 s without Joy and then waits for neutral: a press
that came right after such a gap did nothing) and a backlog of frames was encoded one after the other.
Here the executor only hands the latest image over; OpenCV releases the GIL while it converts and
encodes, so the encoding runs beside the node's callbacks and the web server. Frames that come while
one is being encoded replace each other: only the newest is encoded, so there is never a backlog.
The thread runs at background priority (vla_common.priority): the station's web thread, which
receives the operator's input, runs before it.

Any DDS peer may publish on the camera topic, so an image is untrusted: its size, encoding, row step
and data length are checked before any use (:func:`image_problem`), and whatever still fails in
OpenCV is counted, never raised: one 0x0 or corrupt image used to kill this thread, and the view
froze for good while the page still said it was connected (issue 32).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
from vla_common.priority import run_in_background

# Channels per pixel of the encodings shown; any other is refused (counted, never shown).
CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
TO_BGR = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR}
MAX_SIDE = 4096        # px: a larger image is not a camera of this robot (and would stall the encoder)


def image_problem(width: int, height: int, encoding: str, step: int, size: int) -> str | None:
    """Why an image cannot be shown, or None. ``step``: bytes per row (0: rows packed), ``size``: the
    data's length. Never quotes the encoding (a peer's string)."""
    if encoding not in CHANNELS:
        return "an encoding the view does not show"
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        return f"a size outside 1..{MAX_SIDE} px"
    row = width * CHANNELS[encoding]
    if step and step < row:
        return "a row step shorter than a row"
    if size < (step or row) * (height - 1) + row:
        return "fewer bytes than its size needs"
    return None


def to_bgr(data, width: int, height: int, encoding: str, step: int = 0) -> np.ndarray:
    """The image as a height x width x 3 BGR array (checked first with :func:`image_problem`)."""
    ch = CHANNELS[encoding]
    step = step or width * ch
    buf = np.frombuffer(data, np.uint8)
    rows = np.lib.stride_tricks.as_strided(buf, (height, width * ch), (step, 1))
    img = rows.reshape(height, width, ch) if ch > 1 else rows.reshape(height, width)
    if encoding == "mono8":
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_GRAY2BGR)
    if encoding in TO_BGR:
        return cv2.cvtColor(np.ascontiguousarray(img), TO_BGR[encoding])
    return np.ascontiguousarray(img)


class FrameEncoder:
    def __init__(self, deliver: Callable[[bytes, dict], None], quality: int = 80):
        self.deliver, self.quality = deliver, quality
        self.received = self.encoded = self.skipped = self.refused = self.failed = 0
        self.last_problem = ""            # why the last refused or failed image was not shown
        self._latest: tuple | None = None
        self._cv = threading.Condition()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="operator-frames", daemon=True)
        self._thread.start()

    def submit(self, data, width: int, height: int, encoding: str, meta: dict, step: int = 0) -> None:
        """The newest frame (``data``: any buffer, as a sensor_msgs/Image's); one not yet encoded is
        dropped. An image that cannot be shown is counted (``refused``) and changes nothing: the last
        good frame stays the latest."""
        problem = image_problem(width, height, encoding, step, len(data))
        with self._cv:
            self.received += 1
            if problem:
                self.refused += 1
                self.last_problem = problem
                return
            if self._latest is not None:
                self.skipped += 1
            self._latest = (data, width, height, encoding, step, {**meta, "received": time.monotonic()})
            self._cv.notify()

    def stop(self) -> None:
        with self._cv:
            self._stopped = True
            self._cv.notify()
        self._thread.join(2.0)

    def alive(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        run_in_background()
        while True:
            with self._cv:
                while self._latest is None and not self._stopped:
                    self._cv.wait()
                if self._stopped:
                    return
                frame, self._latest = self._latest, None
            try:
                jpeg = self.encode(*frame[:5])
                if jpeg is None:
                    raise ValueError("the JPEG encoder refused it")
                self.encoded += 1
                self.deliver(jpeg, frame[5])
            except Exception as e:  # noqa: BLE001 - nothing a peer sends may end the view
                self.failed += 1
                self.last_problem = f"not encoded ({type(e).__name__})"

    def encode(self, data, width: int, height: int, encoding: str, step: int = 0) -> bytes | None:
        """The JPEG of one image, or None when it cannot be shown."""
        if image_problem(width, height, encoding, step, len(data)):
            return None
        ok, jpeg = cv2.imencode(".jpg", to_bgr(data, width, height, encoding, step),
                                [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        return jpeg.tobytes() if ok else None

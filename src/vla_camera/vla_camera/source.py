"""Frame sources for the camera node: a V4L2 device, a video file or a folder/glob of images.

Plain Python + OpenCV (no rclpy) so the reading, looping, end-of-file and reconnect logic is unit-tested
without ROS. The node calls :meth:`FrameSource.read` from a timer at the publish rate; a source never
sleeps and never raises for a device that is missing or disappears: it reports ``RECONNECTING`` and
retries on an exponential backoff measured on the caller's clock.
"""
from __future__ import annotations

import enum
import glob
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
PIXEL_FORMATS = ("rgb8", "bgr8", "mono8")
_GLOB_CHARS = re.compile(r"[*?\[]")


class SourceError(ValueError):
    """A source specification that can never work (missing file, empty folder, unreadable video)."""


class SourceKind(enum.Enum):
    DEVICE = "device"
    VIDEO = "video"
    IMAGES = "images"


class SourceState(enum.Enum):
    STREAMING = "streaming"
    PAUSED = "paused"
    RECONNECTING = "reconnecting"
    ENDED = "ended"


@dataclass
class SourceSpec:
    kind: SourceKind
    target: int | str  # device index or path, video path, or list-of-images description
    images: list[str] = field(default_factory=list)

    def describe(self) -> str:
        if self.kind is SourceKind.IMAGES:
            return f"{len(self.images)} images from {self.target}"
        return f"{self.kind.value} {self.target}"


def parse_source(spec: str) -> SourceSpec:
    """Decide what ``spec`` names: a device index, ``/dev/videoN``, a video file or image folder/glob.

    A device need not exist yet (it is opened with backoff); a file, folder or glob must exist now.
    """
    spec = str(spec).strip()
    if not spec:
        raise SourceError("source is empty: give a device index (0), /dev/videoN, a video file or a folder")
    if spec.isdigit():
        return SourceSpec(SourceKind.DEVICE, int(spec))
    if spec.startswith("/dev/"):
        return SourceSpec(SourceKind.DEVICE, spec)
    path = os.path.expanduser(spec)
    if os.path.isdir(path):
        images = sorted(
            os.path.join(path, name) for name in os.listdir(path) if name.lower().endswith(IMAGE_EXTENSIONS)
        )
        if not images:
            raise SourceError(f"source folder {path!r} holds no images ({', '.join(IMAGE_EXTENSIONS)})")
        return SourceSpec(SourceKind.IMAGES, path, images)
    if _GLOB_CHARS.search(path):
        images = sorted(p for p in glob.glob(path) if os.path.isfile(p))
        if not images:
            raise SourceError(f"source glob {path!r} matches no files")
        return SourceSpec(SourceKind.IMAGES, path, images)
    if os.path.isfile(path):
        if path.lower().endswith(IMAGE_EXTENSIONS):
            return SourceSpec(SourceKind.IMAGES, path, [path])
        return SourceSpec(SourceKind.VIDEO, path)
    raise SourceError(f"source {spec!r} is not a device index, /dev/videoN, an existing file, folder or glob")


class Backoff:
    """Exponential retry delay: ``initial``, doubling up to ``maximum``; reset on success."""

    def __init__(self, initial: float = 0.25, maximum: float = 8.0):
        if not (0 < initial <= maximum):
            raise ValueError(f"backoff needs 0 < initial ({initial}) <= maximum ({maximum})")
        self.initial = initial
        self.maximum = maximum
        self.attempts = 0
        self._next_delay = initial
        self.next_time = float("-inf")

    def due(self, now: float) -> bool:
        return now >= self.next_time

    def failed(self, now: float) -> float:
        """Record a failed attempt at ``now``; returns the delay until the next one."""
        self.attempts += 1
        delay = self._next_delay
        self.next_time = now + delay
        self._next_delay = min(self._next_delay * 2.0, self.maximum)
        return delay

    def reset(self) -> None:
        self.attempts = 0
        self._next_delay = self.initial
        self.next_time = float("-inf")


def convert_frame(bgr: np.ndarray, pixel_format: str, width: int = 0, height: int = 0) -> np.ndarray:
    """OpenCV's BGR (or grey) frame → the requested encoding and, when given, size."""
    if bgr.ndim == 2:
        bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
    elif bgr.shape[2] == 4:
        bgr = cv2.cvtColor(bgr, cv2.COLOR_BGRA2BGR)
    if width > 0 and height > 0 and (bgr.shape[1], bgr.shape[0]) != (width, height):
        shrinking = width * height < bgr.shape[0] * bgr.shape[1]
        interpolation = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
        bgr = cv2.resize(bgr, (width, height), interpolation=interpolation)
    if pixel_format == "bgr8":
        return np.ascontiguousarray(bgr)
    if pixel_format == "rgb8":
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    if pixel_format == "mono8":
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    raise ValueError(f"pixel_format {pixel_format!r} is not one of {PIXEL_FORMATS}")


@dataclass
class ReadResult:
    """What one :meth:`FrameSource.read` produced: a frame, or the reason there is none."""

    frame: np.ndarray | None
    state: SourceState
    message: str = ""
    opened: bool = False  # the device/file was (re)opened during this call
    looped: bool = False  # a file source wrapped around to its start


def _default_capture_opener(target: int | str):
    """Open a cv2.VideoCapture; V4L2 backend for devices on Linux (no FFmpeg guessing)."""
    if isinstance(target, int) or str(target).startswith("/dev/"):
        node = f"/dev/video{target}" if isinstance(target, int) else target
        if sys.platform.startswith("linux") and not os.path.exists(node):
            return None  # missing device: skip OpenCV's stderr warnings on every retry
        backend = cv2.CAP_V4L2 if sys.platform.startswith("linux") else cv2.CAP_ANY
        return cv2.VideoCapture(target, backend)
    return cv2.VideoCapture(target)


class FrameSource:
    """Reads frames on demand from one :class:`SourceSpec`, converting them to ``pixel_format``.

    ``width``/``height`` of 0 keep the native size; otherwise frames are resized to exactly that size
    (a device is also asked for it). At the end of a file or folder the source loops when ``loop`` is
    set and reports ``ENDED`` otherwise. A device that fails to open or read is closed and retried on
    :class:`Backoff`; ``capture_opener`` is injectable for tests.
    """

    def __init__(
        self,
        spec: SourceSpec,
        *,
        pixel_format: str = "rgb8",
        width: int = 0,
        height: int = 0,
        fps: float = 30.0,
        loop: bool = False,
        backoff: Backoff | None = None,
        capture_opener: Callable[[int | str], object] | None = None,
        image_reader: Callable[[str], np.ndarray | None] | None = None,
    ):
        if pixel_format not in PIXEL_FORMATS:
            raise ValueError(f"pixel_format {pixel_format!r} is not one of {PIXEL_FORMATS}")
        self.spec = spec
        self.pixel_format = pixel_format
        self.width = width
        self.height = height
        self.fps = fps
        self.loop = loop
        self.backoff = backoff or Backoff()
        self._open_capture = capture_opener or _default_capture_opener
        self._read_image = image_reader or (lambda p: cv2.imread(p, cv2.IMREAD_COLOR))
        self._cap = None
        self._index = 0  # next image in a folder
        self._frames_in_pass = 0  # frames read since the file was (re)opened, to detect empty videos
        self.state = SourceState.RECONNECTING if spec.kind is SourceKind.DEVICE else SourceState.STREAMING
        self.paused = False
        self.last_error = ""
        if spec.kind is SourceKind.VIDEO:
            self._open_video()

    # -- lifecycle ---------------------------------------------------------------------------------
    def _open_video(self) -> None:
        cap = self._open_capture(self.spec.target)
        if cap is None or not cap.isOpened():
            raise SourceError(f"cannot open video file {self.spec.target!r} (unknown container or codec?)")
        self._cap = cap
        self._frames_in_pass = 0

    def close(self) -> None:
        if self._cap is not None:
            try:
                self._cap.release()
            except Exception:  # noqa: BLE001 - releasing a dead device must not raise
                pass
            self._cap = None

    def pause(self) -> None:
        """Stop capturing; a device is released (frees it, turns its LED off), files keep position."""
        self.paused = True
        if self.spec.kind is SourceKind.DEVICE:
            self.close()
            self.backoff.reset()

    def resume(self) -> None:
        self.paused = False
        if self.spec.kind is SourceKind.DEVICE and self._cap is None:
            self.state = SourceState.RECONNECTING

    def restart(self) -> None:
        """Rewind an ended file/folder to its first frame."""
        if self.spec.kind is SourceKind.IMAGES:
            self._index = 0
        elif self.spec.kind is SourceKind.VIDEO:
            self.close()
            self._open_video()
        self.state = SourceState.STREAMING

    @property
    def current_state(self) -> SourceState:
        return SourceState.PAUSED if self.paused else self.state

    # -- reading -----------------------------------------------------------------------------------
    def read(self, now: float) -> ReadResult:
        """One frame (converted) or the reason there is none. ``now`` is a monotonic time in seconds."""
        if self.paused:
            return ReadResult(None, SourceState.PAUSED, "capture paused")
        if self.state is SourceState.ENDED:
            return ReadResult(None, SourceState.ENDED, "end of source")
        if self.spec.kind is SourceKind.DEVICE:
            return self._read_device(now)
        if self.spec.kind is SourceKind.VIDEO:
            return self._read_video()
        return self._read_image_folder()

    def _read_device(self, now: float) -> ReadResult:
        opened = False
        if self._cap is None:
            if not self.backoff.due(now):
                return ReadResult(None, SourceState.RECONNECTING, self.last_error)
            cap = None
            reason = f"cannot open device {self.spec.target}"
            try:
                cap = self._open_capture(self.spec.target)
            except Exception as exc:  # noqa: BLE001 - a driver error is a failed attempt, not a crash
                reason = f"opening {self.spec.target} failed: {exc}"
            if cap is None or not cap.isOpened():
                if cap is not None:
                    cap.release()
                return self._device_failed(now, reason)
            self._configure_device(cap)
            self._cap = cap
            opened = True
        reason = f"device {self.spec.target} returned no frame (unplugged?)"
        try:
            ok, frame = self._cap.read()
        except Exception as exc:  # noqa: BLE001
            ok, frame = False, None
            reason = f"reading {self.spec.target} failed: {exc}"
        if not ok or frame is None:
            self.close()
            return self._device_failed(now, reason)
        self.backoff.reset()
        self.last_error = ""
        self.state = SourceState.STREAMING
        return ReadResult(self._convert(frame), SourceState.STREAMING, opened=opened)

    def _device_failed(self, now: float, reason: str) -> ReadResult:
        delay = self.backoff.failed(now)
        self.state = SourceState.RECONNECTING
        self.last_error = f"{reason}; retry {self.backoff.attempts + 1} in {delay:.2f} s"
        return ReadResult(None, SourceState.RECONNECTING, self.last_error)

    def _configure_device(self, cap) -> None:
        if self.width > 0 and self.height > 0:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps > 0:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        # Keep latency low: don't let the driver queue stale frames.
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)

    def _read_video(self) -> ReadResult:
        looped = False
        ok, frame = self._cap.read()
        if not ok or frame is None:
            if self._frames_in_pass == 0:
                self.state = SourceState.ENDED
                msg = f"video {self.spec.target} holds no readable frame"
                return ReadResult(None, SourceState.ENDED, msg)
            if not self.loop:
                self.state = SourceState.ENDED
                self.close()
                return ReadResult(None, SourceState.ENDED, f"end of video {self.spec.target}")
            self.close()
            self._open_video()
            looped = True
            ok, frame = self._cap.read()
            if not ok or frame is None:
                self.state = SourceState.ENDED
                return ReadResult(None, SourceState.ENDED, f"video {self.spec.target} cannot be re-read")
        self._frames_in_pass += 1
        return ReadResult(self._convert(frame), SourceState.STREAMING, looped=looped)

    def _read_image_folder(self) -> ReadResult:
        """Next readable image; unreadable files are skipped (reported), never fatal."""
        images = self.spec.images
        looped = False
        skipped: list[str] = []
        for _ in range(len(images) + 1):
            if self._index >= len(images):
                if not self.loop:
                    self.state = SourceState.ENDED
                    msg = "end of image list"
                    if skipped:
                        msg += f" (skipped unreadable: {', '.join(skipped)})"
                    return ReadResult(None, SourceState.ENDED, msg)
                self._index = 0
                looped = True
            path = images[self._index]
            self._index += 1
            frame = self._read_image(path)
            if frame is not None:
                msg = f"skipped unreadable: {', '.join(skipped)}" if skipped else ""
                return ReadResult(self._convert(frame), SourceState.STREAMING, msg, looped=looped)
            skipped.append(path)
        self.state = SourceState.ENDED
        return ReadResult(None, SourceState.ENDED, f"no readable image among {len(images)} files")

    def _convert(self, frame: np.ndarray) -> np.ndarray:
        return convert_frame(frame, self.pixel_format, self.width, self.height)

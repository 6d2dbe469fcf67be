"""The live view's encoder: only the newest frame is encoded, colours survive, and no image a peer sends
(0x0, corrupt, an unknown encoding or size) stops it."""
import threading
import time

import cv2
import numpy as np
import pytest
from vla_operator.frames import FrameEncoder


def test_frames_that_come_while_one_is_encoded_replace_each_other():
    delivered, first_in, go = [], threading.Event(), threading.Event()
    done = threading.Condition()

    def deliver(jpeg: bytes, meta: dict) -> None:
        first_in.set()
        go.wait(10.0)                   # the first frame's delivery is slow: the others pile up
        with done:
            delivered.append(meta["n"])
            done.notify_all()

    enc = FrameEncoder(deliver, 80)
    try:
        img = np.zeros((48, 64, 3), np.uint8)
        enc.submit(img.tobytes(), 64, 48, "bgr8", {"n": 0})
        assert first_in.wait(10.0)
        for n in range(1, 6):
            enc.submit(img.tobytes(), 64, 48, "bgr8", {"n": n})
        go.set()
        with done:
            assert done.wait_for(lambda: len(delivered) == 2, 10.0)
        assert delivered == [0, 5] and enc.received == 6 and enc.skipped == 4 and enc.encoded == 2
    finally:
        go.set()
        enc.stop()


def test_rgb8_is_encoded_with_its_colours_and_a_wrong_size_is_skipped():
    enc = FrameEncoder(lambda jpeg, meta: None, 95)
    try:
        rgb = np.zeros((32, 32, 3), np.uint8)
        rgb[..., 0] = 255                                       # red in rgb8
        jpeg = enc.encode(rgb.tobytes(), 32, 32, "rgb8")
        bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert bgr[16, 16, 2] > 240 and bgr[16, 16, 0] < 15      # still red
        assert enc.encode(b"\0" * 10, 32, 32, "rgb8") is None
    finally:
        enc.stop()


def test_frames_are_encoded_at_background_priority():
    """The station's web thread (the operator's input) runs before the encoder (vla_common.priority)."""
    from vla_common.priority import BACKGROUND_NICE, MAX_NICE, thread_nice

    here, seen, got = thread_nice(), [], threading.Event()
    enc = FrameEncoder(lambda jpeg, meta: (seen.append(thread_nice()), got.set()), 80)
    try:
        enc.submit(np.zeros((8, 8, 3), np.uint8).tobytes(), 8, 8, "bgr8", {})
        assert got.wait(10.0)
        assert seen == [min(MAX_NICE, here + BACKGROUND_NICE)] and thread_nice() == here
    finally:
        enc.stop()


def _good(n: int = 0) -> tuple:
    img = np.full((24, 32, 3), n % 250, np.uint8)
    return img.tobytes(), 32, 24, "bgr8", {"n": n}


@pytest.mark.parametrize("data, width, height, encoding, step", [
    (b"", 0, 0, "rgb8", 0),                                   # the 0x0 image that killed the thread
    (b"", 32, 24, "rgb8", 0),                                 # no data for its size
    (b"\x01" * 100, 32, 24, "bgr8", 0),                       # corrupt: too short
    (b"\x01" * (32 * 24 * 3), 32, 24, "16UC1", 0),            # an encoding the view does not show
    (b"\x01" * (32 * 24 * 3), 32, 24, "<script>", 0),
    (b"\x01" * (32 * 24 * 3), 32, 24, "rgb8", 10),            # a row step shorter than a row
    (b"\x01" * (32 * 24 * 3), 32, 24, "rgb8", 32 * 3 + 1),    # a longer step than the data holds
    (b"\x01" * 30, 10**6, 10**6, "rgb8", 0),                  # a size no camera of ours has
    (b"\x01" * 30, -1, 10, "rgb8", 0),
], ids=["0x0", "no-data", "too-short", "16UC1", "markup-encoding", "short-step", "long-step", "huge",
        "negative"])
def test_an_image_that_cannot_be_shown_is_counted_and_the_view_goes_on(data, width, height, encoding, step):
    """Issue 32: one 0x0 image from any DDS peer killed the encoder's thread; the view froze for good."""
    got, cv = [], threading.Condition()

    def deliver(jpeg, meta):
        with cv:
            got.append(meta["n"])
            cv.notify_all()
    enc = FrameEncoder(deliver, 80)
    try:
        enc.submit(*_good(0))
        with cv:
            assert cv.wait_for(lambda: got == [0], 10.0)
        enc.submit(data, width, height, encoding, {"n": -1}, step=step)
        enc.submit(*_good(1))
        with cv:
            assert cv.wait_for(lambda: got == [0, 1], 10.0), got
        assert enc.refused == 1 and enc.failed == 0 and enc.alive() and enc.last_problem
        assert "script" not in enc.last_problem
    finally:
        enc.stop()


def test_an_image_opencv_fails_on_is_counted_and_the_thread_lives(monkeypatch):
    got = threading.Event()
    enc = FrameEncoder(lambda jpeg, meta: got.set() if meta["n"] == 1 else None, 80)
    try:
        calls = []

        def imencode(*a, **k):
            calls.append(1)
            if len(calls) == 1:
                raise cv2.error("corrupt")
            return real(*a, **k)
        real = cv2.imencode
        monkeypatch.setattr(cv2, "imencode", imencode)
        enc.submit(*_good(0))
        assert wait_until(lambda: enc.failed == 1)
        enc.submit(*_good(1))
        assert got.wait(10.0) and enc.alive() and enc.encoded == 1
    finally:
        enc.stop()


def wait_until(pred, timeout: float = 10.0) -> bool:
    """A condition, with a generous timeout only against a hang."""
    end = time.monotonic() + timeout
    while not pred() and time.monotonic() < end:
        threading.Event().wait(0.005)
    return pred()


def test_padded_rows_grey_and_alpha_images_keep_their_pixels():
    enc = FrameEncoder(lambda jpeg, meta: None, 95)
    try:
        rgba = np.zeros((16, 20, 4), np.uint8)
        rgba[..., 2] = 255                                        # blue in rgba8
        padded = np.zeros((16, 20 * 4 + 8), np.uint8)             # rows padded to a step of 88 bytes
        padded[:, :80] = rgba.reshape(16, 80)
        bgr = cv2.imdecode(np.frombuffer(enc.encode(padded.tobytes(), 20, 16, "rgba8", 88), np.uint8),
                           cv2.IMREAD_COLOR)
        assert bgr.shape == (16, 20, 3) and bgr[8, 10, 0] > 240 and bgr[8, 10, 2] < 15
        grey = enc.encode(np.full((8, 8), 200, np.uint8).tobytes(), 8, 8, "mono8")
        assert abs(int(cv2.imdecode(np.frombuffer(grey, np.uint8), cv2.IMREAD_COLOR)[4, 4, 1]) - 200) < 5
    finally:
        enc.stop()

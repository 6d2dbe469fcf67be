"""The live view's encoder: only the newest frame is encoded, colours survive, bad sizes are skipped."""
import threading

import cv2
import numpy as np
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

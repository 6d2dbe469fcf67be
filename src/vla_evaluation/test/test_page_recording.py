"""demo --record-page: a page recorded through headless Chromium's screencast into an mp4 that plays in
real time, and the browser gone afterwards (VLA_REQUIRE_BROWSER=1 in CI: it cannot skip there)."""
import threading
import time
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
import pytest
from require import missing
from vla_evaluation.page_recording import PageRecorder, RecordingError, find_chromium

PAGE = ("<!doctype html><html lang=en><title>t</title><body><h1 id=t>0</h1><script>let n = 0;"
        "setInterval(() => { document.getElementById('t').textContent = String(++n); }, 50);</script>")


def test_a_changing_page_is_recorded_at_a_fixed_rate_and_the_browser_ends(tmp_path):
    try:
        find_chromium()
    except RecordingError as e:
        missing("BROWSER", str(e))
    (tmp_path / "index.html").write_text(PAGE)
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(SimpleHTTPRequestHandler, directory=str(tmp_path)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    rec = PageRecorder(f"http://127.0.0.1:{server.server_port}/", tmp_path / "page.mp4", size=(640, 480))
    try:
        rec.start()
        deadline = time.monotonic() + 60.0
        while rec.frames < 10 and time.monotonic() < deadline:   # the page's frames, as they come
            time.sleep(0.05)
        assert rec.frames >= 10
    finally:
        path = rec.stop()
        server.shutdown()
    assert path == tmp_path / "page.mp4"
    video = cv2.VideoCapture(str(path))
    n, fps = video.get(cv2.CAP_PROP_FRAME_COUNT), video.get(cv2.CAP_PROP_FPS)
    ok, frame = video.read()
    assert ok and frame.shape[1] == 640 and fps == pytest.approx(rec.fps)
    assert n == rec.written and n >= 2          # repeated frames fill the time between the page's own
    assert rec._proc.poll() is not None         # the browser's process ended with the recording


def test_a_frame_of_another_size_is_fitted_into_the_video_with_its_aspect_kept():
    from vla_evaluation.page_recording import fit

    frame = np.full((480, 548, 3), 200, np.uint8)   # a screencast frame seen for a 640x480 window
    out = fit(frame, (640, 480))
    assert out.shape == (480, 640, 3)
    assert (out[:, 46:594] == 200).all() and not out[:, :46].any() and not out[:, 594:].any()
    big = fit(np.full((960, 1280, 3), 9, np.uint8), (640, 480))
    assert big.shape == (480, 640, 3) and (big == 9).all()

"""Frame sources without ROS: parsing, video files (loop/end), image folders, device reconnect."""
import cv2
import numpy as np
import pytest
from vla_camera.source import (
    Backoff,
    FrameSource,
    SourceError,
    SourceKind,
    SourceState,
    convert_frame,
    parse_source,
)

W, H = 64, 48


def make_video(path, levels, size=(W, H), fps=10):
    """MJPG .avi whose frame i is a uniform grey of ``levels[i]`` (survives JPEG nearly exactly)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert writer.isOpened()
    for level in levels:
        writer.write(np.full((size[1], size[0], 3), level, np.uint8))
    writer.release()
    return str(path)


def make_images(folder, colours):
    """PNG files img_00.png… each a uniform BGR colour."""
    folder.mkdir(exist_ok=True)
    for i, bgr in enumerate(colours):
        cv2.imwrite(str(folder / f"img_{i:02d}.png"), np.full((H, W, 3), bgr, np.uint8))
    return str(folder)


def level(frame):
    return int(round(float(frame.mean())))


def drain(source, limit=100):
    frames = []
    for _ in range(limit):
        r = source.read(0.0)
        if r.frame is None:
            return frames, r
        frames.append(r.frame)
    return frames, r


# -- parse_source ------------------------------------------------------------------------------------
def test_parse_source_kinds(tmp_path):
    assert parse_source("0").kind is SourceKind.DEVICE and parse_source("0").target == 0
    assert parse_source("/dev/video99").target == "/dev/video99"
    video = make_video(tmp_path / "v.avi", [10, 20])
    assert parse_source(video).kind is SourceKind.VIDEO
    folder = make_images(tmp_path / "imgs", [(0, 0, 255), (0, 255, 0)])
    spec = parse_source(folder)
    assert spec.kind is SourceKind.IMAGES and len(spec.images) == 2
    assert spec.images == sorted(spec.images)
    assert len(parse_source(folder + "/img_0*.png").images) == 2
    assert parse_source(spec.images[0]).images == [spec.images[0]]


@pytest.mark.parametrize("bad", ["", "/nonexistent/video.avi", "/nonexistent/*.png"])
def test_parse_source_rejects_missing(bad):
    with pytest.raises(SourceError):
        parse_source(bad)


def test_parse_source_rejects_empty_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("no images")
    with pytest.raises(SourceError, match="holds no images"):
        parse_source(str(tmp_path))


def test_unreadable_video_file_is_a_clear_error(tmp_path):
    bad = tmp_path / "garbage.avi"
    bad.write_bytes(b"this is not a video")
    with pytest.raises(SourceError, match="cannot open video"):
        FrameSource(parse_source(str(bad)))


# -- conversion --------------------------------------------------------------------------------------
def test_convert_frame_encodings_and_size():
    bgr = np.zeros((H, W, 3), np.uint8)
    bgr[..., 2] = 200  # red in BGR
    rgb = convert_frame(bgr, "rgb8")
    assert rgb.shape == (H, W, 3) and rgb[0, 0].tolist() == [200, 0, 0]
    assert convert_frame(bgr, "bgr8")[0, 0].tolist() == [0, 0, 200]
    mono = convert_frame(bgr, "mono8", 32, 24)
    assert mono.shape == (24, 32) and mono.dtype == np.uint8
    assert abs(int(mono[0, 0]) - round(0.299 * 200)) <= 1
    assert convert_frame(np.zeros((H, W), np.uint8), "rgb8").shape == (H, W, 3)
    with pytest.raises(ValueError):
        convert_frame(bgr, "yuv422")


# -- video files -------------------------------------------------------------------------------------
def test_video_plays_once_then_ends(tmp_path):
    video = make_video(tmp_path / "v.avi", [10, 60, 110, 160, 210])
    src = FrameSource(parse_source(video), pixel_format="bgr8")
    frames, last = drain(src)
    assert [level(f) for f in frames] == pytest.approx([10, 60, 110, 160, 210], abs=4)
    assert last.state is SourceState.ENDED and "end of video" in last.message
    assert src.read(0.0).state is SourceState.ENDED  # stays ended, never raises


def test_video_loops(tmp_path):
    video = make_video(tmp_path / "v.avi", [10, 110, 210])
    src = FrameSource(parse_source(video), loop=True, pixel_format="mono8")
    results = [src.read(0.0) for _ in range(8)]
    assert all(r.frame is not None for r in results)
    assert [level(r.frame) for r in results] == pytest.approx([10, 110, 210] * 2 + [10, 110], abs=4)
    assert [r.looped for r in results] == [False, False, False, True, False, False, True, False]


def test_video_resized_to_requested_size(tmp_path):
    src = FrameSource(parse_source(make_video(tmp_path / "v.avi", [50])), width=32, height=20)
    assert src.read(0.0).frame.shape == (20, 32, 3)


def test_video_restart_after_end(tmp_path):
    src = FrameSource(parse_source(make_video(tmp_path / "v.avi", [10, 200])))
    frames, _ = drain(src)
    assert len(frames) == 2
    src.restart()
    assert level(src.read(0.0).frame) == pytest.approx(10, abs=4)


# -- image folders -----------------------------------------------------------------------------------
def test_image_folder_order_colour_and_end(tmp_path):
    folder = make_images(tmp_path / "imgs", [(255, 0, 0), (0, 255, 0), (0, 0, 255)])  # BGR: blue, green, red
    src = FrameSource(parse_source(folder), pixel_format="rgb8")
    frames, last = drain(src)
    assert [f[0, 0].tolist() for f in frames] == [[0, 0, 255], [0, 255, 0], [255, 0, 0]]
    assert last.state is SourceState.ENDED


def test_image_folder_loops_and_skips_unreadable(tmp_path):
    folder = make_images(tmp_path / "imgs", [(10, 10, 10), (90, 90, 90)])
    (tmp_path / "imgs" / "img_00b.png").write_bytes(b"corrupt")
    src = FrameSource(parse_source(folder), loop=True, pixel_format="mono8")
    results = [src.read(0.0) for _ in range(5)]
    assert [level(r.frame) for r in results] == [10, 90, 10, 90, 10]
    assert "img_00b.png" in results[1].message  # reported, not fatal


def test_folder_of_only_unreadable_images_ends(tmp_path):
    (tmp_path / "a.png").write_bytes(b"x")
    src = FrameSource(parse_source(str(tmp_path)), loop=True)
    r = src.read(0.0)
    assert r.frame is None and r.state is SourceState.ENDED and "no readable image" in r.message


def test_pause_holds_position(tmp_path):
    src = FrameSource(parse_source(make_video(tmp_path / "v.avi", [10, 110, 210])), pixel_format="mono8")
    assert level(src.read(0.0).frame) == pytest.approx(10, abs=4)
    src.pause()
    r = src.read(0.0)
    assert r.frame is None and r.state is SourceState.PAUSED and src.current_state is SourceState.PAUSED
    src.resume()
    assert level(src.read(0.0).frame) == pytest.approx(110, abs=4)


# -- devices -----------------------------------------------------------------------------------------
class FakeCapture:
    """Stands in for cv2.VideoCapture: ``frames`` good reads, then failures (an unplugged camera)."""

    def __init__(self, frames, opened=True):
        self.frames = frames
        self.opened = opened
        self.released = False
        self.props = {}

    def isOpened(self):
        return self.opened

    def read(self):
        if self.frames <= 0:
            return False, None
        self.frames -= 1
        return True, np.full((H, W, 3), 77, np.uint8)

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def release(self):
        self.released = True


def test_backoff_doubles_and_caps():
    b = Backoff(0.5, 2.0)
    assert b.due(0.0)
    assert [b.failed(t) for t in (0.0, 0.5, 1.5, 3.5, 5.5)] == [0.5, 1.0, 2.0, 2.0, 2.0]
    assert b.attempts == 5 and not b.due(7.4) and b.due(7.5)
    b.reset()
    assert b.attempts == 0 and b.due(0.0)
    with pytest.raises(ValueError):
        Backoff(2.0, 1.0)


def test_missing_device_reconnects_with_backoff_without_raising():
    calls = []

    def opener(target):
        calls.append(target)
        return None  # device node absent

    src = FrameSource(parse_source("/dev/video99"), backoff=Backoff(0.25, 1.0), capture_opener=opener)
    t, states = 0.0, set()
    while t < 3.0:  # a 100 Hz timer for 3 s
        r = src.read(t)
        states.add(r.state)
        assert r.frame is None
        t += 0.01
    assert states == {SourceState.RECONNECTING}
    # attempts at 0, .25, .75, 1.75, 2.75 -> 5 tries in 300 ticks: backoff, not a busy retry
    assert len(calls) == 5 and src.backoff.attempts == 5
    assert "cannot open device /dev/video99" in src.last_error


def test_device_unplug_and_replug():
    plan = [FakeCapture(3), FakeCapture(0, opened=False), FakeCapture(2)]
    opened = []

    def opener(target):
        cap = plan.pop(0)
        opened.append(cap)
        return cap

    src = FrameSource(parse_source("2"), backoff=Backoff(0.1, 1.0), capture_opener=opener, width=W, height=H)
    results = [src.read(i * 0.05) for i in range(12)]
    states = [r.state for r in results]
    assert states[:3] == [SourceState.STREAMING] * 3 and results[0].opened
    assert states[3] is SourceState.RECONNECTING and opened[0].released  # unplugged: closed, not raised
    assert SourceState.STREAMING in states[4:]  # replugged: streaming again
    assert opened[0].props[cv2.CAP_PROP_FRAME_WIDTH] == W
    assert src.backoff.attempts in (0, 1, 2)


def test_device_pause_releases_and_resume_reopens():
    caps = []

    def opener(target):
        caps.append(FakeCapture(100))
        return caps[-1]

    src = FrameSource(parse_source("0"), capture_opener=opener)
    assert src.read(0.0).frame is not None
    src.pause()
    assert caps[0].released and src.read(1.0).state is SourceState.PAUSED
    src.resume()
    assert src.read(2.0).frame is not None and len(caps) == 2


def test_opener_exception_is_a_failed_attempt():
    def opener(target):
        raise RuntimeError("driver exploded")

    src = FrameSource(parse_source("0"), capture_opener=opener)
    r = src.read(0.0)
    assert r.state is SourceState.RECONNECTING and "driver exploded" in r.message

"""Image message payloads -> RGB for every supported encoding; bad payloads rejected with a reason."""

import numpy as np
import pytest
from vla_common.detection import Detection
from vla_common.image_convert import UnsupportedImageError, draw_detections, to_rgb

H, W = 6, 8


@pytest.fixture
def rgb():
    return np.random.default_rng(1).integers(0, 255, (H, W, 3), dtype=np.uint8)


@pytest.mark.parametrize(
    "encoding,make",
    [
        ("rgb8", lambda x: x),
        ("bgr8", lambda x: x[..., ::-1]),
        ("8UC3", lambda x: x[..., ::-1]),
        ("rgba8", lambda x: np.dstack([x, np.full(x.shape[:2], 255, np.uint8)])),
        ("bgra8", lambda x: np.dstack([x[..., ::-1], np.zeros(x.shape[:2], np.uint8)])),
    ],
)
def test_colour_encodings(rgb, encoding, make):
    raw = np.ascontiguousarray(make(rgb))
    out = to_rgb(encoding, W, H, raw.shape[1] * raw.shape[2], raw.tobytes())
    np.testing.assert_array_equal(out, rgb)


def test_mono_and_16bit(rgb):
    gray = rgb[..., 0].copy()
    np.testing.assert_array_equal(to_rgb("mono8", W, H, W, gray.tobytes()), np.dstack([gray] * 3))
    g16 = gray.astype(np.uint16) << 8
    np.testing.assert_array_equal(
        to_rgb("mono16", W, H, 2 * W, g16.astype("<u2").tobytes()), np.dstack([gray] * 3)
    )
    np.testing.assert_array_equal(
        to_rgb("mono16", W, H, 2 * W, g16.astype(">u2").tobytes(), is_bigendian=True), np.dstack([gray] * 3)
    )


def test_yuv422():
    r, g, b = 200, 40, 90  # BT.601 video range, what V4L2 YUYV / UYVY cameras send
    y = round(16 + 0.257 * r + 0.504 * g + 0.098 * b)
    u = round(128 - 0.148 * r - 0.291 * g + 0.439 * b)
    v = round(128 + 0.439 * r - 0.368 * g - 0.071 * b)
    for enc, quad in (
        ("yuyv", [y, u, y, v]),
        ("yuv422_yuy2", [y, u, y, v]),
        ("uyvy", [u, y, v, y]),
        ("yuv422", [u, y, v, y]),
    ):
        packed = np.tile(np.array(quad, np.uint8), H * W // 2)
        out = to_rgb(enc, W, H, 2 * W, packed.tobytes())
        assert out.shape == (H, W, 3)
        assert np.abs(out.astype(int) - (r, g, b)).max() <= 3, enc


def test_row_padding_is_skipped(rgb):
    step = W * 3 + 5
    buf = np.zeros((H, step), np.uint8)
    buf[:, : W * 3] = rgb.reshape(H, -1)
    np.testing.assert_array_equal(to_rgb("rgb8", W, H, step, buf.tobytes()), rgb)


def test_rclpy_array_payload(rgb):
    import array

    np.testing.assert_array_equal(to_rgb("rgb8", W, H, 3 * W, array.array("B", rgb.tobytes())), rgb)


@pytest.mark.parametrize(
    "args,match",
    [
        (("jpeg", W, H, 3 * W, b"x" * 144), "unsupported encoding"),
        (("rgb8", W, H, 3 * W, b"x" * 10), "needs step"),
        (("rgb8", W, H, 2 * W, b"x" * 144), "needs step"),
        (("rgb8", 0, H, 0, b""), "empty image"),
    ],
)
def test_bad_images(args, match):
    with pytest.raises(UnsupportedImageError, match=match):
        to_rgb(*args)


def test_overlay_draws_boxes(rgb):
    img = np.zeros((48, 64, 3), np.uint8)
    out = draw_detections(img, [Detection("bread", 0.9, 32, 24, 20, 10, class_index=0)])
    assert out.shape == img.shape and out.any() and not img.any()

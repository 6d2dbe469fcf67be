"""sensor_msgs/Image payloads <-> NumPy RGB, without cv_bridge (no wheel of it exists here).

Works on the message's fields, not the message type, so it is tested without rclpy. Encodings a
webcam driver or a simulator produce are converted to RGB; anything else raises
`UnsupportedImageError` with the reason, for the node to skip the frame with a throttled warning.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

# encoding -> (channels, bytes per channel)
_LAYOUT = {
    "rgb8": (3, 1),
    "bgr8": (3, 1),
    "rgba8": (4, 1),
    "bgra8": (4, 1),
    "mono8": (1, 1),
    "8UC1": (1, 1),
    "8UC3": (3, 1),
    "8UC4": (4, 1),
    "mono16": (1, 2),
    "16UC1": (1, 2),
    "yuv422": (2, 1),
    "uyvy": (2, 1),
    "yuv422_yuy2": (2, 1),
    "yuyv": (2, 1),
}
SUPPORTED_ENCODINGS = tuple(_LAYOUT)


class UnsupportedImageError(ValueError):
    """The image cannot be converted (encoding, size or buffer length)."""


def to_rgb(encoding: str, width: int, height: int, step: int, data, is_bigendian: bool = False) -> np.ndarray:
    """Image fields -> (H, W, 3) uint8 RGB (a new array)."""
    enc = encoding.strip()
    if enc not in _LAYOUT:
        raise UnsupportedImageError(
            f"unsupported encoding {encoding!r} (supported: {', '.join(SUPPORTED_ENCODINGS)})"
        )
    if width <= 0 or height <= 0:
        raise UnsupportedImageError(f"empty image {width}x{height}")
    ch, bpc = _LAYOUT[enc]
    row = width * ch * bpc
    step = step or row
    try:
        buf = np.frombuffer(data, dtype=np.uint8)  # bytes, array.array (rclpy), memoryview
    except (TypeError, ValueError):
        buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if step < row or buf.size < step * (height - 1) + row:
        raise UnsupportedImageError(
            f"{enc} image {width}x{height} needs step >= {row} and {step * height} bytes, "
            f"got step {step} and {buf.size} bytes"
        )
    if buf.size < step * height:  # last row without padding
        buf = np.concatenate([buf, np.zeros(step * height - buf.size, np.uint8)])
    rows = buf[: step * height].reshape(height, step)[:, :row]
    if bpc == 2:
        px = rows.copy().view(">u2" if is_bigendian else "<u2").reshape(height, width)
        gray = (px >> 8).astype(np.uint8)
        return cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB)
    img = rows.reshape(height, width, ch)
    if enc in ("rgb8",):
        return img.copy()
    if enc in ("bgr8", "8UC3"):
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if enc == "rgba8":
        return cv2.cvtColor(img, cv2.COLOR_RGBA2RGB)
    if enc in ("bgra8", "8UC4"):
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    if enc in ("mono8", "8UC1"):
        return cv2.cvtColor(img[..., 0], cv2.COLOR_GRAY2RGB)
    if enc in ("yuv422", "uyvy"):
        return cv2.cvtColor(img, cv2.COLOR_YUV2RGB_UYVY)
    return cv2.cvtColor(img, cv2.COLOR_YUV2RGB_YUYV)



def read_image(path: str | Path) -> np.ndarray:
    """Image file -> (H, W, 3) uint8 RGB; UnsupportedImageError if it cannot be decoded."""
    path = Path(path)
    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data is not None and data.size else None
    if img is None:
        raise UnsupportedImageError(
            f"{path}: unreadable image (missing, empty or not an image format OpenCV decodes)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def draw_detections(rgb: np.ndarray, detections, colours=None) -> np.ndarray:
    """Copy of the image with boxes and 'class score' labels, for the overlay topic."""
    out = rgb.copy()
    for d in detections:
        c = (colours or {}).get(d.class_index) or _colour(d.class_index)
        x1, y1 = int(round(d.cx - d.width / 2)), int(round(d.cy - d.height / 2))
        x2, y2 = int(round(d.cx + d.width / 2)), int(round(d.cy + d.height / 2))
        cv2.rectangle(out, (x1, y1), (x2, y2), c, 1)
        cv2.drawMarker(out, (int(round(d.cx)), int(round(d.cy))), c, cv2.MARKER_CROSS, 6, 1)
        cv2.putText(
            out,
            f"{d.class_id} {d.score:.2f}",
            (x1, max(10, y1 - 3)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            c,
            1,
            cv2.LINE_AA,
        )
    return out


def _colour(i: int) -> tuple[int, int, int]:
    palette = [
        (255, 56, 56),
        (50, 205, 50),
        (61, 119, 255),
        (255, 178, 29),
        (207, 210, 49),
        (72, 249, 10),
        (146, 204, 23),
        (255, 55, 199),
        (0, 194, 255),
        (52, 69, 147),
    ]
    return palette[i % len(palette)]

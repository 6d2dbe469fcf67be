"""Standard ROS camera calibration YAML (camera_calibration_parsers format), read with PyYAML.

The file is what `cameracalibrator` writes (``ost.yaml``): image_width, image_height, camera_name,
camera_matrix, distortion_model, distortion_coefficients, rectification_matrix, projection_matrix,
each matrix as ``{rows, cols, data}``. No rclpy here: the node turns a :class:`Calibration` into a
``sensor_msgs/CameraInfo``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from urllib.parse import unquote, urlparse

import yaml
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

# Number of coefficients each known distortion model takes (others are passed through unchecked).
DISTORTION_SIZES = {"plumb_bob": (5,), "rational_polynomial": (8,), "equidistant": (4,)}
ASPECT_TOLERANCE = 0.01


class CalibrationError(ValueError):
    """The calibration file is missing, malformed, or does not fit the image size."""


@dataclass
class Calibration:
    width: int
    height: int
    camera_name: str = ""
    k: list[float] = field(default_factory=lambda: [0.0] * 9)
    distortion_model: str = ""
    d: list[float] = field(default_factory=list)
    r: list[float] = field(default_factory=lambda: [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0])
    p: list[float] = field(default_factory=lambda: [0.0] * 12)

    def scaled_to(self, width: int, height: int) -> Calibration:
        """The calibration for images resized to ``width``×``height``.

        Scaling is exact only for a resize of the whole frame; a change of aspect ratio usually means
        the driver cropped, which scaling cannot undo, so that is refused.
        """
        if (width, height) == (self.width, self.height):
            return self
        if width <= 0 or height <= 0:
            raise CalibrationError(f"cannot scale calibration to {width}x{height}")
        sx, sy = width / self.width, height / self.height
        if abs(sx / sy - 1.0) > ASPECT_TOLERANCE:
            raise CalibrationError(
                f"calibration {self.camera_name or ''} is for {self.width}x{self.height} but images are "
                f"{width}x{height}: the aspect ratio differs (cropped?), recalibrate at this size"
            )
        k = list(self.k)
        k[0] *= sx
        k[1] *= sx
        k[2] *= sx
        k[4] *= sy
        k[5] *= sy
        p = list(self.p)
        p[0] *= sx
        p[1] *= sx
        p[2] *= sx
        p[3] *= sx
        p[5] *= sy
        p[6] *= sy
        p[7] *= sy
        return replace(self, width=width, height=height, k=k, p=p)


def url_to_path(url: str) -> str:
    """``file:///abs/path``, ``package://pkg/rel/path`` or a plain path → a filesystem path."""
    url = url.strip()
    if url.startswith("file://"):
        return unquote(urlparse(url).path)
    if url.startswith("package://"):
        rest = url[len("package://"):]
        pkg, _, rel = rest.partition("/")
        try:
            return os.path.join(get_package_share_directory(pkg), rel)
        except PackageNotFoundError as exc:
            raise CalibrationError(f"{url}: package {pkg!r} is not installed") from exc
    if "://" in url:
        raise CalibrationError(f"{url}: only file://, package:// or a plain path are supported")
    return os.path.expanduser(url)


def _matrix(doc: dict, key: str, rows: int, cols: int, source: str) -> list[float]:
    m = doc.get(key)
    if not isinstance(m, dict):
        raise CalibrationError(f"{source}: '{key}' missing or not a mapping with rows, cols, data")
    try:
        r, c, data = int(m["rows"]), int(m["cols"]), m["data"]
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{source}: '{key}' needs integer rows, cols and a data list ({exc})") from exc
    if (r, c) != (rows, cols):
        raise CalibrationError(f"{source}: '{key}' must be {rows}x{cols}, got {r}x{c}")
    return _numbers(data, rows * cols, key, source)


def _numbers(data, count: int | None, key: str, source: str) -> list[float]:
    if not isinstance(data, list):
        raise CalibrationError(f"{source}: '{key}' data must be a list of numbers")
    try:
        values = [float(v) for v in data]
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{source}: '{key}' data holds a non-number ({exc})") from exc
    if count is not None and len(values) != count:
        raise CalibrationError(f"{source}: '{key}' needs {count} numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise CalibrationError(f"{source}: '{key}' holds NaN or infinity")
    return values


def parse_calibration(text: str, source: str = "<string>") -> Calibration:
    """Parse calibration YAML text; every problem raises :class:`CalibrationError` naming ``source``."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{source}: not valid YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source}: expected a mapping of calibration fields")
    try:
        width, height = int(doc["image_width"]), int(doc["image_height"])
    except KeyError as exc:
        raise CalibrationError(f"{source}: missing {exc.args[0]}") from exc
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{source}: image_width/image_height must be integers") from exc
    if width <= 0 or height <= 0:
        raise CalibrationError(f"{source}: image size {width}x{height} must be positive")
    k = _matrix(doc, "camera_matrix", 3, 3, source)
    if k[0] <= 0 or k[4] <= 0:
        raise CalibrationError(f"{source}: camera_matrix focal lengths must be positive, got {k[0]}, {k[4]}")
    model = str(doc.get("distortion_model", "plumb_bob"))
    d_doc = doc.get("distortion_coefficients")
    if d_doc is None:
        d = [0.0] * DISTORTION_SIZES.get(model, (0,))[0]
    else:
        if not isinstance(d_doc, dict) or "data" not in d_doc:
            raise CalibrationError(f"{source}: 'distortion_coefficients' needs rows, cols and data")
        d = _numbers(d_doc["data"], None, "distortion_coefficients", source)
        if model in DISTORTION_SIZES and len(d) not in DISTORTION_SIZES[model]:
            raise CalibrationError(
                f"{source}: distortion_model {model} takes {DISTORTION_SIZES[model][0]} coefficients, "
                f"got {len(d)}"
            )
    r = _matrix(doc, "rectification_matrix", 3, 3, source) if "rectification_matrix" in doc else None
    p = _matrix(doc, "projection_matrix", 3, 4, source) if "projection_matrix" in doc else None
    if r is None:
        r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    if p is None:  # monocular, unrectified: P = [K | 0]
        p = [k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0]
    return Calibration(width, height, str(doc.get("camera_name", "") or ""), k, model, d, r, p)


def load_calibration(url: str) -> Calibration:
    """Read a calibration from ``file://…``, ``package://…`` or a path (clear error when unreadable)."""
    path = url_to_path(url)
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as exc:
        raise CalibrationError(f"cannot read camera calibration {path!r}: {exc.strerror or exc}") from exc
    return parse_calibration(text, path)

"""The project's QoS profiles and the image transport: one home for every image and sensor topic.

- `IMAGE_QOS` (reliable, keep-last 30, volatile) for camera images and their camera_info, publishers
  and subscribers alike. A best-effort subscriber to a 640x480 rgb8 camera at 30 Hz received about
  half of the frames between two processes (bench/bench_detector.py); reliable lost none. Keep-last
  never blocks the publisher: the oldest unacknowledged frame is overwritten. 30 frames (1 s at
  30 Hz) ride out a subscriber starved of CPU on a loaded machine (keep-last 5 lost 1-2 % there). A
  reliable subscriber does not match a best-effort publisher, so every image publisher uses it too.
- `SENSOR_QOS` (SensorDataQoS: best effort, keep-last 5) for small, frequent sensor data (joint
  states, joy, detections) whose next sample replaces a lost one. It matches any publisher.
- `use_large_image_transport()`, called before rclpy.init, gives Fast DDS a shared-memory segment
  that holds whole frames (`fastdds_large_images.xml`). It is the sender's segment that counts: with
  it, even best-effort subscribers of this process's images receive every frame, at ~1.5 ms.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

IMAGE_DEPTH = 30
RELIABILITIES = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
SENSOR_QOS = qos_profile_sensor_data

LARGE_IMAGE_PROFILE = Path(__file__).with_name("fastdds_large_images.xml")
PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
# A user's own choice of transports wins: any of these set leaves the environment alone.
_USER_CHOICES = (PROFILE_VARIABLE, "FASTDDS_DEFAULT_PROFILES_FILE", "FASTDDS_BUILTIN_TRANSPORTS")
_FAST_DDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


def image_qos(reliability: str = "reliable", depth: int = IMAGE_DEPTH) -> QoSProfile:
    """The image profile; `"best_effort"` for a best-effort camera driver, a smaller `depth` for a
    subscriber that would rather skip frames than fall behind."""
    if reliability not in RELIABILITIES:
        raise ValueError(f"image reliability must be one of {list(RELIABILITIES)}, got {reliability!r}")
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=RELIABILITIES[reliability], durability=DurabilityPolicy.VOLATILE)


IMAGE_QOS = image_qos()


def use_large_image_transport(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Point Fast DDS at the large-image profile; return its path, or None where the environment
    already chooses transports or another RMW. Must run before the process's first node."""
    if environ.get("RMW_IMPLEMENTATION", "") not in _FAST_DDS_RMWS:
        return None
    if any(environ.get(name) for name in _USER_CHOICES):
        return None
    environ[PROFILE_VARIABLE] = str(LARGE_IMAGE_PROFILE)
    return environ[PROFILE_VARIABLE]

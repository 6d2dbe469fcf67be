"""The TF tree every header of ours is stamped in: the Panda URDF's links (robot_state_publisher
publishes them from joint_states) plus the camera, a static transform from the camera's pose given as
data (vla_bringup/config/camera_pose.yaml). No rclpy: the launch option `use_tf:=true` and tests read it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from vla_common.camera_model import CAMERA_FRAME_ID, SIM_WEBCAM, look_at_rotation

BASE_FRAME = "panda_link0"


@dataclass(frozen=True)
class StaticTransform:
    parent: str
    child: str
    xyz: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]

    def static_transform_publisher_args(self) -> list[str]:
        """Arguments of tf2_ros' static_transform_publisher (Jazzy's named form)."""
        x, y, z = (f"{v:.6f}" for v in self.xyz)
        qx, qy, qz, qw = (f"{v:.9f}" for v in self.quat_xyzw)
        return ["--x", x, "--y", y, "--z", z, "--qx", qx, "--qy", qy, "--qz", qz, "--qw", qw,
                "--frame-id", self.parent, "--child-frame-id", self.child]


def _quat_xyzw(rot: np.ndarray) -> tuple[float, float, float, float]:
    w = math.sqrt(max(0.0, 1.0 + rot[0, 0] + rot[1, 1] + rot[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + rot[0, 0] - rot[1, 1] - rot[2, 2])) / 2, rot[2, 1] - rot[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - rot[0, 0] + rot[1, 1] - rot[2, 2])) / 2, rot[0, 2] - rot[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - rot[0, 0] - rot[1, 1] + rot[2, 2])) / 2, rot[1, 0] - rot[0, 1])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return x / n, y / n, z / n, w / n


def camera_transform(path: str | Path | None = None) -> StaticTransform:
    """The camera's static transform from a camera_pose.yaml; without one, the simulated webcam."""
    data = yaml.safe_load(Path(path).read_text()) if path else {
        "parent": BASE_FRAME, "child": CAMERA_FRAME_ID,
        "position": list(SIM_WEBCAM.position), "look_at": list(SIM_WEBCAM.look_at)}
    pos = [float(v) for v in data["position"]]
    rot = look_at_rotation(pos, [float(v) for v in data["look_at"]])
    return StaticTransform(str(data["parent"]), str(data["child"]), tuple(pos), _quat_xyzw(rot))


def urdf_links(urdf_text: str) -> set[str]:
    return {e.get("name") for e in ET.fromstring(urdf_text).iter("link")}


def tree_frames(urdf_text: str, camera: StaticTransform) -> set[str]:
    """Every frame the tree defines; the camera must hang off one of the URDF's links."""
    links = urdf_links(urdf_text)
    if camera.parent not in links:
        raise ValueError(f"camera parent frame {camera.parent!r} is not a link of the URDF")
    return links | {camera.child}

"""The TF tree every header of ours is stamped in: the Panda URDF's links (robot_state_publisher
publishes them from joint_states) plus the camera, a static transform whose pose is data: the
`camera_tf` argument of vla_bringup's tf.launch.yaml (static_transform_publisher's arguments), which
`use_tf:=true` starts. No rclpy: tests read it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

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


def camera_transform(args: list[str] | None = None) -> StaticTransform:
    """The camera's static transform from static_transform_publisher's named arguments (`--x .. --qw
    --frame-id --child-frame-id`); without them, the simulated webcam. ValueError on anything else."""
    if args is None:
        rot = look_at_rotation(list(SIM_WEBCAM.position), list(SIM_WEBCAM.look_at))
        return StaticTransform(BASE_FRAME, CAMERA_FRAME_ID, tuple(float(v) for v in SIM_WEBCAM.position),
                               _quat_xyzw(rot))
    names = ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--frame-id", "--child-frame-id")
    if len(args) % 2 or any(a not in names for a in args[::2]) or set(args[::2]) != set(names):
        raise ValueError(f"expected each of {' '.join(names)} once with a value")
    got = dict(zip(args[::2], args[1::2]))
    try:
        xyz = tuple(float(got[k]) for k in names[:3])
        q = tuple(float(got[k]) for k in names[3:7])
    except ValueError as e:
        raise ValueError(f"a pose value is not a number: {e}") from e
    n = math.sqrt(sum(v * v for v in q))
    if not all(map(math.isfinite, xyz + q)) or abs(n - 1.0) > 1e-6:
        raise ValueError("the pose must be finite with a unit quaternion")
    return StaticTransform(got["--frame-id"], got["--child-frame-id"], xyz, q)


def urdf_links(urdf_text: str) -> set[str]:
    return {e.get("name") for e in ET.fromstring(urdf_text).iter("link")}


def tree_frames(urdf_text: str, camera: StaticTransform) -> set[str]:
    """Every frame the tree defines; the camera must hang off one of the URDF's links."""
    links = urdf_links(urdf_text)
    if camera.parent not in links:
        raise ValueError(f"camera parent frame {camera.parent!r} is not a link of the URDF")
    return links | {camera.child}

"""The camera model: a fixed pinhole camera given by its pose (position + look-at point, no roll) and
vertical field of view, and where a world point appears in its image. One home for the simulated
webcam's pose (the MuJoCo scene builds its camera from it), for the projection the controller's
`nearest_to_ee` and the planner demonstrations use, and for its inverse onto a plane (where the
controller's assistance finds a detected object on the table)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CAMERA_FRAME_ID = "camera_optical_frame"


def look_at_rotation(pos, target) -> np.ndarray:
    """Optical-frame rotation (columns x right, y down, z forward in the world) of a camera without roll."""
    z = np.asarray(target, float) - np.asarray(pos, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def pinhole_intrinsics(width: int, height: int, fovy_deg: float) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels: square pixels, pixel centres at integer coordinates (ROS/OpenCV)."""
    f = 0.5 * height / math.tan(0.5 * math.radians(fovy_deg))
    return f, f, 0.5 * (width - 1), 0.5 * (height - 1)


def project(point, pos, rot: np.ndarray, intrinsics) -> tuple[float, float] | None:
    """Pixel (u, v) of a world point, or None when it is behind the camera."""
    pc = (np.asarray(point, float) - np.asarray(pos, float)) @ rot
    if pc[2] <= 1e-6:
        return None
    fx, fy, cx, cy = intrinsics
    return float(fx * pc[0] / pc[2] + cx), float(fy * pc[1] / pc[2] + cy)


def unproject(pixel, pos, rot: np.ndarray, intrinsics, z: float) -> np.ndarray | None:
    """The world point at height `z` (m, world frame) that appears at pixel (u, v): the inverse of
    `project` on that plane (where a detection's box centre lies on the table, at an object's middle
    height). None when the pixel's ray does not reach the plane in front of the camera."""
    fx, fy, cx, cy = intrinsics
    u, v = float(pixel[0]), float(pixel[1])
    ray = np.asarray(rot, float) @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
    pos = np.asarray(pos, float)
    if abs(ray[2]) < 1e-9:
        return None
    s = (float(z) - pos[2]) / ray[2]
    return pos + s * ray if s > 1e-6 else None


@dataclass(frozen=True)
class PinholeCamera:
    """A calibrated camera: its optical centre and rotation in the world and its intrinsics, with
    `project` and its inverse onto a plane, `unproject`."""

    position: np.ndarray
    rotation: np.ndarray
    intrinsics: tuple[float, float, float, float]

    def project(self, point) -> tuple[float, float] | None:
        return project(point, self.position, self.rotation, self.intrinsics)

    def unproject(self, pixel, z: float) -> np.ndarray | None:
        return unproject(pixel, self.position, self.rotation, self.intrinsics, z)


@dataclass(frozen=True)
class CameraModel:
    """A fixed camera: `position` and `look_at` in the robot base frame (m), vertical field of view."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    fovy_deg: float

    def rotation(self) -> np.ndarray:
        return look_at_rotation(self.position, self.look_at)

    def intrinsics(self, width: int, height: int) -> tuple[float, float, float, float]:
        return pinhole_intrinsics(width, height, self.fovy_deg)

    def projector(self, width: int, height: int):
        """point -> (u, v) or None, for images of `width` x `height` pixels."""
        rot, k = self.rotation(), self.intrinsics(width, height)
        return lambda p: project(p, self.position, rot, k)

    def unprojector(self, width: int, height: int):
        """(pixel (u, v), z) -> the world point at height z seen there, or None (see `unproject`)."""
        return self.pinhole(width, height).unproject

    def pinhole(self, width: int, height: int) -> PinholeCamera:
        """This camera for images of `width` x `height` pixels."""
        k = self.intrinsics(width, height)
        return PinholeCamera(np.asarray(self.position, float), self.rotation(), k)


# The simulated webcam, like the paper's: in front of the table, above it, facing the robot.
SIM_WEBCAM = CameraModel(position=(1.40, -0.25, 1.15), look_at=(0.36, 0.0, 0.22), fovy_deg=58.0)

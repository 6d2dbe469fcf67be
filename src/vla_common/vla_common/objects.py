"""Objects on the table: the pose type shared by the simulator, the planner and evaluation, and the
default catalogue's classes and specs (`vla_common.catalogue` is where classes are defined, as data;
their order is the class index everywhere).

Frames: world = robot base frame, table top at z = 0, x away from the robot. Compass directions on
the table: north = +x, south = -x (towards the robot), west = +y (robot's left), east = -y.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vla_common.catalogue import COMPASS, ObjectSpec, compass_vector, default_catalogue  # noqa: F401

# The default catalogue's classes (data/catalogue.yaml); code that takes a user's catalogue reads it.
OBJECT_CLASSES: tuple[str, ...] = default_catalogue().classes
OBJECT_SPECS: dict[str, ObjectSpec] = dict(default_catalogue().objects)

def class_index(class_id: str) -> int:
    """Index of a class name in the default catalogue (CatalogueError, a ValueError, lists them)."""
    return default_catalogue().class_index(class_id)


@dataclass
class ObjectPose:
    """Pose of one object on the table. x, y: centre on the table (m); yaw about +z (rad);
    z: height of the object's centre (0.0 in requests: the simulator rests objects on the table);
    quat: full orientation (w, x, y, z) as reported by the simulator."""

    class_id: str
    x: float
    y: float
    yaw: float
    z: float = 0.0
    quat: tuple = field(default=(1.0, 0.0, 0.0, 0.0))

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])

    def to_dict(self) -> dict:
        return {"class_id": self.class_id, "x": self.x, "y": self.y, "yaw": self.yaw, "z": self.z,
                "quat": list(self.quat)}


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) quaternion of a rotation by yaw about +z."""
    return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))


def quat_yaw(quat) -> float:
    """Yaw (rotation about +z) of a (w, x, y, z) quaternion."""
    w, x, y, z = (float(v) for v in quat)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

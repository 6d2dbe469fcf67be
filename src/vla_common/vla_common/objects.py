"""The paper's tabletop objects: class names (their order is the class index everywhere), shapes and
physical properties, and the pose type shared by the simulator, the planner and evaluation.

Frames: world = robot base frame, table top at z = 0, x away from the robot. Compass directions on
the table: north = +x, south = -x (towards the robot), west = +y (robot's left), east = -y.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

OBJECT_CLASSES: tuple[str, ...] = ("bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box")

COMPASS: dict[str, tuple[float, float]] = {
    "north": (1.0, 0.0),
    "south": (-1.0, 0.0),
    "west": (0.0, 1.0),
    "east": (0.0, -1.0),
    "north_west": (math.sqrt(0.5), math.sqrt(0.5)),
    "north_east": (math.sqrt(0.5), -math.sqrt(0.5)),
    "south_west": (-math.sqrt(0.5), math.sqrt(0.5)),
    "south_east": (-math.sqrt(0.5), -math.sqrt(0.5)),
}


def compass_vector(direction: str) -> np.ndarray:
    """Unit (x, y) vector of a compass direction name ("east", "south_west", "south-west", ...)."""
    key = direction.strip().lower().replace("-", "_").replace(" ", "_")
    if key not in COMPASS:
        raise ValueError(f"unknown compass direction {direction!r}; expected one of {sorted(COMPASS)}")
    return np.array(COMPASS[key])


@dataclass(frozen=True)
class ObjectSpec:
    """Shape and physics of one object class.

    shape: "box" (size = full x, y, z extents in the object's frame) or "cylinder" (size = radius,
    radius, height). rgba is the main colour; accent_rgba colours a decorative band/label.
    """

    shape: str
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    mass: float
    friction: float
    accent_rgba: tuple[float, float, float, float] | None = None

    @property
    def height(self) -> float:
        return self.size[2]

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle enclosing the object's footprint on the table (for layouts)."""
        if self.shape == "cylinder":
            return self.size[0]
        return 0.5 * math.hypot(self.size[0], self.size[1])

    @property
    def min_half_extent(self) -> float:
        """The smallest distance from the centre to the footprint's edge, over all directions."""
        if self.shape == "cylinder":
            return self.size[0]
        return 0.5 * min(self.size[0], self.size[1])


# Sizes are close to the real items; masses are light-but-plausible (partly empty packages) so
# the Panda's closed fingers can push them; friction is the object/table sliding coefficient.
OBJECT_SPECS: dict[str, ObjectSpec] = {
    "bread": ObjectSpec("box", (0.20, 0.10, 0.08), (0.62, 0.38, 0.16, 1.0), 0.40, 0.5,
                        accent_rgba=(0.80, 0.58, 0.30, 1.0)),
    "soda_can": ObjectSpec("cylinder", (0.033, 0.033, 0.122), (0.85, 0.05, 0.05, 1.0), 0.35, 0.4,
                           accent_rgba=(0.85, 0.85, 0.88, 1.0)),
    "milk_carton": ObjectSpec("box", (0.075, 0.075, 0.20), (0.96, 0.96, 0.96, 1.0), 0.50, 0.5,
                              accent_rgba=(0.10, 0.30, 0.85, 1.0)),
    "glass_bottle": ObjectSpec("cylinder", (0.036, 0.036, 0.22), (0.10, 0.55, 0.20, 0.8), 0.45, 0.4,
                               accent_rgba=(0.10, 0.45, 0.15, 0.8)),
    "cereal_box": ObjectSpec("box", (0.19, 0.07, 0.27), (0.98, 0.70, 0.05, 1.0), 0.35, 0.5,
                             accent_rgba=(0.95, 0.35, 0.05, 1.0)),
}


def class_index(class_id: str) -> int:
    """Index of a class name in OBJECT_CLASSES (ValueError with the known names otherwise)."""
    try:
        return OBJECT_CLASSES.index(class_id)
    except ValueError:
        raise ValueError(f"unknown object class {class_id!r}; expected one of {OBJECT_CLASSES}") from None


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

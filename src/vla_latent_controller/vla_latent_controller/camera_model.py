"""A fixed pinhole camera given by its pose (position + look-at point, no roll) and intrinsics: where
the end effector or an object appears in the detector's image (nearest_to_ee, planner demos)."""

from __future__ import annotations

import numpy as np


def look_at_rotation(pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Optical-frame rotation (columns x right, y down, z forward in the world) of a camera without roll."""
    z = np.asarray(target, float) - np.asarray(pos, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def project(point, pos, rot: np.ndarray, intrinsics) -> tuple[float, float] | None:
    """Pixel (u, v) of a world point, or None when it is behind the camera."""
    pc = (np.asarray(point, float) - np.asarray(pos, float)) @ rot
    if pc[2] <= 1e-6:
        return None
    fx, fy, cx, cy = intrinsics
    return float(fx * pc[0] / pc[2] + cx), float(fy * pc[1] / pc[2] + cy)

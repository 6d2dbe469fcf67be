"""What the bridge needs from a robot: read the joint state, write a (safety-filtered) velocity.

Two implementations: `backend_mujoco.MujocoBackend` (the simulated Panda, stepped by the bridge) and
`backend_ros2_control.Ros2ControlBackend` (a real or simulated ros2_control system that moves on its
own). The bridge node runs the same SafetyFilter in front of either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class JointSample:
    """One joint state in panda_joint1..7 order. `reference` is the servo position target where the
    backend knows it (the integral of the commands); the safety layer keeps that inside the margins."""

    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    stamp: float  # seconds on the backend's clock
    reference: np.ndarray | None = None


class Backend(Protocol):
    kind: str

    def read(self) -> JointSample | None:
        """Latest joint state, or None if none is known yet."""

    def write(self, dq: np.ndarray) -> None:
        """Send a safety-filtered joint-velocity command (7,)."""

    def close(self) -> None:
        """Stop: command zero and release resources."""

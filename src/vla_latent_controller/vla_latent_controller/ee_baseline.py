"""The paper's end-effector baseline: one stick axis drives one Cartesian direction at a time.

A button cycles x, y, z, roll, pitch, yaw (debounced); the axis value times a speed gives the twist
along that direction (world-aligned, at the tool centre point), mapped to joint velocities with a damped
pseudo-inverse of the Jacobian (well-behaved near singularities, unlike the paper's plain pinv).
"""

from __future__ import annotations

import numpy as np

EE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def damped_pinv(J: np.ndarray, damping: float) -> np.ndarray:
    """Jᵀ (J Jᵀ + λ² I)⁻¹: the damped least-squares pseudo-inverse."""
    m = J.shape[0]
    return J.T @ np.linalg.solve(J @ J.T + (damping**2) * np.eye(m), np.eye(m))


class EndEffectorBaseline:
    """Cartesian jogging along the selected axis; ``kinematics`` has ``jacobian(q) -> (6, 7)``
    (LOCAL_WORLD_ALIGNED, linear rows first), as vla_common.kinematics.PandaKinematics."""

    def __init__(
        self,
        kinematics,
        linear_speed: float = 0.2,
        angular_speed: float = 0.5,
        damping: float = 0.05,
        debounce: float = 0.25,
    ):
        self.kinematics = kinematics
        self.linear_speed, self.angular_speed = linear_speed, angular_speed
        self.damping, self.debounce = damping, debounce
        self.index = 0
        self._last_switch = -np.inf

    @property
    def axis(self) -> str:
        return EE_AXES[self.index]

    def select(self, axis: str) -> None:
        self.index = EE_AXES.index(axis)

    def press(self, now: float) -> bool:
        """Cycle to the next axis unless the previous switch was less than ``debounce`` s ago."""
        if now - self._last_switch < self.debounce:
            return False
        self._last_switch = now
        self.index = (self.index + 1) % len(EE_AXES)
        return True

    def twist(self, u: float) -> np.ndarray:
        xd = np.zeros(6)
        xd[self.index] = u * (self.linear_speed if self.index < 3 else self.angular_speed)
        return xd

    def command(self, q: np.ndarray, u: float) -> np.ndarray:
        """Joint velocities moving the TCP along the selected axis at ``u`` ∈ [-1, 1] of full speed."""
        J = np.asarray(self.kinematics.jacobian(np.asarray(q, float)), float)
        if J.shape != (6, len(q)):
            raise ValueError(f"jacobian has shape {J.shape}, expected (6, {len(q)})")
        return damped_pinv(J, self.damping) @ self.twist(u)

"""The paper's end-effector baseline: one stick axis drives one Cartesian direction at a time.

A button cycles x, y, z, roll, pitch, yaw (debounced), or the subset a lab gives (`axes`: a task done
with the hand pointing down needs only x, y, z, and each mode a person does not need costs presses);
the axis value times a speed gives the twist
along that direction (world-aligned, at the tool centre point), mapped to joint velocities with a damped
pseudo-inverse of the Jacobian (well-behaved near singularities, unlike the paper's plain pinv).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import numpy as np

EE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def check_axes(axes: Sequence[str]) -> tuple[str, ...]:
    """The axes the mode button cycles, in order; ValueError unless distinct names from EE_AXES."""
    axes = tuple(str(a) for a in axes)
    bad = [a for a in axes if a not in EE_AXES]
    if not axes or bad or len(set(axes)) != len(axes):
        raise ValueError(f"needs distinct axes from {list(EE_AXES)}, got {list(axes)}")
    return axes


def parse_axes(value: str | Sequence[str]) -> tuple[str, ...]:
    """The axes from their text, names apart by commas and/or spaces ("x,y,z"), or from a list."""
    items = re.split(r"[\s,]+", value.strip()) if isinstance(value, str) else list(value)
    return check_axes([a for a in items if a != ""])


def axes_text(axes: Sequence[str]) -> str:
    """The axes as one string, "x,y,z": the parameter's form. A list would not do: `ros2 param dump`
    writes it unquoted, `[x, y, z]`, and rcl reads a bare y as the boolean true."""
    return ",".join(str(a) for a in axes)


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
        axes: Sequence[str] = EE_AXES,
    ):
        self.kinematics = kinematics
        self.linear_speed, self.angular_speed = linear_speed, angular_speed
        self.damping, self.debounce = damping, debounce
        self.axes = check_axes(axes)
        self.index = 0
        self._last_switch = -np.inf

    @property
    def axis(self) -> str:
        return self.axes[self.index]

    def select(self, axis: str) -> None:
        self.index = self.axes.index(axis)

    def restart(self) -> None:
        """The first axis, no switch pending: what a newly chosen mode starts with (a trial's start)."""
        self.index, self._last_switch = 0, -np.inf

    def restamp(self, f: Callable[[float], float]) -> None:
        """The core's clock moved its origin (`TeleopCore.restamp`)."""
        self._last_switch = f(self._last_switch)

    def set_axes(self, axes: Sequence[str]) -> None:
        """Cycle these axes from now on; the selected one stays if it is among them, else the first."""
        axis, self.axes = self.axis, check_axes(axes)
        self.index = self.axes.index(axis) if axis in self.axes else 0

    def press(self, now: float) -> bool:
        """Cycle to the next axis unless the previous switch was less than ``debounce`` s ago."""
        if now - self._last_switch < self.debounce:
            return False
        self._last_switch = now
        self.index = (self.index + 1) % len(self.axes)
        return True

    def twist(self, u: float) -> np.ndarray:
        xd = np.zeros(6)
        k = EE_AXES.index(self.axis)
        xd[k] = u * (self.linear_speed if k < 3 else self.angular_speed)
        return xd

    def command(self, q: np.ndarray, u: float) -> np.ndarray:
        """Joint velocities moving the TCP along the selected axis at ``u`` ∈ [-1, 1] of full speed."""
        J = np.asarray(self.kinematics.jacobian(np.asarray(q, float)), float)
        if J.shape != (6, len(q)):
            raise ValueError(f"jacobian has shape {J.shape}, expected (6, {len(q)})")
        return damped_pinv(J, self.damping) @ self.twist(u)

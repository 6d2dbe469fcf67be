"""The workspace floor: the tool centre point never driven into the table (plain NumPy, no ROS).

The paper's code had no workspace limit, and a decoder asked for motion beyond its demonstrations can
aim the hand at the table: the demo's cereal box push dived 8 cm in a fraction of a second and ended
in a reflex. A careful operator slows down near the table; this does it for them.

The rule is a control barrier on the TCP height z above `floor` (the lowest the TCP may go, in the
robot's base frame): the commanded descent speed may not exceed `gain` x (z - floor), so the hand
approaches the floor exponentially and never reaches it. A command that breaks the rule is changed as
little as possible (the closed form of min |dq - cmd|^2 subject to J_z dq >= -gain (z - floor)):
only its component along J_z, so sideways and upward motion keep going at full speed and the operator
can always lift the hand. The safety filter (`safety.py`) applies it to its target; this module only
computes. Kinematics are injected (`height`), so the rule is tested without a robot model.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

FLOOR_GAIN = 4.0      # 1/s: allowed descent speed per metre above the floor (time constant 0.25 s)
DEFAULT_FLOOR = 0.015  # m: the TCP's lowest height above the table the robot stands on (z = 0); the
# simulated fingertips touch the table with the TCP at 0.011 m, and pushes run at 0.02-0.03 m


class WorkspaceFloor:
    """`limit(cmd, q)`: the command with its descent towards the floor bounded (None: unchanged)."""

    def __init__(self, height: Callable[[np.ndarray], tuple[float, np.ndarray]], floor: float,
                 gain: float = FLOOR_GAIN):
        """`height(q)` -> (TCP z in m, dz/dq (7,)); `floor` in m, in the same frame."""
        if not (np.isfinite(floor) and np.isfinite(gain) and gain > 0.0):
            raise ValueError(f"workspace floor: floor={floor!r} and gain={gain!r} must be finite, gain > 0")
        self._height = height
        self.floor = float(floor)
        self.gain = float(gain)

    def allowed_descent(self, z: float) -> float:
        """Largest descent speed (m/s, >= 0) at TCP height z: none at or below the floor."""
        return self.gain * max(z - self.floor, 0.0)

    def limit(self, cmd: Sequence[float], q, free: Sequence[bool] | None = None) -> list[float] | None:
        """The least change to `cmd` (rad/s) whose TCP descent is within `allowed_descent`, or None
        when `cmd` already is (or the kinematics cannot be evaluated at `q`: nothing is invented).

        `free`: the joints the change may use (default all). The safety filter leaves out the joints
        near a position limit, whose speed it caps afterwards: a change that leaned on them would be
        undone there and the hand would go on down. With no free joint that moves the hand up or down,
        the whole command is scaled down instead (direction kept)."""
        try:
            z, jz = self._height(np.asarray(q, dtype=float))
            jz = [float(x) for x in np.asarray(jz, dtype=float).reshape(-1)]
            z = float(z)
            v = [float(x) for x in cmd]
        except (TypeError, ValueError):
            return None
        # Python floats on 7 values: this runs every period of the 1 kHz loop, where NumPy's
        # per-call overhead was half its cost.
        if len(jz) != len(v) or not (math.isfinite(z) and all(map(math.isfinite, jz))):
            return None
        vz = sum(a * b for a, b in zip(jz, v))
        bound = -self.allowed_descent(z)
        if vz >= bound:                    # within the rule (rising, level, or slow enough)
            return None
        use = jz if free is None else [a if f else 0.0 for a, f in zip(jz, free)]
        reach = sum(a * b for a, b in zip(jz, use))
        if reach < 1e-9:                   # no free joint moves the hand vertically: slow it all
            return [x * (bound / vz) for x in v]
        k = (bound - vz) / reach
        return [x + u * k for x, u in zip(v, use)]


def tcp_height(kinematics) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """`height` for `WorkspaceFloor` from a `vla_common.kinematics.PandaKinematics`: the TCP's z and
    the z row of its world-aligned Jacobian (one Pinocchio pass, ~15 us)."""
    def height(q: np.ndarray) -> tuple[float, np.ndarray]:
        jac = kinematics.jacobian(q)                      # also places every frame at q
        z = float(kinematics.data.oMf[kinematics.tcp_id].translation[2])
        return z, jac[2]
    return height

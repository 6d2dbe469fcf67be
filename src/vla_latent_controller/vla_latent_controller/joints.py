"""Which robot joint each of the controller's joints is, by name (no rclpy).

The controller computes in its own joint order (the model's `joint_names`, or the kinematics' joints in
end-effector mode). The robot's order is the order of the names in its `joint_states`: the command goes
out in that order, so a model that lists its joints in another order still drives the right ones. A
joint map renames the controller's joints to the robot's (a Panda model on an FR3: `fr3_joint1` is
`panda_joint1`, ...); without one a joint must have the same name on both sides.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


def parse_joint_map(entries: Sequence[str]) -> dict[str, str]:
    """`["robot_joint:model_joint", ...]` → {model_joint: robot_joint}; ValueError names a bad entry."""
    out: dict[str, str] = {}
    robots: set[str] = set()
    for entry in entries:
        robot, sep, model = (s.strip() for s in str(entry).partition(":"))
        if not sep or not robot or not model or ":" in model:
            raise ValueError(f"joint_map entry {entry!r} is not 'robot_joint:model_joint'")
        if model in out or robot in robots:
            raise ValueError(f"joint_map names {model if model in out else robot!r} twice")
        out[model] = robot
        robots.add(robot)
    return out


@dataclass(frozen=True)
class JointBinding:
    """How one `joint_states` name list lines up with the controller's joints."""

    q_index: np.ndarray  # positions[q_index]: the state in the controller's joint order
    order: np.ndarray  # command[order]: controller order -> the robot's order (as in joint_states)
    robot_names: tuple[str, ...]  # the command's joints, in the robot's order


class JointResolver:
    """Binds the controller's joints to the names of a `joint_states` message (cached per name list)."""

    def __init__(self, joints: Sequence[str], joint_map: Mapping[str, str] | None = None):
        self.joints = tuple(joints)
        self.robot_joints = tuple((joint_map or {}).get(j, j) for j in self.joints)
        self._names: tuple[str, ...] | None = None
        self._bound: JointBinding | str = ""

    def bind(self, names: tuple[str, ...]) -> JointBinding | str:
        """The binding for this name list, or the reason there is none (joints the robot lacks)."""
        if names != self._names:
            self._names, self._bound = names, self._bind(names)
        return self._bound

    def _bind(self, names: tuple[str, ...]) -> JointBinding | str:
        index = {n: i for i, n in enumerate(names)}
        missing = [r for r in self.robot_joints if r not in index]
        if missing:
            return self.mismatch(names, missing)
        q_index = np.array([index[r] for r in self.robot_joints], dtype=np.intp)
        order = np.argsort(q_index, kind="stable")
        return JointBinding(q_index, order, tuple(self.robot_joints[i] for i in order))

    def mismatch(self, names: Sequence[str], missing: Sequence[str] | None = None) -> str:
        """Why these joint_states cannot drive the controller's joints."""
        missing = list(missing if missing is not None else self.robot_joints)
        renamed = self.robot_joints != self.joints
        hint = "check joint_map" if renamed else "a model for another robot? map the joints with joint_map"
        return (
            f"the robot's joint_states lack {', '.join(missing)} (it has {', '.join(names) or 'no joints'}; "
            f"the controller needs {', '.join(self.robot_joints)}): {hint}"
        )

    def overlaps(self, names: Sequence[str]) -> bool:
        return any(n in self.robot_joints for n in names)

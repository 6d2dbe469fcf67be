"""The Franka arms the project drives: one `RobotSpec` per model, with its joint names and limits.

- `PANDA` (Franka Emika FER): the official limits (Franka control parameters, identical to libfranka
  0.9.2 rate_limiting.h).
- `FR3` (Franka Research 3): q_min, q_max and dq_max from the Franka documentation; acceleration and
  jerk limits as libfranka enforces them (10 rad/s^2, 5000 rad/s^3, less its 0.001 margin; checked
  against franka-sim with the limits enforced); torque limits the Panda's table. FR3 velocity limits
  also depend on the position (libfranka >= 0.15); these are the constant maxima.

Both carry the Franka Hand (`HandSpec`): its finger joints (`<model>_finger_joint1/2`, each half the
gap between the fingers) and its range, which the gripper layer enforces.

The module-level names (`JOINT_NAMES`, `Q_MIN`, `DQ_MAX`, ...) are the Panda's: the simulator, the
planners and the controllers import them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NUM_JOINTS = 7


def _frozen(values) -> np.ndarray:
    a = np.array(values, dtype=float)
    if a.shape != (NUM_JOINTS,):
        raise ValueError(f"expected {NUM_JOINTS} values, got {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class HandSpec:
    """The Franka Hand (datasheet): stroke 0..80 mm between the fingers, 70 N continuous grasping
    force (140 N peak, not offered), 50 mm/s per finger (0.1 m/s of width)."""

    finger_joints: tuple[str, str]
    max_width: float = 0.08        # m between the fingers
    max_force: float = 70.0        # N, continuous grasping force
    max_speed: float = 0.1         # m/s of width


@dataclass(frozen=True, eq=False)
class RobotSpec:
    """One arm model: joint names and the limit table the safety layer enforces."""

    name: str
    joint_names: tuple[str, ...]
    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    dddq_max: np.ndarray
    tau_max: np.ndarray
    ready_pose: np.ndarray
    base_frame: str           # the robot's base link (frame of Cartesian poses)
    hand: HandSpec            # the Franka Hand on its flange

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)


_PANDA_DDQ = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
_PANDA_DDDQ = (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)
_PANDA_TAU = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
_READY = (0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4)

PANDA = RobotSpec(
    name="panda",
    joint_names=tuple(f"panda_joint{i}" for i in range(1, NUM_JOINTS + 1)),
    q_min=_frozen([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
    q_max=_frozen([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
    dq_max=_frozen([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]),
    ddq_max=_frozen(_PANDA_DDQ),
    dddq_max=_frozen(_PANDA_DDDQ),
    tau_max=_frozen(_PANDA_TAU),
    ready_pose=_frozen(_READY),
    base_frame="panda_link0",
    hand=HandSpec(("panda_finger_joint1", "panda_finger_joint2")),
)

FR3 = RobotSpec(
    name="fr3",
    joint_names=tuple(f"fr3_joint{i}" for i in range(1, NUM_JOINTS + 1)),
    q_min=_frozen([-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159]),
    q_max=_frozen([2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159]),
    dq_max=_frozen([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26]),
    # libfranka's FR3 limits (10 rad/s^2, 5000 rad/s^3 on every joint) less its 0.001 safety margin:
    # franka-sim, enforcing the limits as the FCI does, aborted a command at exactly 10.0 rad/s^2.
    ddq_max=_frozen([9.999] * 7),
    dddq_max=_frozen([4999.999] * 7),
    tau_max=_frozen(_PANDA_TAU),
    ready_pose=_frozen(_READY),
    base_frame="fr3_link0",
    hand=HandSpec(("fr3_finger_joint1", "fr3_finger_joint2")),
)

ROBOTS: dict[str, RobotSpec] = {r.name: r for r in (PANDA, FR3)}


def robot_spec(name: str) -> RobotSpec:
    """The spec of a model by name; ValueError lists the known ones."""
    try:
        return ROBOTS[name]
    except KeyError:
        raise ValueError(f"unknown robot model {name!r}; one of {sorted(ROBOTS)}") from None


# The Panda's names, for the packages that drive only the Panda (simulator, planners, controllers).
JOINT_NAMES: tuple[str, ...] = PANDA.joint_names
Q_MIN = PANDA.q_min
Q_MAX = PANDA.q_max
DQ_MAX = PANDA.dq_max
DDQ_MAX = PANDA.ddq_max
DDDQ_MAX = PANDA.dddq_max
TAU_MAX = PANDA.tau_max
READY_POSE = PANDA.ready_pose
HAND = PANDA.hand

"""The Franka Emika Panda (FER): joint names and the official limits (Franka control parameters,
identical to libfranka 0.9.2 rate_limiting.h). One place, used by the safety layer, the simulator,
the planners and the controllers."""
import numpy as np

NUM_JOINTS = 7
JOINT_NAMES: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, NUM_JOINTS + 1))

Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
DQ_MAX = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
DDQ_MAX = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
DDDQ_MAX = np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0])
TAU_MAX = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])

READY_POSE = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])

for _a in (Q_MIN, Q_MAX, DQ_MAX, DDQ_MAX, DDDQ_MAX, TAU_MAX, READY_POSE):
    _a.setflags(write=False)

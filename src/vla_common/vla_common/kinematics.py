"""Panda kinematics with Pinocchio on example-robot-data's URDF — the same file MuJoCo imports, so
the simulator, the planner and the controllers share one kinematic truth.

The fingers are locked (their gap does not move the hand), leaving the 7 arm joints. The tool
centre point (TCP) is the URDF's `panda_hand_tcp` frame, between the finger tips.
"""
from __future__ import annotations

import functools
import os

import numpy as np
import pinocchio as pin

from vla_common.robot import HAND, Q_MAX, Q_MIN, READY_POSE

TCP_FRAME = "panda_hand_tcp"
FLANGE_FRAME = "panda_link8"
FINGER_JOINTS = HAND.finger_joints


def panda_description_dir() -> str:
    """Folder of example-robot-data's panda_description (urdf/, meshes/)."""
    import example_robot_data

    robots = os.path.normpath(example_robot_data.getModelPath("panda_description/urdf/panda.urdf"))
    path = os.path.join(robots, "panda_description")
    if not os.path.isdir(path):
        raise FileNotFoundError(f"example-robot-data's panda_description not found at {path}")
    return path


def panda_urdf_path() -> str:
    """Absolute path of example-robot-data's Panda URDF."""
    path = os.path.join(panda_description_dir(), "urdf", "panda.urdf")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"Panda URDF not found at {path}")
    return path


ARM_LINKS = ("panda_link3", "panda_link4", "panda_link5", "panda_link6", "panda_link7")


@functools.cache
def _mesh_vertices(mesh: str) -> np.ndarray:
    """Unique vertices of a binary STL collision mesh of example-robot-data's Panda (link frame)."""
    path = os.path.join(panda_description_dir(), "meshes", "collision", f"{mesh}.stl")
    with open(path, "rb") as f:
        data = f.read()
    count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
    tri = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    if len(data) != 84 + count * tri.itemsize:
        raise ValueError(f"{path} is not a binary STL file")
    verts = np.frombuffer(data, dtype=tri, count=count, offset=84)["v"].reshape(-1, 3)
    return np.unique(verts.astype(float).round(6), axis=0)


@functools.cache
def _sampled_vertices(mesh: str, n: int) -> np.ndarray:
    """`n` vertices of a link's collision mesh spread over it (farthest-point sampling from the one
    farthest from its centre; deterministic): a cheap stand-in for the link's surface."""
    verts = _mesh_vertices(mesh)
    chosen = [int(np.argmax(np.linalg.norm(verts - verts.mean(0), axis=1)))]
    dist = np.linalg.norm(verts - verts[chosen[0]], axis=1)
    while len(chosen) < min(n, len(verts)):
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(verts - verts[chosen[-1]], axis=1))
    return verts[chosen].copy()


class PandaKinematics:
    """Forward kinematics, TCP Jacobian and damped-least-squares IK for the 7-joint Panda."""

    def __init__(self, urdf_path: str | None = None):
        full = pin.buildModelFromUrdf(urdf_path or panda_urdf_path())
        locked = [full.getJointId(name) for name in FINGER_JOINTS if full.existJointName(name)]
        self.model = pin.buildReducedModel(full, locked, pin.neutral(full)) if locked else full
        if self.model.nq != 7:
            raise ValueError(f"expected a 7-joint arm after locking the fingers, got nq={self.model.nq}")
        self.data = self.model.createData()
        self.tcp_id = self.model.getFrameId(TCP_FRAME)
        self.flange_id = self.model.getFrameId(FLANGE_FRAME)
        self.q_min = np.asarray(Q_MIN, dtype=float)
        self.q_max = np.asarray(Q_MAX, dtype=float)
        self._arm_samples: dict = {}

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be 7 finite joint positions, got {q!r}")
        return q

    def _frame(self, q, frame_id: int) -> tuple[np.ndarray, np.ndarray]:
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        placement = pin.updateFramePlacement(self.model, self.data, frame_id)
        return placement.translation.copy(), placement.rotation.copy()

    def fk(self, q) -> tuple[np.ndarray, np.ndarray]:
        """TCP position (3,) and rotation matrix (3, 3) in the robot base (world) frame."""
        return self._frame(q, self.tcp_id)

    def flange_fk(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Flange (panda_link8) position and rotation in the base frame."""
        return self._frame(q, self.flange_id)

    def frame_position(self, q, frame: str) -> np.ndarray:
        """Position of any URDF frame (e.g. "panda_link6", the wrist) in the base frame."""
        if not self.model.existFrame(frame):
            raise ValueError(f"unknown frame {frame!r}")
        return self._frame(q, self.model.getFrameId(frame))[0]

    def link_points(self, q, links: tuple[str, ...] = ARM_LINKS) -> np.ndarray:
        """(N, 3) world positions of the collision-mesh vertices of `links` (the STL files MuJoCo
        also uses), for clearance checks in planning."""
        qv = self._check_q(q)
        pin.forwardKinematics(self.model, self.data, qv)
        out = []
        for name in links:
            verts = _mesh_vertices(name.removeprefix("panda_"))
            placement = pin.updateFramePlacement(self.model, self.data, self.model.getFrameId(name))
            out.append(verts @ placement.rotation.T + placement.translation)
        return np.vstack(out)

    def jacobian(self, q) -> np.ndarray:
        """(6, 7) TCP Jacobian, LOCAL_WORLD_ALIGNED: rows 0-2 linear, 3-5 angular velocity (world axes)."""
        return pin.computeFrameJacobian(self.model, self.data, self._check_q(q), self.tcp_id,
                                        pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).copy()

    def tcp_state(self, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TCP position (3,), rotation (3, 3) and its (6, 7) Jacobian (as `jacobian`) in one pass: what
        a control step needs, at a tenth of `fk` and `jacobian` called apart (one kinematics sweep)."""
        pin.computeJointJacobians(self.model, self.data, self._check_q(q))
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, self.tcp_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        placement = self.data.oMf[self.tcp_id]
        return placement.translation.copy(), placement.rotation.copy(), J.copy()

    def arm_points(self, q, links: tuple[str, ...] = ARM_LINKS, per_link: int = 16):
        """(N, 3) world positions of `per_link` points on each of `links`' collision meshes, and a
        function giving the (k, 3, 7) linear Jacobians of the points at given indices: what keeps the
        arm's links off an object (the hand and fingers, meant to touch it, are not among them).
        Jacobians cost a frame Jacobian each, so they are computed only for the points asked."""
        key = (tuple(links), per_link)
        if key not in self._arm_samples:
            ids = [self.model.getFrameId(n) for n in links]
            verts = [_sampled_vertices(n.removeprefix("panda_"), per_link) for n in links]
            owner = np.repeat(np.arange(len(ids)), [len(v) for v in verts])
            self._arm_samples[key] = (ids, [v.T.copy() for v in verts], owner)
        ids, verts, owner = self._arm_samples[key]
        pin.forwardKinematics(self.model, self.data, self._check_q(q))
        frames = [pin.updateFramePlacement(self.model, self.data, f) for f in ids]
        origins = [m.translation for m in frames]
        points = np.vstack([(m.rotation @ v).T + o for v, m, o in zip(verts, frames, origins)])

        def jacobians(index) -> np.ndarray:
            index = np.asarray(index, int).reshape(-1)
            pin.computeJointJacobians(self.model, self.data, self._check_q(q))
            out = np.empty((len(index), 3, 7))
            for link in np.unique(owner[index]):
                J = pin.getFrameJacobian(self.model, self.data, ids[link],
                                         pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
                mine = np.flatnonzero(owner[index] == link)
                r = points[index[mine]] - origins[link]     # v = v_origin + w x r = v_origin - [r]x w
                skew = np.zeros((len(r), 3, 3))
                skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
                skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
                out[mine] = J[:3][None] - skew @ J[3:]
            return out

        return points, jacobians

    def ik(self, pos, rot=None, q0=None, *, max_iter: int = 300, tol_pos: float = 1e-4,
           tol_rot: float = 1e-3, damping: float = 1e-4, null_gain: float = 0.05,
           locked: tuple[int, ...] = ()) -> tuple[np.ndarray, bool]:
        """Joint positions putting the TCP at `pos` (and orientation `rot` unless None).

        Damped least squares from q0 (default: the ready pose), clamped to the joint limits, with a
        weak null-space pull towards q0 so solutions stay close to the start. Joints listed in
        `locked` (indices 0..6) keep their q0 value. Returns (q, success).
        """
        target_p = np.asarray(pos, dtype=float).reshape(3)
        target_r = None if rot is None else np.asarray(rot, dtype=float).reshape(3, 3)
        q_ref = self._check_q(READY_POSE if q0 is None else q0)
        q = np.clip(q_ref, self.q_min, self.q_max)
        rows = slice(0, 3) if target_r is None else slice(0, 6)
        for _ in range(max_iter):
            p, r = self.fk(q)
            err = np.zeros(6)
            err[:3] = target_p - p
            if target_r is not None:
                err[3:] = pin.log3(target_r @ r.T)
            e = err[rows]
            if np.linalg.norm(err[:3]) < tol_pos and np.linalg.norm(err[3:]) < tol_rot:
                return q, True
            J = self.jacobian(q)[rows]
            if locked:
                J[:, list(locked)] = 0.0
            # Damping fades as the error shrinks so the last steps are exact Gauss-Newton steps.
            lam = damping * min(1.0, float(e @ e) / 1e-4) + 1e-9
            JJt = J @ J.T + lam * np.eye(J.shape[0])
            J_pinv = J.T @ np.linalg.solve(JJt, np.eye(J.shape[0]))
            dq = J_pinv @ e + null_gain * (np.eye(7) - J_pinv @ J) @ (q_ref - q)
            if locked:
                dq[list(locked)] = 0.0
            step = np.linalg.norm(dq)
            if step > 0.3:
                dq *= 0.3 / step
            q = np.clip(q + dq, self.q_min, self.q_max)
        p, r = self.fk(q)
        ok = np.linalg.norm(target_p - p) < tol_pos and (
            target_r is None or np.linalg.norm(pin.log3(target_r @ r.T)) < tol_rot)
        return q, bool(ok)

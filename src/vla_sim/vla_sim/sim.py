"""PandaSim: the simulated Panda, table, objects and webcam in MuJoCo, behind a small API that the
bridge node, the demonstration generator and the detector's synthetic data all use.

Velocity commands behave like a real joint-velocity interface: they are integrated into position
targets of stiff joint servos, gravity is compensated, and the arm holds its pose under a zero
command. The servo (`_servo`, every physics step) is a computed-torque position loop: the joint
acceleration it asks for is the command's own acceleration plus a critically damped correction of
the tracking error, limited so that the arm's own drive never takes it past the Panda's velocity and
acceleration table (scaled down as a whole where the torque limits cannot give it), and the torque is
M(q) times it plus the Coriolis and gravity terms. So in free motion the arm follows a command that
respects the table to ~1e-12 rad/s, and whatever the command, its measured velocity and
acceleration stay inside the table; `reflex()` reports where contact forced it past its limits, as
a real Panda's reflexes do. Teaching mode switches the servo off (gravity compensation stays).
The hand (`hand`, vla_sim.hand.SimHand) is a force-limited servo on the gap between the fingers,
stepped with the arm; `held_objects()` names what both fingers touch. Rendering is optional
(render=False never creates a GL context), headless with MUJOCO_GL=egl, without shadows.
"""
from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence

import mujoco
import numpy as np
from vla_common.camera_model import CAMERA_FRAME_ID, pinhole_intrinsics
from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.layout import (  # noqa: F401  (re-exported for callers of the simulator)
    LAYOUT_X,
    LAYOUT_Y,
    random_layout,
    validate_layout,
)
from vla_common.objects import ObjectPose, quat_yaw, yaw_quat
from vla_common.robot import DDQ_MAX, DQ_MAX, HAND, JOINT_NAMES, NUM_JOINTS, Q_MAX, Q_MIN, READY_POSE, TAU_MAX

from vla_sim.arm_checks import CollisionChecker, ReflexMonitor
from vla_sim.hand import SimHand
from vla_sim.scene import (
    CAMERA_NAME,
    MAX_OFFSCREEN,
    MOTOR_PREFIX,
    OBJECT_BODY_PREFIX,
    TCP_SITE,
    build_model,
    park_position,
)

ROBOT_PREFIX = "panda_"
ENVIRONMENT_GEOMS = ("table_top", "floor")
SERVO_BANDWIDTH = 50.0   # rad/s: natural frequency of the (critically damped) tracking-error loop
# rad: how far the servo's position target may lead the joint. A hand held up by an object while
# commands go on would otherwise store the whole commanded travel (0.13 rad measured, on the demo's
# cereal-box push) and release it as a lunge when the hand slips off: 1 m/s into the table and a
# reflex; at 0.05 a hand slipping off a loaf still dropped 3 cm into a reflex (3 of 25 held-stick
# holds). Free motion away from the position limits leads by ~1e-13 rad (random 1.5 rad/s steps).
MAX_FOLLOWING_ERROR = 0.01


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """A contiguous index array as a slice (views instead of copies on the 1 kHz path)."""
    if np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class PandaSim:
    """MuJoCo Panda + table + objects + fixed camera.

    Contract: reset(seed, objects, q0) -> layout; set_velocity_command(dq) (already safety-filtered);
    step(n); time, q, dq, effort, physics_dt; object_poses(); render(); set_camera_size(w, h);
    camera_intrinsics(); camera_frame_id; project(points).
    """

    camera_frame_id = CAMERA_FRAME_ID

    def __init__(self, camera_width: int = 640, camera_height: int = 480, render: bool = True,
                 physics_dt: float = 0.002, catalogue: Catalogue | None = None):
        self._check_size(camera_width, camera_height)
        self.catalogue = catalogue or default_catalogue()
        self.model = build_model(physics_dt, self.catalogue)
        self.data = mujoco.MjData(self.model)
        self._render_enabled = bool(render)
        self._renderer: mujoco.Renderer | None = None
        self._width, self._height = int(camera_width), int(camera_height)
        m = self.model
        self._qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in JOINT_NAMES])
        self._dadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in JOINT_NAMES])
        self._motor = _as_slice(np.array([m.actuator(MOTOR_PREFIX + n).id for n in JOINT_NAMES]))
        self._qpos = _as_slice(self._qadr)
        self._dofs = _as_slice(self._dadr)
        self._acc = np.zeros(m.nv)                 # servo buffers (no allocation per step)
        self._mv = np.zeros(m.nv)
        self._limits = [tuple(float(x[i]) for x in (Q_MIN, Q_MAX, DQ_MAX, DDQ_MAX, TAU_MAX))
                        for i in range(NUM_JOINTS)]
        self._zero = [0.0] * NUM_JOINTS
        self._cmd = self._cmd_prev = self._zero    # the command being executed and the previous one
        self._q_t = list(READY_POSE)               # servo position targets (integral of the commands)
        self._servo_on = True
        self.torque_limited_steps = 0              # steps whose acceleration the torque limits scaled
        self._reflex = ReflexMonitor(JOINT_NAMES, Q_MIN, Q_MAX, DQ_MAX, TAU_MAX)
        self._violation: str | None = None
        self._collisions: CollisionChecker | None = None
        self._cam_id = m.camera(CAMERA_NAME).id
        self._tcp_site = m.site(TCP_SITE).id
        self._obj_body = {c: m.body(OBJECT_BODY_PREFIX + c).id for c in self.catalogue.classes}
        self._obj_qadr = {c: m.jnt_qposadr[m.body_jntadr[b]] for c, b in self._obj_body.items()}
        self._obj_dadr = {c: m.jnt_dofadr[m.body_jntadr[b]] for c, b in self._obj_body.items()}
        self._obj_geoms = {c: [g for g in range(m.ngeom) if m.geom_bodyid[g] == b]
                           for c, b in self._obj_body.items()}
        self._geom_contype = m.geom_contype.copy()
        self._geom_conaffinity = m.geom_conaffinity.copy()
        self._active: list[str] = []
        self.hand = SimHand(m, self.data)         # the fingers' servo, stepped with the arm's
        self.reset(seed=0)

    # ------------------------------------------------------------------ state
    @property
    def physics_dt(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        return self.data.qpos[self._qadr].copy()

    @property
    def dq(self) -> np.ndarray:
        return self.data.qvel[self._dadr].copy()

    @property
    def external_torque(self) -> np.ndarray:
        """The torque contacts and limits exert on each arm joint (Nm): what a real arm's tau_ext
        estimate measures, and what the torque reflex judges."""
        return self.data.qfrc_constraint[self._dofs].copy()

    @property
    def effort(self) -> np.ndarray:
        """Joint torques of the servos (including gravity compensation), like a measured tau_J."""
        return self.data.qfrc_actuator[self._dadr].copy()

    @property
    def q_target(self) -> np.ndarray:
        """Position targets of the joint servos (integral of the velocity commands)."""
        return np.array(self._q_t)

    @property
    def command(self) -> np.ndarray:
        """The velocity command being executed (clipped to DQ_MAX)."""
        return np.array(self._cmd)

    @property
    def active_objects(self) -> list[str]:
        return list(self._active)

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Simulated TCP position and rotation (equals PandaKinematics.fk(q))."""
        mujoco.mj_kinematics(self.model, self.data)  # mj_step leaves poses of the pre-step state
        return (self.data.site_xpos[self._tcp_site].copy(),
                self.data.site_xmat[self._tcp_site].reshape(3, 3).copy())

    # ------------------------------------------------------------------ control
    def set_velocity_command(self, dq) -> None:
        """Joint-velocity command (7,), already safety-filtered; integrated by the servos each step.
        Raises ValueError on a wrong length or non-finite values (the safety layer prevents these).
        Clipped to DQ_MAX joint by joint."""
        try:
            values = np.asarray(dq, dtype=float).reshape(-1).tolist()
        except (TypeError, ValueError):
            values = None
        if values is None or len(values) != NUM_JOINTS or not all(map(math.isfinite, values)):
            raise ValueError(f"velocity command must be 7 finite values, got {dq!r}")
        self._cmd = [-lim[2] if x < -lim[2] else lim[2] if x > lim[2] else x
                     for x, lim in zip(values, self._limits)]

    def step(self, n: int = 1) -> None:
        """Advance the physics by n steps of physics_dt."""
        n = int(n)
        if n < 0:
            raise ValueError(f"step count must be >= 0, got {n}")
        m, d = self.model, self.data
        h = m.opt.timestep
        for _ in range(n):
            mujoco.mj_step1(m, d)
            q = d.qpos[self._qpos].tolist()
            v = d.qvel[self._dofs].tolist()
            if self._violation is None:        # the reflexes look at every state (contact forces of
                self._violation = self._reflex.check(q, v, d.qfrc_constraint[self._dofs].tolist())
            if self._servo_on:                 # the step that led to it: mj_step2 computes them)
                self._servo(h, q, v)
            else:
                self._integrate_targets(h)
            self.hand.step(h)
            mujoco.mj_step2(m, d)
            self._cmd_prev = self._cmd

    def _integrate_targets(self, h: float) -> None:
        """q_t += h * command, inside the joint limits (the servo does it on its own pass)."""
        q_t, cmd = self._q_t, self._cmd
        for i, lim in enumerate(self._limits):
            x = q_t[i] + h * cmd[i]
            q_t[i] = lim[0] if x < lim[0] else lim[1] if x > lim[1] else x

    def _servo(self, h: float, q: list[float], v: list[float]) -> None:
        """Set the joint torques of this step (between mj_step1, which computed M(q) and the bias
        forces at this state, and mj_step2, which integrates exactly with them), and move the targets
        on. The reference is the integrated command: position q_t, velocity the previous command,
        acceleration the change of command. Joint by joint on Python floats (several times faster than
        NumPy for seven values)."""
        d = self.data
        cmd, prev, q_t = self._cmd, self._cmd_prev, self._q_t
        inv_h = 1.0 / h
        wn = SERVO_BANDWIDTH
        wn2, kd = wn * wn, 2.0 * wn
        acc = []
        for i, (q_lo, q_hi, vmax, amax, _) in enumerate(self._limits):
            c, p, vi = cmd[i], prev[i], v[i]
            a = (c - p) * inv_h + wn2 * (q_t[i] - q[i]) + kd * (p - vi)
            lo = (-vmax - vi) * inv_h              # the drive never passes the velocity limit ...
            hi = (vmax - vi) * inv_h
            lo = -amax if lo < -amax else lo       # ... nor the acceleration limit
            hi = amax if hi > amax else hi
            acc.append(lo if a < lo else hi if a > hi else a)
            x = q_t[i] + h * c                     # the target of the next step, inside the limits
            x = min(max(x, q[i] - MAX_FOLLOWING_ERROR), q[i] + MAX_FOLLOWING_ERROR)   # no windup
            q_t[i] = q_lo if x < q_lo else q_hi if x > q_hi else x
        self._acc[self._dofs] = acc
        mujoco.mj_mulM(self.model, d, self._mv, self._acc)
        tau = self._mv[self._dofs].tolist()
        bias = d.qfrc_bias[self._dofs].tolist()
        grav = d.qfrc_gravcomp[self._dofs].tolist()  # added by MuJoCo (actuator gravity compensation)
        scale = 1.0
        for t, b, lim in zip(tau, bias, self._limits):
            if abs(t + b) > lim[4] and t != 0.0:   # where the torque limits cannot give it: scale
                bound = lim[4] if t > 0 else -lim[4]   # the whole acceleration (direction kept)
                scale = min(scale, max(0.0, (bound - b) / t))
        if scale < 1.0:
            self.torque_limited_steps += 1
            tau = [scale * t for t in tau]
        d.ctrl[self._motor] = [t + b - g for t, b, g in zip(tau, bias, grav)]

    def hold(self) -> None:
        """Stop where the arm is, as a real Panda's reflex does: servo targets at the measured position
        (inside the joint limits), zero command; the servo brakes within the limit table."""
        self._q_t = np.clip(self.data.qpos[self._qpos], Q_MIN, Q_MAX).tolist()
        self._cmd = self._cmd_prev = self._zero

    def reflex(self) -> str | None:
        """The libfranka-like error of the first limit the arm went past (position, velocity,
        external torque; see arm_checks.ReflexMonitor) since the last clear_reflex(), or None."""
        return self._violation

    def clear_reflex(self) -> None:
        self._violation = None

    @property
    def teaching(self) -> bool:
        return not self._servo_on

    def set_teaching(self, active: bool, damping=0.0) -> None:
        """Teaching mode: servo off, the arm backdrivable (gravity compensated, joint damping
        `damping` N m s/rad, one value or one per joint). Leaving it holds the measured pose (hold())."""
        if active:
            b = np.broadcast_to(np.asarray(damping, dtype=float), (NUM_JOINTS,))
            if not np.all(np.isfinite(b) & (b >= 0.0)):
                raise ValueError(f"teaching damping must be >= 0, got {damping!r}")
            self._servo_on = False
            self.data.ctrl[self._motor] = 0.0
            self.model.dof_damping[self._dofs] = b
        else:
            self.model.dof_damping[self._dofs] = 0.0
            self._servo_on = True
            self.hold()

    def collisions(self, q) -> list[str]:
        """Pairs in collision at arm configuration q (robot with itself, the table or the floor)."""
        if self._collisions is None:
            self._collisions = CollisionChecker(self.model, self._qadr, ROBOT_PREFIX, ENVIRONMENT_GEOMS)
        return self._collisions.collisions(np.asarray(q, dtype=float))

    # ------------------------------------------------------------------ scene
    def reset(self, seed: int | None = None, objects: Sequence | None = None,
              q0=None, refuse_collisions: bool = False, hand_width: float = 0.0) -> list[ObjectPose]:
        """New episode: arm at q0 (default ready pose) at rest, zero command, time 0, the hand at
        `hand_width` (m; default closed, fingers pressed together), and either an
        explicit object layout (ObjectPose, dict or (class, x, y, yaw) items) or a random one from
        `seed` (1..4 distinct objects; same seed -> same layout). Returns the resulting layout.
        Raises ValueError with a clear message on bad input, leaving the scene unchanged; with
        `refuse_collisions` also for a q0 in collision with the robot itself or the table."""
        q_init = self._validate_q0(q0)
        if refuse_collisions:
            hits = self.collisions(q_init)
            if hits:
                raise ValueError(f"q0 in collision: {'; '.join(hits)}")
        if objects is not None:
            layout = self.validate_layout(objects)
        else:
            if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                                     or seed < 0):
                raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
            layout = random_layout(np.random.default_rng(seed), catalogue=self.catalogue)
        if not (isinstance(hand_width, (int, float)) and math.isfinite(hand_width)
                and 0.0 <= hand_width <= HAND.max_width):
            raise ValueError(f"hand_width must be within 0..{HAND.max_width} m, got {hand_width!r}")
        self._apply(layout, q_init, float(hand_width))
        return self.object_poses()

    def _validate_q0(self, q0) -> np.ndarray:
        if q0 is None:
            return np.array(READY_POSE, dtype=float)
        try:
            q = np.asarray(q0, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"q0 must be 7 joint positions, got {q0!r}") from None
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q0 must be 7 finite joint positions, got {q0!r}")
        bad = np.nonzero((q < Q_MIN) | (q > Q_MAX))[0]
        if bad.size:
            raise ValueError(f"q0 outside the joint limits at {[JOINT_NAMES[i] for i in bad]}")
        return q

    def validate_layout(self, objects: Iterable) -> list[ObjectPose]:
        """Normalise and check an explicit layout; ValueError says what is wrong."""
        return validate_layout(objects, self.catalogue)

    def _apply(self, layout: list[ObjectPose], q_init: np.ndarray, hand_width: float = 0.0) -> None:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self._qadr] = q_init
        d.ctrl[:] = 0.0
        m.dof_damping[self._dofs] = 0.0
        self._servo_on = True
        self._violation = None
        self._q_t = [float(x) for x in q_init]
        self._cmd = self._cmd_prev = self._zero
        placed = {p.class_id: p for p in layout}
        self._active = [p.class_id for p in layout]
        for i, c in enumerate(self.catalogue.classes):
            qa, geoms = self._obj_qadr[c], self._obj_geoms[c]
            if c in placed:
                p = placed[c]
                d.qpos[qa:qa + 3] = (p.x, p.y, self.catalogue.spec(c).height / 2)
                d.qpos[qa + 3:qa + 7] = yaw_quat(p.yaw)
                m.body_gravcomp[self._obj_body[c]] = 0.0
                m.geom_contype[geoms] = self._geom_contype[geoms]
                m.geom_conaffinity[geoms] = self._geom_conaffinity[geoms]
            else:
                d.qpos[qa:qa + 3] = park_position(i)
                d.qpos[qa + 3:qa + 7] = (1.0, 0.0, 0.0, 0.0)
                m.body_gravcomp[self._obj_body[c]] = 1.0
                m.geom_contype[geoms] = 0
                m.geom_conaffinity[geoms] = 0
        self.hand.reset(hand_width)
        mujoco.mj_forward(m, d)

    def held_objects(self) -> list[str]:
        """Classes of the layout's objects that both fingers touch now (what the hand holds)."""
        return self.hand.holding({c: self._obj_body[c] for c in self._active})

    def object_poses(self) -> list[ObjectPose]:
        """Ground-truth poses of the objects in the current layout (centre, yaw, full quaternion)."""
        out = []
        for c in self._active:
            qa = self._obj_qadr[c]
            x, y, z = (float(v) for v in self.data.qpos[qa:qa + 3])
            quat = tuple(float(v) for v in self.data.qpos[qa + 3:qa + 7])
            out.append(ObjectPose(c, x, y, quat_yaw(quat), z, quat))
        return out

    # ------------------------------------------------------------------ camera
    @staticmethod
    def _check_size(width: int, height: int) -> None:
        if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))):
            raise ValueError(f"camera size must be integers, got {width!r}x{height!r}")
        if not (16 <= width <= MAX_OFFSCREEN[0] and 16 <= height <= MAX_OFFSCREEN[1]):
            raise ValueError(f"camera size must be within 16x16..{MAX_OFFSCREEN[0]}x{MAX_OFFSCREEN[1]}, "
                             f"got {width}x{height}")

    @property
    def camera_size(self) -> tuple[int, int]:
        return self._width, self._height

    @property
    def render_enabled(self) -> bool:
        return self._render_enabled

    def set_camera_size(self, width: int, height: int) -> None:
        """Change the rendered image size (intrinsics follow)."""
        self._check_size(width, height)
        if (width, height) != (self._width, self._height) and self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._width, self._height = int(width), int(height)

    def render(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB image from the fixed camera (row 0 at the top)."""
        if not self._render_enabled:
            raise RuntimeError("PandaSim was created with render=False; no camera images")
        if self._renderer is None:
            os.environ.setdefault("MUJOCO_GL", "egl")
            self._renderer = mujoco.Renderer(self.model, height=self._height, width=self._width)
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        mujoco.mj_kinematics(self.model, self.data)  # draw the current qpos, not the pre-step one
        self._renderer.update_scene(self.data, camera=self._cam_id)
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        return self._renderer.render()

    def camera_intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels of the current image size (pinhole, square pixels, pixel
        centres at integer coordinates as in ROS/OpenCV)."""
        return pinhole_intrinsics(self._width, self._height, float(self.model.cam_fovy[self._cam_id]))

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and rotation of camera_optical_frame in the world (z forward, x right, y down)."""
        pos = self.data.cam_xpos[self._cam_id].copy()
        rot = self.data.cam_xmat[self._cam_id].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
        return pos, rot

    def project(self, points_world) -> np.ndarray:
        """(N, 2) pixel coordinates (u right, v down) of world points; NaN for points behind the camera."""
        pts = np.asarray(points_world, dtype=float).reshape(-1, 3)
        pos, rot = self.camera_pose()
        pc = (pts - pos) @ rot
        fx, fy, cx, cy = self.camera_intrinsics()
        uv = np.full((len(pts), 2), np.nan)
        front = pc[:, 2] > 1e-9
        uv[front, 0] = fx * pc[front, 0] / pc[front, 2] + cx
        uv[front, 1] = fy * pc[front, 1] / pc[front, 2] + cy
        return uv

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __del__(self):  # best effort: free the GL context
        try:
            self.close()
        except Exception:
            pass

"""The teleoperation core (no rclpy): joystick + joint state + latched visual context → joint velocity.

Joystick mapping as teleop_twist_joy (axis, scale, deadband → exactly zero, optional deadman button,
timeout → zero); the paper's 1.5 rad/s norm clamp; the context (detection and/or image) is latched at
episode start and re-latched on a button, on request, or when older than ``detection_max_age``.
:meth:`TeleopCore.step` never raises: every problem becomes a zero command and a status saying why.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from vla_common.arming import Arming
from vla_common.detection import Detection
from vla_common.robot import HAND, JOINT_NAMES

from vla_latent_controller.assistance import Assistance, AssistState, check_level
from vla_latent_controller.context import (
    GOAL_SELECTIONS,
    ContextError,
    candidates,
    detection_problem,
    select_detection,
)
from vla_latent_controller.ee_baseline import EE_AXES, EndEffectorBaseline
from vla_latent_controller.joints import JointBinding, JointResolver

MODES = ("latent", "end_effector")


class Code(enum.IntEnum):
    """Mirrors vla_interfaces/msg/ControllerStatus constants (a test checks they agree)."""

    ACTIVE = 0
    ZERO_DEADBAND = 1
    WAITING_FOR_JOY = 2
    JOY_TIMEOUT = 3
    WAITING_FOR_JOINT_STATES = 4
    WAITING_FOR_DETECTION = 5
    BAD_INPUT = 6
    DEADMAN_RELEASED = 7
    MODEL_ERROR = 8
    AWAITING_NEUTRAL = 9


# Zeros the operator chose: the only inputs that re-arm the controller after a stop (vla_common.arming).
NEUTRAL_CODES = (Code.ZERO_DEADBAND, Code.DEADMAN_RELEASED)


@dataclass
class TeleopParams:
    """Controller parameters (the node declares each with a descriptor; see README)."""

    mode: str = "latent"
    axis: int = 0
    axis_scale: float = 1.0
    deadband: float = 0.1
    enable_button: int = -1
    joy_timeout: float = 0.1
    action_scale: float = 1.0
    max_joint_speed: float = 1.5
    # The latent whose chord gives the command's direction, as a fraction of the stick's (the speed stays
    # the chord's at the stick's latent; decoder_np.LatentDecoder.velocity). 0: the model's own
    # (its calibrated latent.path_fraction, 1 (the paper's command) when it has none; model.path_fraction).
    # A held full stick with the shipped `default` model did its base tasks far more often at 0.65
    # (issue 20; docs/history/controller.md), the cereal-box models failed the demo's layouts with it.
    path_fraction: float = 0.0
    redetect_button: int = -1
    grasp_button: int = -1   # a press toggles the hand (grasp / open): the node asks the bridge
    ee_mode_button: int = 0
    ee_debounce: float = 0.25
    ee_linear_speed: float = 0.2
    ee_angular_speed: float = 0.5
    ee_damping: float = 0.05
    ee_axes: list[str] = field(default_factory=lambda: list(EE_AXES))  # what ee_mode_button cycles
    detection_max_age: float = 0.0
    goal_selection: str = "highest_score"
    # Goal inference and a pull toward the inferred goal, latent mode (assistance.py): off, low, high
    assistance: str = "off"
    joint_states_timeout: float = 0.5
    # per-joint speed limits (rad/s) by the robot's joint name; the whole vector is scaled to respect them
    dq_max: Mapping[str, float] | None = None

    def check(self, classes: Sequence[str] | None = None) -> str | None:
        """A reason the parameters are unusable, or None."""
        if self.mode not in MODES:
            return f"mode {self.mode!r} is not one of {MODES}"
        if not 0.0 <= self.deadband < 1.0:
            return f"deadband {self.deadband} must be in [0, 1)"
        if not 0.0 <= self.path_fraction <= 1.0:
            return f"path_fraction {self.path_fraction} must be in [0, 1] (0: the model's)"
        if check_level(self.assistance):
            return check_level(self.assistance)
        if (
            self.goal_selection not in GOAL_SELECTIONS
            and classes is not None
            and self.goal_selection not in classes
        ):
            return (
                f"goal_selection {self.goal_selection!r} is neither {GOAL_SELECTIONS} nor one of the model's "
                f"classes {list(classes)}"
            )
        return None


@dataclass
class Status:
    mode: str = "latent"
    code: Code = Code.WAITING_FOR_JOINT_STATES
    reason: str = ""
    latched_class: str = ""
    latched_x: float = math.nan
    latched_y: float = math.nan
    latched_by: str = ""  # how the latched object was chosen: goal_selection or the operator's pick
    z: float = 0.0
    ee_axis: str = "x"
    command: np.ndarray = field(default_factory=lambda: np.zeros(7))
    assist: AssistState = field(default_factory=AssistState)  # the inferred goal, how sure, its share


@dataclass
class Latched:
    class_id: str | None
    x: float
    y: float
    t: float
    gain: float
    by: str = ""


def stick_to_unit(stick, deadband: float, axis_scale: float = 1.0):
    """The stick mapping (scalar or array): |s| <= deadband → 0 exactly; beyond, rescaled so it starts at
    0 and reaches ±1 at full stick, times ``axis_scale``, clamped to [-1, 1]. The simulated teleoperator
    uses this too, so it commands what the node would."""
    s = np.clip(np.asarray(stick, dtype=float), -1.0, 1.0)
    u = np.where(np.abs(s) <= deadband, 0.0, np.sign(s) * (np.abs(s) - deadband) / (1.0 - deadband))
    u = np.clip(u * axis_scale, -1.0, 1.0)
    return float(u) if u.ndim == 0 else u


def unit_to_stick(unit: float, deadband: float) -> float:
    """The stick value that stick_to_unit maps to ``unit`` ∈ [-1, 1] (axis_scale 1): 0 stays 0, anything
    else lies past the deadband. A simulated operator who wants a share of full speed pushes this."""
    u = float(np.clip(unit, -1.0, 1.0))
    return 0.0 if u == 0.0 else float(np.sign(u)) * (deadband + abs(u) * (1.0 - deadband))


def _pressed_now(buttons: Sequence[int], prev: Sequence[int], i: int) -> bool:
    """Button i went from not pressed to pressed (value 1) between two joy messages."""
    return 0 <= i < len(buttons) and buttons[i] == 1 and not (i < len(prev) and prev[i] == 1)


def _finite(x) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


@dataclass
class _JointStates:
    """The latest joint_states message that names any of the controller's joints."""

    names: tuple[str, ...] = ()
    positions: np.ndarray | None = None
    t: float = -math.inf
    error: str | None = None  # a malformed message (BAD_INPUT)


class TeleopCore:
    """One controller instance. Feed it inputs with ``on_*`` and call :meth:`step` at the command rate.

    ``model`` is a :class:`vla_latent_controller.model.LatentModel` (or None with ``model_error`` saying
    why); ``kinematics`` has ``jacobian(q)`` (and ``fk(q)`` for ``nearest_to_ee``) over the joints
    ``joint_names`` (default: the Panda's); ``ee_pixel`` maps q to the end effector's pixel in the
    detector's image (or None when the camera is not calibrated). ``joint_map`` renames the
    controller's joints to the robot's ({model joint: robot joint}, see :mod:`.joints`).
    ``camera()`` is the detector's calibrated camera (a `vla_common.camera_model.PinholeCamera`, or
    None while not calibrated): where the assistance finds the detected objects (see :mod:`.assistance`).
    """

    def __init__(
        self,
        params: TeleopParams,
        model=None,
        kinematics=None,
        joint_names: Sequence[str] | None = None,
        model_error: str | None = None,
        ee_pixel: Callable[[np.ndarray], tuple[float, float] | None] | None = None,
        joint_map: Mapping[str, str] | None = None,
        camera: Callable[[], object | None] | None = None,
    ):
        self.params = params
        self.assist = Assistance(kinematics, camera)
        self.kinematics = kinematics
        self.ee_pixel = ee_pixel
        self.ee = EndEffectorBaseline(
            kinematics, params.ee_linear_speed, params.ee_angular_speed, params.ee_damping,
            params.ee_debounce, params.ee_axes,
        )
        self.mode = params.mode if params.mode in MODES else "latent"
        self.kin_joints = tuple(joint_names) if joint_names is not None else JOINT_NAMES
        self.joint_map = dict(joint_map or {})
        self.model = None
        self.model_error = model_error
        # inputs
        self._js = _JointStates()
        self._foreign: tuple[float, tuple[str, ...]] | None = None  # (time, names) naming none of ours
        self._axes: list[float] | None = None
        self._buttons: list[int] = []
        self.grasp_presses = 0  # presses of grasp_button so far (the node sends one toggle per press)
        self._joy_t = -math.inf
        self._dets: list[Detection] = []
        self._dets_size: tuple[int, int] | None = None
        self._dets_t = -math.inf
        self._image: np.ndarray | None = None
        self._image_t = -math.inf
        # context
        self.latched: Latched | None = None
        self._latch_after = -math.inf  # a new latch needs inputs received at or after this time
        self._target: tuple[str, str, int, float, float] | None = None  # the operator's pick (select_target)
        self._target_by = ""
        self.set_model(model, model_error)
        self._cmd = np.zeros(len(self.joint_names))
        self.command_joints: tuple[str, ...] = ()  # the command's joints (the robot's names and order)
        self._limits: tuple[tuple, np.ndarray | None] = ((), None)  # ((joints, id(dq_max)), limits)
        # Motion needs the operator's neutral first: at start, and after every zero they did not choose.
        self.arming = Arming(armed=False, reason="starting")
        self.status = Status(mode=self.mode, ee_axis=self.ee.axis, command=self._cmd.copy())

    # ----------------------------------------------------------------- configuration
    def set_model(self, model, error: str | None = None) -> None:
        self.model, self.model_error = model, (None if model is not None else error)
        self.latched = None
        self._bind_joints()
        # the assistance's kinematics are the Panda's, in its joint order: a model on other joints gets none
        fits = model is not None and tuple(model.joint_names) == tuple(self.kin_joints)
        self.assist.kinematics = self.kinematics if fits else None
        self.assist.set_tasks(model.tasks() if model is not None else {})

    def set_joint_map(self, joint_map: Mapping[str, str]) -> None:
        """Rename the controller's joints to the robot's ({model joint: robot joint})."""
        self.joint_map = dict(joint_map)
        self._bind_joints()

    def _bind_joints(self) -> None:
        model_joints = self.model.joint_names if self.model is not None else self.kin_joints
        self._resolvers = {
            "latent": JointResolver(model_joints, self.joint_map),
            "end_effector": JointResolver(self.kin_joints, self.joint_map),
        }

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The active mode's joints, in the order the decoder (or the kinematics) computes them."""
        return self._resolvers[self.mode].joints

    def sync_params(self) -> None:
        """Apply changed end-effector parameters (the rest are read from ``params`` on every step)."""
        p, ee = self.params, self.ee
        ee.linear_speed, ee.angular_speed = p.ee_linear_speed, p.ee_angular_speed
        ee.damping, ee.debounce = p.ee_damping, p.ee_debounce
        if tuple(p.ee_axes) != ee.axes:
            ee.set_axes(p.ee_axes)

    def set_mode(self, mode: str) -> tuple[bool, str]:
        if mode not in MODES:
            return False, f"unknown mode {mode!r}; expected one of {MODES}"
        self.mode = mode
        self.ee.restart()   # a mode set (again) starts at the first axis, whatever the last trial left
        return True, f"mode {mode}"

    def restamp(self, f: Callable[[float], float]) -> None:
        """The clock that gives ``now`` moved its origin (a lockstep node counts each episode from its
        re-latch: vla_latent_controller.lockstep.EpisodeClock): every time kept, here and in the
        assistance and the end-effector baseline, is mapped by ``f`` (old seconds -> new)."""
        js = self._js
        self._js = _JointStates(js.names, js.positions, f(js.t), js.error)
        if self._foreign is not None:
            self._foreign = (f(self._foreign[0]), self._foreign[1])
        self._joy_t, self._dets_t, self._image_t = f(self._joy_t), f(self._dets_t), f(self._image_t)
        self._latch_after = f(self._latch_after)
        if self.latched is not None:
            self.latched.t = f(self.latched.t)
        self.ee.restamp(f)
        self.assist.restamp(f)

    def request_redetect(self, now: float) -> None:
        """Drop the latched context; the next detection (and image) received from ``now`` on is latched."""
        self.latched = None
        self._latch_after = now
        self.assist.reset()

    def select_target(
        self, by: str, class_id: str, index: int, x: float, y: float, now: float
    ) -> tuple[bool, str]:
        """The operator picks the object to latch: by ``class`` (highest score of it), by ``index`` into the
        latest detections, by ``pixel`` (the smallest box holding x, y in detector pixels), or ``policy``
        (back to goal_selection). The pick is latched from the next detection; a refusal says why."""
        if by == "policy":
            self._target = None
        elif by == "class":
            classes = self.model.classes if self.model is not None else ()
            if class_id not in classes:
                return False, f"class {class_id!r} is not one of the model's classes {list(classes)}"
            self._target = ("class", class_id, -1, math.nan, math.nan)
        elif by == "index":
            if not 0 <= index < len(self._dets):
                return False, f"index {index} is not in the latest {len(self._dets)} detections"
            self._target = ("index", "", index, math.nan, math.nan)
        elif by == "pixel":
            if not (_finite(x) and _finite(y)):
                return False, "pixel coordinates must be finite"
            self._target = ("pixel", "", -1, float(x), float(y))
        else:
            return False, f"unknown selection {by!r}; expected class, index, pixel or policy"
        self.request_redetect(now)
        return True, f"selection by {by}: latched from the next detection"

    def _picked(self) -> tuple[Detection | None, str]:
        """The operator's pick among the latest detections (None when it is not there) and how it was made."""
        by, class_id, index, x, y = self._target
        classes = self.model.classes if self.model is not None else ()
        dets = [d for d in self._dets if d.class_id in classes]
        if by == "class":
            hits = [d for d in dets if d.class_id == class_id]
            return (max(hits, key=lambda d: d.score) if hits else None), f"operator: class {class_id}"
        if by == "index":
            d = self._dets[index] if index < len(self._dets) else None
            return (d if d in dets else None), f"operator: index {index}"
        hits = [d for d in dets if abs(d.cx - x) <= d.width / 2 and abs(d.cy - y) <= d.height / 2]
        best = min(hits, key=lambda d: d.width * d.height) if hits else None
        return best, f"operator: pixel ({x:.0f}, {y:.0f})"

    def on_joy(self, axes: Sequence[float], buttons: Sequence[int], now: float) -> None:
        prev = self._buttons
        try:
            self._axes = list(axes)
            self._buttons = [int(b) for b in buttons]
        except (TypeError, ValueError):  # not a sequence of numbers: BAD_INPUT via an empty axes list
            self._axes, self._buttons = [], []
        self._joy_t = now
        p = self.params
        if _pressed_now(self._buttons, prev, p.ee_mode_button) and self.mode == "end_effector":
            self.ee.press(now)
        if _pressed_now(self._buttons, prev, p.redetect_button):
            self.request_redetect(now)
        if _pressed_now(self._buttons, prev, p.grasp_button):
            self.grasp_presses += 1
            self.assist.on_grasp_press()

    def on_joint_states(self, names: Sequence[str], positions: Sequence[float], now: float) -> None:
        """Keep the latest message that names any of our joints (resolved by name in :meth:`step`); one
        naming none of them (another robot, or a gripper's own joint_states) is only remembered."""
        names = tuple(names)
        if len(names) != len(positions):
            error = f"joint_states has {len(names)} names but {len(positions)} positions"
            self._js = _JointStates(names, None, now, error)
            return
        if not any(r.overlaps(names) for r in self._resolvers.values()):
            self._foreign = (now, names)
            return
        try:
            q = np.asarray(positions, dtype=float)
        except (TypeError, ValueError):
            self._js = _JointStates(names, None, now, "joint_states positions are not numbers")
            return
        self._js = _JointStates(names, q, now)
        fingers = [q[names.index(f)] for f in HAND.finger_joints if f in names]
        if len(fingers) == 2:   # each finger joint is half the gap
            self.assist.on_fingers(float(fingers[0] + fingers[1]), now)

    def on_detections(self, dets: Sequence[Detection], image_size: tuple[int, int], now: float) -> None:
        self._dets, self._dets_size, self._dets_t = list(dets), tuple(image_size), now

    def on_image(self, rgb: np.ndarray, now: float) -> None:
        self._image, self._image_t = rgb, now

    # ----------------------------------------------------------------- loop
    def step(self, now: float) -> tuple[np.ndarray, Status]:
        """The command for this tick (in the robot's joint order) and the status; never raises."""
        try:
            cmd, status = self._step(now)
        except Exception as e:  # a control loop must not die: report and command zero
            cmd, status = self._zero(Code.MODEL_ERROR, f"internal error: {type(e).__name__}: {e}")
        return self._armed(cmd, status)

    def _armed(self, cmd: np.ndarray, status: Status) -> tuple[np.ndarray, Status]:
        """The arming rule at the operator's end: a zero the operator chose (stick at neutral, deadman
        released) re-arms; any other zero (input late, no joint states, no context, bad input, a model
        error) is a stop they did not choose and disarms; while disarmed a moving stick gives zero and
        AWAITING_NEUTRAL. The bridge re-arms on any zero command, so this is what keeps a stick held
        through a stop from moving the arm (see vla_common.arming). An ACTIVE command that happens to
        be ~0 cannot be abused to re-arm the bridge: it depends only on q and z, which stay constant
        while the arm rests and the stick is held, so it stays ~0 until the operator moves the stick."""
        code = status.code
        if code == Code.ACTIVE:
            if self.arming.armed:
                return cmd, status
            return self._zero(Code.AWAITING_NEUTRAL,
                              f"stopped ({self.arming.reason}): return the stick to neutral to move")
        if code in NEUTRAL_CODES:
            self.arming.offer(True)
        else:
            self.arming.disarm(code.name.lower().replace("_", " "))
        return cmd, status

    def _zero(self, code: Code, reason: str, z: float = 0.0) -> tuple[np.ndarray, Status]:
        self._cmd[:] = 0.0
        return self._cmd, self._set_status(code, reason, z)

    def _set_status(self, code: Code, reason: str, z: float) -> Status:
        s = self.status
        s.mode, s.code, s.reason, s.z, s.ee_axis = self.mode, code, reason, float(z), self.ee.axis
        lat = self.latched
        s.latched_class = (lat.class_id or "") if lat else ""
        s.latched_x, s.latched_y = (lat.x, lat.y) if lat else (math.nan, math.nan)
        s.latched_by = lat.by if lat else ""
        s.command = self._cmd.copy()
        moving = code == Code.ACTIVE and self.mode == "latent"
        s.assist = self.assist.shown(self.params.assistance, moving)
        return s

    def _joint_state(self, now: float) -> tuple[np.ndarray, JointBinding] | tuple[Code, str]:
        """(q in the active joints' order, its binding to the robot), or (code, reason) for zero."""
        js, resolver, timeout = self._js, self._resolvers[self.mode], self.params.joint_states_timeout
        foreign = self._foreign is not None and self._foreign[0] >= js.t
        if foreign and (js.t == -math.inf or now - js.t > timeout):
            return Code.MODEL_ERROR, resolver.mismatch(self._foreign[1])
        if js.t == -math.inf:
            return Code.WAITING_FOR_JOINT_STATES, "no joint_states yet"
        if now - js.t > timeout:
            return (
                Code.WAITING_FOR_JOINT_STATES,
                f"last joint_states {now - js.t:.2f} s ago (timeout {timeout} s)",
            )
        if js.error is not None:
            return Code.BAD_INPUT, js.error
        binding = resolver.bind(js.names)
        if isinstance(binding, str):
            return Code.MODEL_ERROR, binding
        q = js.positions[binding.q_index]
        if not np.all(np.isfinite(q)):
            bad = [n for n, v in zip(resolver.robot_joints, q) if not math.isfinite(v)]
            return Code.BAD_INPUT, f"joint_states has non-finite positions for {', '.join(bad)}"
        return q, binding

    def _step(self, now: float) -> tuple[np.ndarray, Status]:
        p = self.params
        bad = p.check(self.model.classes if self.model is not None else None)
        if bad:
            return self._zero(Code.MODEL_ERROR, f"bad parameters: {bad}")
        state = self._joint_state(now)
        if isinstance(state[0], Code):
            return self._zero(*state)
        q, binding = state
        self._use_binding(binding)
        problem = self._mode_problem(q, now)
        if problem is not None:
            return self._zero(*problem)
        code, reason, u = self._stick(now)
        if code is not None:
            if code in NEUTRAL_CODES:
                self.assist.on_neutral()
            return self._zero(code, reason)
        z, dq = self._command(q, u, now)
        if self.assist.lost:
            return self._zero(Code.WAITING_FOR_DETECTION, self.assist.lost, z)
        if not np.all(np.isfinite(dq)):
            return self._zero(
                Code.MODEL_ERROR, "command is not finite (model or kinematics output NaN/Inf)", z
            )
        np.take(dq, binding.order, out=self._cmd)
        self._limit(self._cmd)
        return self._cmd, self._set_status(Code.ACTIVE, "", z)

    def _use_binding(self, binding: JointBinding) -> None:
        """Size the command for the bound joints; they are the robot's, in its order."""
        if binding.robot_names != self.command_joints:
            self.command_joints = binding.robot_names
            self._cmd = np.zeros(len(binding.robot_names))

    def _mode_problem(self, q: np.ndarray, now: float) -> tuple[Code, str] | None:
        """Why the active mode cannot command now (no model, no context yet, no kinematics), or None."""
        if self.mode == "latent":
            if self.model is None:
                return Code.MODEL_ERROR, self.model_error or "no model loaded (set model_path)"
            return self._ensure_context(q, now)
        if self.kinematics is None:
            return Code.MODEL_ERROR, "end_effector mode needs the Panda kinematics (Pinocchio)"
        return None

    def _command(self, q: np.ndarray, u: float, now: float) -> tuple[float, np.ndarray]:
        """(latent z, joint velocities in the active joints' order) for stick value u."""
        if self.mode == "latent":
            z = u * self.latched.gain
            fraction = self.model.path_fraction(self.params.path_fraction)   # 0: the model's calibrated one
            dq = self.model.decoder.velocity(q, z, fraction) * self.params.action_scale
            if self.params.assistance != "off":
                self._observe(q, now)
                dq = self.assist.command(q, u, dq, now)
            return z, dq
        return u, self.ee.command(q, u)

    def _observe(self, q: np.ndarray, now: float) -> None:
        """Show the assistance the latest detections and the latched object (in detector pixels)."""
        a, lat, size = self.assist, self.latched, self._dets_size
        a.level = self.params.assistance
        latched = None
        if lat is not None and lat.class_id and size and math.isfinite(lat.x):
            latched = (lat.class_id, lat.x * size[0], lat.y * size[1])
        a.observe(self._dets, size, self._dets_t, latched, q, now)

    def stick_code(self, now: float) -> Code | None:
        """What the stick says now (None: it drives; else why it gives zero): a change is a press, a
        release or an input that came back, whose command should not wait for the next period."""
        return self._stick(now)[0]

    def _stick(self, now: float) -> tuple[Code | None, str, float]:
        """(problem code or None, reason, stick value u ∈ [-1, 1] after deadband and scale)."""
        p = self.params
        if self._axes is None:
            return Code.WAITING_FOR_JOY, "no joy message yet", 0.0
        age = now - self._joy_t
        if age > p.joy_timeout:
            return Code.JOY_TIMEOUT, f"last joy message {age:.2f} s ago (joy_timeout {p.joy_timeout} s)", 0.0
        if not 0 <= p.axis < len(self._axes):
            return Code.BAD_INPUT, f"axis {p.axis} out of range: joy has {len(self._axes)} axes", 0.0
        deadman = self._deadman()
        if deadman is not None:
            return (*deadman, 0.0)
        v = self._axes[p.axis]
        if not _finite(v):
            return Code.BAD_INPUT, f"joy axis {p.axis} is not a finite number ({v!r})", 0.0
        if abs(float(v)) <= p.deadband:
            return Code.ZERO_DEADBAND, f"stick within deadband {p.deadband}", 0.0
        return None, "", stick_to_unit(float(v), p.deadband, p.axis_scale)

    def _deadman(self) -> tuple[Code, str] | None:
        """Why the enable button does not let the stick through, or None (held, or none configured)."""
        b = self.params.enable_button
        if b < 0:
            return None
        if b >= len(self._buttons):
            return Code.BAD_INPUT, f"enable_button {b} out of range: joy has {len(self._buttons)} buttons"
        v = self._buttons[b]
        if v == 1:  # pressed; a driver's -1 or any other value is not a held deadman
            return None
        return Code.DEADMAN_RELEASED, f"enable button {b} not held" + ("" if v == 0 else f" (value {v})")

    def _limit(self, dq: np.ndarray) -> None:
        """Scale the whole vector (keeping its direction) to the norm clamp and the per-joint limits."""
        p = self.params
        n = float(np.linalg.norm(dq))
        scale = 1.0
        if p.max_joint_speed > 0 and n > p.max_joint_speed:
            scale = p.max_joint_speed / n
        lim = self._joint_limits()
        if lim is not None:
            worst = float(np.max(np.abs(dq) / lim))
            if worst * scale > 1.0:
                scale = 1.0 / worst
        if scale < 1.0:
            dq *= scale

    def _joint_limits(self) -> np.ndarray | None:
        """Per-joint speed limits of the command's joints (by the robot's names; inf where unknown)."""
        limits = self.params.dq_max
        key = (self.command_joints, id(limits))
        if self._limits[0] != key:
            lim = None if not limits else np.array([limits.get(n, math.inf) for n in self.command_joints])
            self._limits = (key, lim)
        return self._limits[1]

    # ----------------------------------------------------------------- context
    def _ensure_context(self, q: np.ndarray, now: float) -> tuple[Code, str] | None:
        """Latch or re-latch the context; a (code, reason) when the command must be zero."""
        self._expire_latch(now)
        if self.latched is not None:
            return None
        det, problem = self._goal_detection(q)
        if problem is not None:
            return problem
        image = None
        if self.model.needs_image:
            if self._image is None or self._image_t < self._latch_after:
                return Code.WAITING_FOR_DETECTION, "waiting for a camera image to latch the context"
            image = self._image
        return self._latch(det, image)

    def detection_wanted(self, now: float) -> float | None:
        """The time from which a step at `now` needs every camera frame's detections, or None when it
        needs none (a lockstep controller waits for them: vla_latent_controller.lockstep): a latch's
        detection, and with the assistance on every frame's since the latch (it reads each array: taken
        whenever the detector's answer came, an assisted episode depended on the machine's load)."""
        p, m, lat = self.params, self.model, self.latched
        if self.mode != "latent" or m is None:
            return None
        fixed_class = p.goal_selection not in GOAL_SELECTIONS
        if m.encoder == "detector" or (m.encoder == "localization" and not fixed_class):
            if lat is None:
                return self._latch_after
            if p.detection_max_age > 0 and now - lat.t > p.detection_max_age:
                return max(self._latch_after, now - p.detection_max_age)
        if lat is not None and p.assistance != "off" and self._dets_t > -math.inf:
            return lat.t   # a detector answers (detections came): every frame's from the latch on
        return None

    def _expire_latch(self, now: float) -> None:
        """Drop a latch older than detection_max_age (0: never); the next one must be newer."""
        p, lat = self.params, self.latched
        if lat is not None and p.detection_max_age > 0 and now - lat.t > p.detection_max_age:
            self.latched = None
            self._latch_after = max(self._latch_after, now - p.detection_max_age)

    def _goal_detection(self, q: np.ndarray) -> tuple[Detection | None, tuple[Code, str] | None]:
        """(the goal's detection, None), (None, None) when the encoder needs none, or (None, problem)."""
        p, m = self.params, self.model
        fixed_class = p.goal_selection not in GOAL_SELECTIONS
        if not (m.encoder == "detector" or (m.encoder == "localization" and not fixed_class)):
            return None, None
        if self._dets_t == -math.inf:
            return None, (Code.WAITING_FOR_DETECTION, "no detections received yet")
        if self._dets_t < self._latch_after:
            return None, (Code.WAITING_FOR_DETECTION, "waiting for a new detection to latch")
        if self._target is not None:
            det, by = self._picked()
            if det is None:
                reason = f"the chosen object ({by}) is not in the latest detections"
                return None, (Code.WAITING_FOR_DETECTION, reason)
            # a re-latch (e.g. detection_max_age) keeps the operator's object by its class
            self._target = ("class", det.class_id, -1, math.nan, math.nan)
            self._target_by = by
            return det, None
        self._target_by = f"goal_selection: {p.goal_selection}"
        det = self._pick(q)
        if det is not None:
            return det, None
        for d in candidates(self._dets, p.goal_selection, m.classes):  # only malformed ones: refuse them
            problem = detection_problem(d, self._dets_size)
            if problem:
                return None, (Code.BAD_INPUT, problem)
        seen = sorted({d.class_id for d in self._dets})
        if seen and not any(c in m.classes for c in seen):
            reason = (f"detected classes {seen} are not in the model's classes {m.classes} "
                      "(model and detector disagree)")
            return None, (Code.MODEL_ERROR, reason)
        want = f" of class {p.goal_selection!r}" if fixed_class else ""
        return None, (Code.WAITING_FOR_DETECTION, f"no detection{want} in the latest detections")

    def _latch(self, det: Detection | None, image: np.ndarray | None) -> tuple[Code, str] | None:
        """Build the context from the goal's detection and/or image and fold it into the decoder."""
        p, m = self.params, self.model
        class_id = det.class_id if det is not None else None
        if class_id is None and p.goal_selection not in GOAL_SELECTIONS:
            class_id = p.goal_selection
        try:
            ctx = m.context(det=det, image_size=self._dets_size, image=image, class_id=class_id)
            m.decoder.set_context(ctx)
        except (ContextError, ValueError) as e:  # a malformed detection or image
            return Code.BAD_INPUT, f"cannot build the context: {e}"
        t = self._dets_t if det is not None else self._image_t
        if det is not None and self._dets_size:
            x, y = det.cx / self._dets_size[0], det.cy / self._dets_size[1]
        else:
            x = y = math.nan
        gain_class = class_id if m.encoder != "end_to_end" else None
        by = self._target_by or f"goal_selection: {p.goal_selection}"
        self.latched = Latched(class_id=class_id, x=x, y=y, t=t, gain=m.gain(gain_class), by=by)
        return None

    def _pick(self, q: np.ndarray) -> Detection | None:
        p = self.params
        ee_px = None
        if p.goal_selection == "nearest_to_ee" and self.ee_pixel is not None:
            try:
                ee_px = self.ee_pixel(q)
            except Exception:  # an uncalibrated camera falls back to the highest score
                ee_px = None
        return select_detection(self._dets, p.goal_selection, self.model.classes, ee_px, self._dets_size)


__all__ = ["Code", "EE_AXES", "MODES", "Status", "TeleopCore", "TeleopParams", "stick_to_unit"]

"""controller_node: joystick → joint velocities through the learned latent-action decoder (or the paper's
end-effector baseline). A thin ROS wrapper around :class:`vla_latent_controller.teleop.TeleopCore`:
inputs are stored as they arrive, a fixed-rate timer computes and publishes the command, and every
problem becomes a zero command plus a status saying why. Topics, parameters and services: README.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState, Joy
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from vla_common.camera_model import SIM_WEBCAM, PinholeCamera, look_at_rotation, project
from vla_common.image_convert import to_rgb
from vla_common.kinematics import PandaKinematics
from vla_common.robot import JOINT_NAMES, ROBOTS
from vla_common.ros import vision
from vla_common.ros.convert import detections_from_array, ns_from_stamp, stamp_from_ns
from vla_common.ros.diagnostics import Diagnostics
from vla_common.ros.node_main import ConfigError, StartupError, run_node
from vla_common.ros.parameters import THREAD_PRIORITY, Param, ParameterTable
from vla_common.ros.qos import IMAGE_QOS

from vla_interfaces.msg import ControllerStatus, DetectionArray, StepAnswer
from vla_interfaces.srv import GripperCommand, SelectTarget, SetMode
from vla_latent_controller.artifacts import ModelError
from vla_latent_controller.assistance import LEVELS
from vla_latent_controller.context import CNN_ENCODERS, GOAL_SELECTIONS
from vla_latent_controller.ee_baseline import axes_text, parse_axes
from vla_latent_controller.joints import parse_joint_map
from vla_latent_controller.lockstep import DETECTIONS, IMAGE, JOY, EpisodeClock, LockstepInputs
from vla_latent_controller.model import LatentModel
from vla_latent_controller.status_log import StatusLog
from vla_latent_controller.teleop import MODES, NEUTRAL_CODES, Code, Status, TeleopCore, TeleopParams

NODE_NAME = "controller_node"
BASE_FRAME = "panda_link0"
LOCKSTEP_QOS = QoSProfile(depth=100)  # reliable: in lockstep a lost message is a hang
LOCKSTEP_WARN_S = 10.0  # wall s a lockstep step may wait for its inputs before the node says what is missing


def _xyz(value: Any) -> str | None:
    return None if len(value) == 3 else f"needs 3 numbers (x, y, z), got {len(value)}"


def _refusal(parse: Callable[[Any], Any]) -> Callable[[Any], str | None]:
    """A parameter check from a parser that raises ValueError: its message is the refusal."""
    def check(value: Any) -> str | None:
        try:
            parse(value)
        except ValueError as e:
            return str(e)
        return None
    return check


_CORE_DEFAULTS = TeleopParams()


def _axes_from_list(value: Any) -> Any:
    """ee_axes given as a list (files written before it was a string; a client's set): its text."""
    return axes_text(value) if isinstance(value, (list, tuple)) else value


def _core(name: str, description: str, **options: Any) -> Param:
    """A parameter the core reads: its default is TeleopParams's, declared there once."""
    return Param(name, getattr(_CORE_DEFAULTS, name), description, **options)


PARAMETERS = ParameterTable([
    THREAD_PRIORITY,   # on the operator's path: SCHED_FIFO where allowed (vla_common.priority)
    Param("model_path", "", "trained model directory (config.json + model.safetensors); empty: the "
          "shipped default; setting it reloads the model", dynamic=True),
    _core("mode", "latent or end_effector (also ~/set_mode)", choices=MODES, dynamic=True),
    Param("rate", 100.0, "command publish rate (Hz; not in lockstep)", range=(1.0, 1000.0)),
    Param("lockstep", False, "answer the bridge's lockstep simulation: one command per joint state, once "
          "the operator's joy stamped with that state is in, sent in a vla_interfaces/StepAnswer on "
          "lockstep/answer (not joint_velocity_cmd); no timer (vla_latent_controller.lockstep)"),
    Param("status_rate", 10.0, "~/status publish rate (Hz); also published on every change of code",
          range=(0.1, 1000.0), dynamic=True),
    _core("axis", "joystick axis that drives the latent action (or the end-effector axis)",
          range=(0, 63), dynamic=True),
    _core("axis_scale", "stick multiplier (negative inverts); the result is clamped to [-1, 1]",
          range=(-10.0, 10.0), dynamic=True),
    _core("deadband", "|stick| at or below this gives exactly zero; rescaled beyond it",
          range=(0.0, 0.95), dynamic=True),
    _core("enable_button", "deadman button that must be held; -1: none", range=(-1, 63), dynamic=True),
    _core("joy_timeout", "no joy message for this long (s) -> zero command", range=(0.01, 10.0),
          dynamic=True),
    _core("action_scale", "decoder output -> rad/s multiplier", range=(0.0, 10.0), dynamic=True),
    _core("max_joint_speed", "joint-velocity norm clamp (rad/s), direction kept; paper: 1.5",
          range=(0.0, 5.0), dynamic=True),
    _core("path_fraction", "the command's direction is the decoder's chord at this fraction of the "
          "latent, its speed the chord's at the latent; 1: the paper's command; 0: the model's calibrated "
          "one (latent.path_fraction; 1 when it has none)", range=(0.0, 1.0), dynamic=True),
    _core("joint_states_timeout", "no joint_states for this long (s) -> zero command",
          range=(0.01, 10.0), dynamic=True),
    Param("joint_map", [], "robot joints that stand for the model's: 'robot_joint:model_joint' entries, "
          "e.g. fr3_joint1:panda_joint1 for a Panda model on an FR3; unmapped joints keep their names",
          dynamic=True, check=_refusal(parse_joint_map), array="string_array"),
    _core("goal_selection", "which detection is the goal: highest_score, nearest_to_ee "
          "or a class of the model", dynamic=True),
    _core("assistance", "goal inference over the detected objects' tasks and a pull toward the inferred "
          "goal as its confidence grows (latent mode): off, low (at most half the command) or high; the "
          "stick still decides: zero at rest, reversed it backs away", choices=LEVELS, dynamic=True),
    _core("detection_max_age", "re-latch when the latched detection is older (s); 0: latch once "
          "(paper)", range=(0.0, 86400.0), dynamic=True),
    _core("redetect_button", "button that re-latches the context from the next detection; -1: none",
          range=(-1, 63), dynamic=True),
    _core("grasp_button", "button whose press toggles the hand (grasp / open) through the bridge's "
          "gripper service; -1: none", range=(-1, 63), dynamic=True),
    Param("gripper_service", "panda_bridge/gripper", "the bridge's vla_interfaces/GripperCommand "
          "service the grasp button calls"),
    Param("camera_position", [float(v) for v in SIM_WEBCAM.position], "camera optical centre in the "
          "world (m), for nearest_to_ee; default: the simulated webcam", dynamic=True, check=_xyz,
          array="double_array"),
    Param("camera_look_at", [float(v) for v in SIM_WEBCAM.look_at], "point the camera looks at (m), for "
          "nearest_to_ee; default: the simulated webcam's", dynamic=True, check=_xyz, array="double_array"),
    _core("ee_mode_button", "button that cycles the end-effector axis x, y, z, roll, pitch, yaw; "
          "-1: none", range=(-1, 63), dynamic=True),
    _core("ee_debounce", "end-effector axis button debounce (s)", range=(0.0, 5.0), dynamic=True),
    Param("ee_axes", axes_text(_CORE_DEFAULTS.ee_axes), "the axes ee_mode_button cycles, in order, "
          "apart by commas: x,y,z,roll,pitch,yaw or distinct ones of them; a task with the hand pointing "
          "down needs x,y,z (a list, the older form, is taken as the same)", dynamic=True,
          check=_refusal(parse_axes), convert=_axes_from_list),
    _core("ee_linear_speed", "end-effector mode: TCP speed at full stick (m/s); paper: 0.5",
          range=(0.0, 1.7), dynamic=True),
    _core("ee_angular_speed", "end-effector mode: rotation speed at full stick (rad/s)",
          range=(0.0, 2.5), dynamic=True),
    _core("ee_damping", "damping of the Jacobian pseudo-inverse", range=(0.0, 1.0), dynamic=True),
])

# Parameters copied into the core's TeleopParams: as they are, or through a conversion of their form.
_CORE_PARAMS = tuple(name for name in TeleopParams.__dataclass_fields__ if name in PARAMETERS.params)
_TO_CORE: dict[str, Callable[[Any], Any]] = {"ee_axes": lambda text: list(parse_axes(text))}


def _core_value(name: str, value: Any) -> Any:
    return _TO_CORE[name](value) if name in _TO_CORE else value


def goal_refusal(value: str, model: LatentModel | None) -> str | None:
    """Why `value` cannot be the goal_selection with this model, or None."""
    if value in GOAL_SELECTIONS:
        return None
    classes = list(model.classes) if model is not None else []
    if value in classes:
        return None
    return f"{value!r} is neither one of {list(GOAL_SELECTIONS)} nor a class of the model {classes}"


def joint_speed_limits() -> dict[str, float]:
    """dq_max of every known arm's joints by name (their names differ: panda_joint1, fr3_joint1, ...)."""
    return {n: float(v) for spec in ROBOTS.values() for n, v in zip(spec.joint_names, spec.dq_max)}


def default_model_path() -> str:
    """share/vla_latent_controller/models/default if a model is installed there, else ''."""
    try:
        share = Path(get_package_share_directory("vla_latent_controller"))
    except PackageNotFoundError:
        return ""
    p = share / "models" / "default"
    return str(p) if (p / "config.json").is_file() else ""


def _panda_kinematics(logger) -> PandaKinematics | None:
    """The Panda's kinematics for end-effector mode, or None (latent mode does not need it)."""
    try:
        return PandaKinematics()
    except Exception as e:  # a missing URDF disables end-effector mode only
        logger.warn(f"Panda kinematics unavailable ({e}); end_effector mode disabled")
        return None


class ControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        values = PARAMETERS.declare(self, self._on_parameter)
        self.params = TeleopParams(dq_max=joint_speed_limits(),
                                   **{n: _core_value(n, values[n]) for n in _CORE_PARAMS})
        self._intrinsics: tuple[float, float, float, float] | None = None
        self._image_size: tuple[int, int] | None = None  # from camera_info, for vision_msgs detections
        self._kin = _panda_kinematics(self.get_logger())
        self.core = TeleopCore(
            self.params, kinematics=self._kin, joint_names=JOINT_NAMES, ee_pixel=self._ee_pixel,
            joint_map=parse_joint_map(values["joint_map"]), camera=self._camera,
        )
        self._image_sub = None  # camera/image_raw, for a CNN-encoder model only
        self._start_model(values["model_path"], values["mode"])
        reason = goal_refusal(values["goal_selection"], self.core.model)
        if reason:
            raise ConfigError(f"parameter 'goal_selection': {reason}")
        self._msg = Float64MultiArray()
        self._last_status: tuple | None = None
        self._status_log = StatusLog()
        # in integer ns: a float period's rounding would depend on how long the node has run (issue 33)
        self._last_status_ns: int | None = None
        self._status_period_ns = round(1e9 / values["status_rate"])
        self._lockstep = LockstepInputs() if values["lockstep"] else None
        self._episode_clock = EpisodeClock()   # lockstep: the core's seconds, counted from the last re-latch
        self._step_ns: int | None = None   # lockstep: the step being computed or last answered
        self._answer: StepAnswer | None = None   # lockstep: the last answer (sent again on a repeat)
        self._create_interfaces()
        if self._lockstep is None:
            self.timer = self.create_timer(1.0 / values["rate"], self._tick)
            pace = f"{values['rate']:g} Hz"
        else:
            self._pending_since: float | None = None
            self.create_timer(1.0, self._lockstep_watch, clock=Clock(clock_type=ClockType.STEADY_TIME))
            pace = "lockstep (a command per joint state)"
        m = self.core.model
        what = f"{m.encoder} model from {m.artifacts.path}" if m is not None else "no model"
        mapped = f", joint_map {self.core.joint_map}" if self.core.joint_map else ""
        self.get_logger().info(f"mode {self.core.mode}, {what}, {pace}{mapped}")

    def _create_interfaces(self) -> None:
        self.cmd_pub = self.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        self.status_pub = self.create_publisher(ControllerStatus, "~/status", 10)
        self.answer_pub = (self.create_publisher(StepAnswer, "lockstep/answer", LOCKSTEP_QOS)
                           if self._lockstep is not None else None)
        self.diagnostics = Diagnostics(self)
        sensor = qos_profile_sensor_data if self._lockstep is None else LOCKSTEP_QOS
        self.create_subscription(Joy, "joy", self._on_joy, sensor)
        self.create_subscription(JointState, "joint_states", self._on_joint_states, sensor)
        self.create_subscription(DetectionArray, "detections", self._on_detections, sensor)
        if vision.AVAILABLE:  # any vision_msgs detector (yolo_ros, ...) as an alternative input
            self.create_subscription(vision.Detection2DArray, "detections" + vision.TOPIC_SUFFIX,
                                     self._on_detections_2d, sensor)
        self.create_subscription(CameraInfo, "camera/camera_info", self._on_camera_info, sensor)
        self.create_service(SetMode, "~/set_mode", self._on_set_mode)
        self.create_service(Trigger, "~/redetect", self._on_redetect)
        self.create_service(SelectTarget, "~/select_target", self._on_select_target)
        self._gripper = self.create_client(GripperCommand, self.get_parameter("gripper_service").value)
        self._grasp_presses = 0

    # ------------------------------------------------------------------ parameters and model
    def _on_parameter(self, name: str, value: Any) -> str | None:
        """Apply one run-time parameter change, or return why it is refused."""
        if name == "goal_selection":
            reason = goal_refusal(value, self.core.model)
            if reason:
                return reason
        if name in _CORE_PARAMS:
            setattr(self.params, name, _core_value(name, value))
            self.core.sync_params()
        if name == "mode":
            self._new_episode()   # set for every trial; an end-effector trial has no re-latch
            self.core.set_mode(value)
        elif name == "model_path":
            return self._reload_model(value)
        elif name == "joint_map":
            self.core.set_joint_map(parse_joint_map(value))
        elif name == "status_rate":
            self._status_period_ns = round(1e9 / float(value))
        return None

    def _start_model(self, path: str, mode: str) -> None:
        """Load the model at startup; StartupError when it does not load (a launch must not run on with
        a controller that can only command zero). End-effector mode may start without one."""
        path = path or default_model_path()
        if not path:
            if mode == "latent":
                raise StartupError("no model: set model_path to a trained model directory")
            self.core.set_model(None, "no model: set the model_path parameter to a trained model directory")
            return
        try:
            self._use_model(LatentModel.load(path))
        except (ModelError, OSError, ValueError) as e:
            raise StartupError(f"cannot load model {path!r}: {e}") from None

    def _reload_model(self, path: str) -> str | None:
        """Switch to the model at `path`, or keep the current one and return why not."""
        path = path or default_model_path()
        if not path:
            return "no model to load: empty model_path and no shipped default installed"
        try:
            model = LatentModel.load(path)
        except (ModelError, OSError, ValueError) as e:
            self.get_logger().error(f"model_path refused, keeping the current model: {e}")
            return f"cannot load model {path!r}: {e}"
        reason = goal_refusal(self.params.goal_selection, model)
        if reason:
            return f"the model at {path!r} does not fit goal_selection: {reason}"
        self._use_model(model)
        return None

    def _use_model(self, model: LatentModel) -> None:
        self.core.set_model(model)
        self._update_image_subscription()
        self.get_logger().info(
            f"model {model.artifacts.path}: encoder {model.encoder}, classes {model.classes}, "
            f"joints {list(model.joint_names)}, trained on "
            f"{model.config.get('training', {}).get('demos', '?')} demos"
        )

    def _update_image_subscription(self) -> None:
        m = self.core.model
        if m is not None and m.encoder in CNN_ENCODERS and self._image_sub is None:
            self._image_sub = self.create_subscription(
                Image, "camera/image_raw", self._on_image, IMAGE_QOS
            )

    # ------------------------------------------------------------------ lockstep
    def _lockstep_try(self) -> None:
        """Compute and answer the pending step once everything it needs is in (module lockstep)."""
        ls = self._lockstep
        if ls.state is not None and self._pending_since is None:
            self._pending_since = time.monotonic()
        if ls.missing(self._wanted_ns()) is not None:
            return
        t_ns, msg, due = ls.take()
        self._step_ns, self._pending_since = t_ns, None
        for kind, stamp, value in due:
            t = self._episode_clock.seconds(stamp)
            if kind == JOY:
                self._joy_to_core(value, t)
            elif kind == DETECTIONS:
                self.core.on_detections(*value, t)
            elif kind == IMAGE:
                self.core.on_image(value, t)
        self.core.on_joint_states(msg.name, msg.position, self._episode_clock.seconds(t_ns))
        cmd = self._tick()
        self._answer = StepAnswer(header=msg.header, node=self.get_name(), command=cmd)
        self.answer_pub.publish(self._answer)

    def _wanted_ns(self) -> int | None:
        """The stamp from which the pending step needs every frame's detections (core.detection_wanted),
        or None: it needs none, or was never asked to re-latch (startup: it latches what comes)."""
        state = self._lockstep.state
        if state is None:
            return None
        since = self.core.detection_wanted(self._episode_clock.seconds(state[0]))
        return None if since is None or since == -math.inf else self._episode_clock.stamp_ns(since)

    def _lockstep_watch(self) -> None:
        """Steady clock, 1 Hz: say what a step has waited for this long (a hang is the bridge's to report;
        this only says why, and reads the wall clock for nothing else)."""
        ls, since = self._lockstep, self._pending_since
        if since is not None and time.monotonic() - since > LOCKSTEP_WARN_S and ls.state is not None:
            self.get_logger().warn(f"lockstep: the joint state stamped {ls.state[0]} ns has waited "
                                   f"{time.monotonic() - since:.0f} s for {ls.missing(self._wanted_ns())}",
                                   throttle_duration_sec=LOCKSTEP_WARN_S)

    # ------------------------------------------------------------------ inputs
    def _now(self) -> float:
        """The core's time (s); in lockstep the step's (its joint state's stamp, whatever /clock says
        yet) on the episode's clock (lockstep.EpisodeClock)."""
        if self._step_ns is not None:
            return self._episode_clock.seconds(self._step_ns)
        return self.get_clock().now().nanoseconds * 1e-9

    def _now_ns(self) -> int:
        return self._step_ns if self._step_ns is not None else self.get_clock().now().nanoseconds

    def _new_episode(self) -> float:
        """A re-latch or a mode set starts an episode: in lockstep the core's clock counts from this
        step on (every time it keeps mapped exactly), so an episode's times are the same floats whatever
        the graph ran before. An end-effector trial sets the mode and never re-latches: on the last
        latent trial's origin, a press 0.25 s after the last switch fell either side of the debounce
        with the trial before it (a study row on Ray unlike the serial one under load). The time (s)
        to give the core."""
        if self._step_ns is not None:
            self.core.restamp(self._episode_clock.restart(self._step_ns))
        return self._now()

    def _input_time(self) -> float | None:
        """The receive time of an input, or None under sim time before the first /clock: an input
        stamped 0 would read as decades old once the clock starts."""
        now = self._now()
        return now if now > 0.0 else None

    def _on_joy(self, msg: Joy) -> None:
        if self._lockstep is not None:
            self._lockstep.on_joy(ns_from_stamp(msg.header.stamp), msg)
            self._lockstep_try()
            return
        if (now := self._input_time()) is None:
            return
        before = self.core.stick_code(now)
        self._joy_to_core(msg, now)
        if self.core.stick_code(now) != before:
            self._tick()   # a press, a release or the input back after a timeout: its command now, not
            #                up to a period later (the operator station's key -> command latency)

    def _joy_to_core(self, msg: Joy, now: float) -> None:
        self.core.on_joy(msg.axes, msg.buttons, now)
        if self.core.grasp_presses != self._grasp_presses:    # one toggle per press; the bridge
            self._grasp_presses = self.core.grasp_presses      # refuses presses too close together
            self._toggle_hand()

    def _toggle_hand(self) -> None:
        if not self._gripper.service_is_ready():
            self.get_logger().warn(f"grasp button: {self._gripper.srv_name} is not available",
                                   throttle_duration_sec=2.0)
            return
        future = self._gripper.call_async(GripperCommand.Request(command=GripperCommand.Request.TOGGLE))
        future.add_done_callback(self._on_toggle_reply)

    def _on_toggle_reply(self, future) -> None:
        res = future.result()
        if res is None:
            return
        if res.success:
            self.get_logger().info(f"grasp button: {res.message}")
        else:
            self.get_logger().warn(f"grasp button refused: {res.message}", throttle_duration_sec=1.0)

    def _on_joint_states(self, msg: JointState) -> None:
        if self._lockstep is not None:
            if self._lockstep.on_state(ns_from_stamp(msg.header.stamp), msg) and self._answer is not None:
                self.answer_pub.publish(self._answer)      # the same answer again
            self._lockstep_try()
            return
        if (now := self._input_time()) is not None:
            self.core.on_joint_states(msg.name, msg.position, now)

    def _on_detections(self, msg: DetectionArray) -> None:
        if self._lockstep is not None:
            self._lockstep.on_detections(ns_from_stamp(msg.header.stamp), detections_from_array(msg))
            self._lockstep_try()
        elif (now := self._input_time()) is not None:
            dets, size = detections_from_array(msg)
            self.core.on_detections(dets, size, now)

    def _on_detections_2d(self, msg) -> None:
        """vision_msgs/Detection2DArray: it carries no image size, so camera_info's is used."""
        if self._image_size is None:
            self.get_logger().warn("vision_msgs detections ignored until camera/camera_info gives the "
                                   "image size", throttle_duration_sec=5.0)
            return
        classes = list(self.core.model.classes) if self.core.model is not None else []
        if self._lockstep is not None:
            dets = vision.from_detection2d_array(msg, classes)
            self._lockstep.on_detections(ns_from_stamp(msg.header.stamp), (dets, self._image_size))
            self._lockstep_try()
        elif (now := self._input_time()) is not None:
            self.core.on_detections(vision.from_detection2d_array(msg, classes), self._image_size, now)

    def _on_image(self, msg: Image) -> None:
        try:
            rgb = to_rgb(msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian))
        except ValueError as e:
            self.get_logger().warn(f"camera image ignored: {e}", throttle_duration_sec=5.0)
            return
        if self._lockstep is not None:
            self._lockstep.on_image(ns_from_stamp(msg.header.stamp), rgb)
        elif (now := self._input_time()) is not None:
            self.core.on_image(rgb, now)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        if self._lockstep is not None:
            self._lockstep.on_frame(ns_from_stamp(msg.header.stamp))   # its detections will follow
        k = msg.k
        if msg.width > 0 and msg.height > 0:
            self._image_size = (int(msg.width), int(msg.height))
        if k[0] > 0 and k[4] > 0:
            self._intrinsics = (k[0], k[4], k[2], k[5])

    def _ee_pixel(self, q: np.ndarray) -> tuple[float, float] | None:
        pos = self.get_parameter("camera_position").value
        target = self.get_parameter("camera_look_at").value
        if self._intrinsics is None or self._kin is None or np.allclose(pos, target):
            return None
        rot = look_at_rotation(np.asarray(pos), np.asarray(target))
        return project(self._kin.fk(q)[0], pos, rot, self._intrinsics)

    def _camera(self) -> PinholeCamera | None:
        """The detector's camera, once camera_info has given its intrinsics (for the assistance)."""
        pos = self.get_parameter("camera_position").value
        target = self.get_parameter("camera_look_at").value
        if self._intrinsics is None or np.allclose(pos, target):
            return None
        return PinholeCamera(np.asarray(pos, float), look_at_rotation(np.asarray(pos), np.asarray(target)),
                             self._intrinsics)

    def _on_set_mode(self, req: SetMode.Request, resp: SetMode.Response) -> SetMode.Response:
        """Through the `mode` parameter, so that it always reads the mode in use."""
        if req.mode not in MODES:
            resp.success, resp.message = False, f"unknown mode {req.mode!r}; expected one of {MODES}"
            return resp
        result = self.set_parameters([Parameter("mode", value=req.mode)])[0]
        resp.success = result.successful
        resp.message = f"mode {req.mode}" if result.successful else result.reason
        return resp

    def _on_redetect(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.core.request_redetect(self._new_episode())
        resp.success, resp.message = True, "context dropped; the next detection will be latched"
        return resp

    def _on_select_target(self, req: SelectTarget.Request, resp: SelectTarget.Response):
        resp.success, resp.message = self.core.select_target(
            req.by, req.class_id, int(req.index), float(req.x), float(req.y), self._new_episode())
        return resp

    # ------------------------------------------------------------------ loop
    def _tick(self) -> list[float]:
        """One command (published on joint_velocity_cmd, or returned for the lockstep answer) and the
        status: at status_rate, and at once when what it says changes (code, mode, end-effector axis,
        latched object, the assistance's level, inferred goal and the pose it steers toward)."""
        now, now_ns = self._now(), self._now_ns()
        cmd, st = self.core.step(now)
        values = cmd.tolist()
        if self._lockstep is None:
            self._msg.data = values
            self.cmd_pub.publish(self._msg)
        said = (st.code, st.mode, st.ee_axis, st.latched_class, st.latched_by, st.assist.level,
                st.assist.goal_task, st.assist.stage)
        changed = said != self._last_status
        last = self._last_status_ns
        if changed or last is None or not 0 <= now_ns - last < self._status_period_ns:
            code_changed = self._last_status is None or st.code != self._last_status[0]
            level = self._status_log.level(st.code) if code_changed else None
            text = f"zero command: {st.code.name}: {st.reason}"
            if level == "info":        # a routine code, the first time (status_log.py)
                self.get_logger().info(text)
            elif level == "problem":
                self.get_logger().info(text, throttle_duration_sec=2.0)
            elif level == "debug":     # a routine code again
                self.get_logger().debug(text)
            self._last_status = said
            self._last_status_ns = now_ns
            self.status_pub.publish(self._status_msg(st))
            level = "ok" if st.code == Code.ACTIVE or st.code in NEUTRAL_CODES else "warn"
            self.diagnostics.update(level, st.reason or st.code.name, mode=st.mode, code=st.code.name,
                                    latched_class=st.latched_class)
        return values

    def _status_msg(self, st: Status) -> ControllerStatus:
        m = ControllerStatus()
        m.header.stamp = (stamp_from_ns(self._step_ns) if self._step_ns is not None
                          else self.get_clock().now().to_msg())
        m.header.frame_id = BASE_FRAME  # the status holds no geometry; the robot's base frame
        m.mode, m.code, m.reason = st.mode, int(st.code), st.reason
        m.latched_class = st.latched_class
        m.latched_by = st.latched_by
        m.latched_x, m.latched_y = float(st.latched_x), float(st.latched_y)
        m.z, m.ee_axis = float(st.z), st.ee_axis
        m.command = [float(v) for v in st.command]
        a = st.assist
        m.assistance, m.goal_task, m.goal_stage = a.level, a.goal_task, a.stage
        m.goal_confidence, m.goal_share = float(a.confidence), float(a.share)
        m.goal_x, m.goal_y = (float(v) for v in a.goal_xy)
        m.goal_image_x, m.goal_image_y = (float(v) for v in a.goal_image_xy)
        return m

    def on_shutdown(self, ack_timeout: float = 1.0) -> bool:
        """Publish the zero command and wait (bounded) until the reliable subscribers have it: the
        process exits right after, and a sample still in the writer's queue would die with it."""
        self._msg.data = [0.0] * len(self.core.command_joints or self.core.joint_names)
        self.cmd_pub.publish(self._msg)
        return self.cmd_pub.wait_for_all_acked(Duration(seconds=ack_timeout))


def main(args: list[str] | None = None) -> int:
    return run_node(ControllerNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())

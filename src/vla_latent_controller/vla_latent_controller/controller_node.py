"""controller_node: joystick → joint velocities through the learned latent-action decoder (or the paper's
end-effector baseline). A thin ROS wrapper around :class:`vla_latent_controller.teleop.TeleopCore`:
inputs are stored as they arrive, a fixed-rate timer computes and publishes the command, and every
problem becomes a zero command plus a status saying why.
"""

from __future__ import annotations

import math
import signal
import sys
from pathlib import Path

import numpy as np
import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, Image, JointState, Joy
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from vla_common.camera_model import SIM_WEBCAM, look_at_rotation, project

from vla_interfaces.msg import ControllerStatus, DetectionArray
from vla_interfaces.srv import SetMode
from vla_latent_controller.artifacts import ModelError
from vla_latent_controller.context import CNN_ENCODERS, GOAL_SELECTIONS, Det
from vla_latent_controller.teleop import MODES, Code, TeleopCore, TeleopParams

NODE_NAME = "controller_node"

# (name, default, description, range (lo, hi) or None); ranges become descriptor ranges.
_DOUBLES = [
    ("rate", 100.0, "command publish rate (Hz); read-only", (1.0, 1000.0)),
    (
        "axis_scale",
        1.0,
        "stick multiplier (negative inverts); the result is clamped to [-1, 1]",
        (-10.0, 10.0),
    ),
    (
        "deadband",
        0.1,
        "|stick| at or below this gives exactly zero; rescaled beyond so it stays continuous",
        (0.0, 0.95),
    ),
    ("joy_timeout", 0.1, "no joy message for this long (s) → zero command", (0.01, 10.0)),
    ("action_scale", 1.0, "decoder output → rad/s multiplier", (0.0, 10.0)),
    ("max_joint_speed", 1.5, "joint-velocity norm clamp (rad/s), direction kept; paper: 1.5", (0.0, 5.0)),
    ("ee_debounce", 0.25, "end-effector axis button debounce (s)", (0.0, 5.0)),
    ("ee_linear_speed", 0.2, "end-effector mode: TCP speed at full stick (m/s); paper: 0.5", (0.0, 1.7)),
    ("ee_angular_speed", 0.5, "end-effector mode: rotation speed at full stick (rad/s)", (0.0, 2.5)),
    ("ee_damping", 0.05, "damping of the Jacobian pseudo-inverse", (0.0, 1.0)),
    (
        "detection_max_age",
        0.0,
        "re-latch when the latched detection is older (s); 0: latch once (paper)",
        (0.0, 86400.0),
    ),
    ("joint_states_timeout", 0.5, "no joint_states for this long (s) → zero command", (0.01, 10.0)),
    ("status_rate", 10.0, "~/status publish rate (Hz); also published on every status change", (0.1, 1000.0)),
]
_INTS = [
    ("axis", 0, "joystick axis that drives the latent action (or the end-effector axis)", (0, 63)),
    ("enable_button", -1, "deadman button that must be held; -1: none", (-1, 63)),
    ("redetect_button", -1, "button that re-latches the context from the next detection; -1: none", (-1, 63)),
    (
        "ee_mode_button",
        0,
        "button that cycles the end-effector axis x, y, z, roll, pitch, yaw; -1: none",
        (-1, 63),
    ),
]
_STRINGS = [
    (
        "model_path",
        "",
        "trained model directory (config.json + model.safetensors); empty: the shipped default",
    ),
    ("mode", "latent", "latent or end_effector (also ~/set_mode)"),
    (
        "goal_selection",
        "highest_score",
        "which detection is the goal: highest_score, nearest_to_ee or a class",
    ),
]
_ARRAYS = [
    (
        "camera_position",
        "camera optical centre in the world (m), for nearest_to_ee; default: the simulated webcam",
    ),
    ("camera_look_at", "point the camera looks at (m), for nearest_to_ee; default: the simulated webcam's"),
]
_TUNABLE = {n for n, *_ in _DOUBLES + _INTS} - {"rate", "status_rate"} | {"goal_selection"}


def default_model_path() -> str:
    """share/vla_latent_controller/models/default if a model is installed there, else ''."""
    try:
        from ament_index_python.packages import get_package_share_directory

        p = Path(get_package_share_directory("vla_latent_controller")) / "models" / "default"
        return str(p) if (p / "config.json").is_file() else ""
    except Exception:
        return ""


def _sim_camera() -> dict[str, list[float]]:
    """The simulated webcam's pose, the default camera for nearest_to_ee (set a real camera's pose)."""
    return {
        "camera_position": [float(v) for v in SIM_WEBCAM.position],
        "camera_look_at": [float(v) for v in SIM_WEBCAM.look_at],
    }


class ControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        for name, default, text, rng in _DOUBLES:
            d = ParameterDescriptor(description=text, read_only=name == "rate")
            d.floating_point_range = [FloatingPointRange(from_value=rng[0], to_value=rng[1], step=0.0)]
            self.declare_parameter(name, default, d)
        for name, default, text, rng in _INTS:
            d = ParameterDescriptor(description=text)
            d.integer_range = [IntegerRange(from_value=rng[0], to_value=rng[1], step=1)]
            self.declare_parameter(name, default, d)
        for name, default, text in _STRINGS:
            self.declare_parameter(name, default, ParameterDescriptor(description=text))
        sim_camera = _sim_camera()
        for name, text in _ARRAYS:
            default = sim_camera[name]
            self.declare_parameter(
                name,
                default,
                ParameterDescriptor(description=text, type=ParameterType.PARAMETER_DOUBLE_ARRAY),
            )

        from vla_common.robot import DQ_MAX, JOINT_NAMES

        self.params = TeleopParams(dq_max=list(DQ_MAX))
        self._apply(self.get_parameters([n for n in _TUNABLE] + ["mode"]))
        self._intrinsics: tuple[float, float, float, float] | None = None
        self._kin = None
        try:
            from vla_common.kinematics import PandaKinematics

            self._kin = PandaKinematics()
        except Exception as e:  # end-effector mode reports it; latent mode does not need it
            self.get_logger().warn(f"Panda kinematics unavailable ({e}); end_effector mode disabled")
        self.core = TeleopCore(
            self.params, kinematics=self._kin, joint_names=JOINT_NAMES, ee_pixel=self._ee_pixel
        )
        self._load_model(self.get_parameter("model_path").value)

        self.cmd_pub = self.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        self.status_pub = self.create_publisher(ControllerStatus, "~/status", 10)
        self.create_subscription(Joy, "joy", self._on_joy, qos_profile_sensor_data)
        self.create_subscription(JointState, "joint_states", self._on_joint_states, qos_profile_sensor_data)
        self.create_subscription(DetectionArray, "detections", self._on_detections, qos_profile_sensor_data)
        self.create_subscription(
            CameraInfo, "camera/camera_info", self._on_camera_info, qos_profile_sensor_data
        )
        self._image_sub = None
        self._update_image_subscription()
        self.create_service(SetMode, "~/set_mode", self._on_set_mode)
        self.create_service(Trigger, "~/redetect", self._on_redetect)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._msg = Float64MultiArray()
        self._last_code: int | None = None
        self._last_status_t = -math.inf
        self._status_period = 1.0 / float(self.get_parameter("status_rate").value)
        self.timer = self.create_timer(1.0 / float(self.get_parameter("rate").value), self._tick)
        m = self.core.model
        what = f"{m.encoder} model from {m.artifacts.path}" if m is not None else "no model"
        self.get_logger().info(f"mode {self.core.mode}, {what}, {self.get_parameter('rate').value:g} Hz")

    # ------------------------------------------------------------------ parameters and model
    def _apply(self, params) -> str | None:
        """Copy parameters into the core's TeleopParams after checking them; a reason on rejection."""
        new = {p.name: p.value for p in params}
        if "mode" in new and new["mode"] not in MODES:
            return f"mode must be one of {MODES}"
        gs = new.get("goal_selection")
        if gs is not None and not gs:
            return f"goal_selection must be one of {GOAL_SELECTIONS} or a class name"
        for name, value in new.items():
            if hasattr(self.params, name):
                setattr(self.params, name, value)
        return None

    def _load_model(self, path: str) -> None:
        from vla_latent_controller.model import LatentModel

        path = path or default_model_path()
        if not path:
            self.core.set_model(None, "no model: set the model_path parameter to a trained model directory")
            self.get_logger().warn("no model_path set: latent mode will command zero (MODEL_ERROR)")
            return
        try:
            model = LatentModel.load(path)
        except (ModelError, OSError, ValueError) as e:
            self.core.set_model(None, f"cannot load model: {e}")
            self.get_logger().error(f"cannot load model {path!r}: {e}")
            return
        self.core.set_model(model)
        self.get_logger().info(
            f"model {path}: encoder {model.encoder}, classes {model.classes}, "
            f"trained on {model.config.get('training', {}).get('demos', '?')} demos"
        )

    def _update_image_subscription(self) -> None:
        m = self.core.model
        if m is not None and m.encoder in CNN_ENCODERS and self._image_sub is None:
            self._image_sub = self.create_subscription(
                Image, "camera/image_raw", self._on_image, qos_profile_sensor_data
            )

    def _on_set_parameters(self, params) -> SetParametersResult:
        for p in params:
            if p.name == "rate":
                return SetParametersResult(successful=False, reason="rate is read-only")
        reason = self._apply([p for p in params if p.name in _TUNABLE or p.name == "mode"])
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        self.core.sync_params()
        for p in params:
            if p.name == "mode":
                self.core.set_mode(p.value)
            elif p.name == "model_path":
                self._load_model(p.value)
                self._update_image_subscription()
            elif p.name == "status_rate":
                self._status_period = 1.0 / float(p.value)
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ inputs
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_joy(self, msg: Joy) -> None:
        self.core.on_joy(msg.axes, msg.buttons, self._now())

    def _on_joint_states(self, msg: JointState) -> None:
        self.core.on_joint_states(msg.name, msg.position, self._now())

    def _on_detections(self, msg: DetectionArray) -> None:
        dets = [
            Det(d.class_id, d.score, d.center_x, d.center_y, d.size_x, d.size_y, d.class_index)
            for d in msg.detections
        ]
        self.core.on_detections(dets, (int(msg.image_width), int(msg.image_height)), self._now())

    def _on_image(self, msg: Image) -> None:
        from vla_common.image_convert import to_rgb

        try:
            rgb = to_rgb(msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian))
        except ValueError as e:
            self.get_logger().warn(f"camera image ignored: {e}", throttle_duration_sec=5.0)
            return
        self.core.on_image(rgb, self._now())

    def _on_camera_info(self, msg: CameraInfo) -> None:
        k = msg.k
        if k[0] > 0 and k[4] > 0:
            self._intrinsics = (k[0], k[4], k[2], k[5])

    def _ee_pixel(self, q: np.ndarray) -> tuple[float, float] | None:
        pos = self.get_parameter("camera_position").value
        target = self.get_parameter("camera_look_at").value
        if self._intrinsics is None or self._kin is None or len(pos) != 3 or len(target) != 3:
            return None
        if np.allclose(pos, target):
            return None
        rot = look_at_rotation(np.asarray(pos), np.asarray(target))
        return project(self._kin.fk(q)[0], pos, rot, self._intrinsics)

    def _on_set_mode(self, req: SetMode.Request, resp: SetMode.Response) -> SetMode.Response:
        ok, text = self.core.set_mode(req.mode)
        if ok:
            self.params.mode = req.mode
        resp.success, resp.message = ok, text
        return resp

    def _on_redetect(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.core.request_redetect(self._now())
        resp.success, resp.message = True, "context dropped; the next detection will be latched"
        return resp

    # ------------------------------------------------------------------ loop
    def _tick(self) -> None:
        now = self._now()
        cmd, st = self.core.step(now)
        self._msg.data = cmd.tolist()
        self.cmd_pub.publish(self._msg)
        if (
            st.code != self._last_code
            or now - self._last_status_t >= self._status_period
            or now < self._last_status_t
        ):
            if st.code != self._last_code and st.code not in (Code.ACTIVE, Code.ZERO_DEADBAND):
                self.get_logger().info(
                    f"zero command: {st.code.name}: {st.reason}", throttle_duration_sec=2.0
                )
            self._last_code = st.code
            self._last_status_t = now
            self.status_pub.publish(self._status_msg(st))

    def _status_msg(self, st) -> ControllerStatus:
        m = ControllerStatus()
        m.header.stamp = self.get_clock().now().to_msg()
        m.header.frame_id = "world"
        m.mode, m.code, m.reason = st.mode, int(st.code), st.reason
        m.latched_class = st.latched_class
        m.latched_x, m.latched_y = float(st.latched_x), float(st.latched_y)
        m.z, m.ee_axis = float(st.z), st.ee_axis
        m.command = [float(v) for v in st.command]
        return m

    def publish_zero(self, ack_timeout: float = 1.0) -> bool:
        """Publish the zero command and wait (bounded) until the reliable subscribers have it: the
        process exits right after, and a sample still in the writer's queue would die with it."""
        self._msg.data = [0.0] * len(self.core.joint_names)
        self.cmd_pub.publish(self._msg)
        return self.cmd_pub.wait_for_all_acked(Duration(seconds=ack_timeout))


def main(args=None) -> int:
    # Our own signal handling: rclpy's would invalidate the context before the zero command goes out.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    node = None
    try:
        node = ControllerNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        try:
            if node is not None:
                if rclpy.ok():
                    node.publish_zero()
                node.destroy_node()
            if rclpy.ok():
                rclpy.shutdown()
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())

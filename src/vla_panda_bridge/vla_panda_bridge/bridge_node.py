"""`panda_bridge`: the robot side of the project as one ROS 2 node.

Takes joint-velocity commands on `joint_velocity_cmd`, runs every control period through the
SafetyFilter, and drives either the MuJoCo-simulated Panda (default; stepped here in fixed physics
increments that equal the filter's period, paced to `real_time_factor`, publishing /clock) or a
ros2_control arm (filtered command forwarded to a JointGroupVelocityController, its joint states
relayed). Publishes joint_states, ee_pose, ~/status, and for the simulation the camera and the
ground-truth scene; serves ~/reset and ~/estop. A thin wrapper: the algorithms live in safety.py,
sim_clock.py, sim.py and kinematics.py.
"""

from __future__ import annotations

import math
import signal
import sys
import time

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, PoseStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool
from vla_common.objects import ObjectPose
from vla_common.robot import JOINT_NAMES, NUM_JOINTS, Q_MAX, Q_MIN, READY_POSE
from vla_sim.sim_clock import SimPacer

from vla_interfaces.msg import SafetyStatus, SceneObject, SceneObjectArray
from vla_interfaces.srv import ResetScene
from vla_panda_bridge import safety
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

BACKENDS = ("mujoco", "ros2_control")
EE_FRAMES = ("tcp", "flange")
MAX_CAMERA_SIZE = (1920, 1440)
STATE_QOS_DEPTH = 2000  # joint_states / ee_pose history (see where the publishers are made)
_NO_STATE = np.full(NUM_JOINTS, np.nan)  # scene.MAX_OFFSCREEN (the offscreen buffer)


class ConfigError(ValueError):
    """A parameter value the node refuses at startup."""


def _desc(
    text: str, *, float_range: tuple[float, float] | None = None, int_range: tuple[int, int] | None = None,
    choices: tuple[str, ...] | None = None,
) -> ParameterDescriptor:
    d = ParameterDescriptor(description=text, read_only=True)
    if choices is not None:
        d.additional_constraints = "one of: " + ", ".join(choices)
    if float_range is not None:
        d.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]))
        ]
    if int_range is not None:
        d.integer_range = [IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]))]
    return d


PARAMETERS: dict[str, tuple[object, ParameterDescriptor]] = {
    "backend": (
        "mujoco",
        _desc(
            "Robot behind the safety layer: 'mujoco' (simulated Panda) or "
            "'ros2_control' (JointGroupVelocityController)",
            choices=BACKENDS,
        ),
    ),
    "control_rate": (
        1000,
        _desc(
            "Safety filter + command updates per second; with mujoco also the "
            "physics rate (one filter update per physics step)",
            int_range=(100, 4000),
        ),
    ),
    "state_rate": (
        200.0,
        _desc(
            "joint_states and ee_pose publish rate (Hz; simulated time with mujoco)",
            float_range=(1.0, 1000.0),
        ),
    ),
    "real_time_factor": (
        1.0,
        _desc("mujoco: simulated seconds per wall second; 0 = as fast as possible", float_range=(0.0, 100.0)),
    ),
    "publish_clock": (True, _desc("mujoco: publish /clock so nodes with use_sim_time follow the simulation")),
    "camera_rate": (
        30.0,
        _desc("mujoco: camera/image_raw rate in simulated Hz (0 = camera off)", float_range=(0.0, 120.0)),
    ),
    "camera_width": (640, _desc("mujoco: image width (px)", int_range=(16, MAX_CAMERA_SIZE[0]))),
    "camera_height": (480, _desc("mujoco: image height (px)", int_range=(16, MAX_CAMERA_SIZE[1]))),
    "scene_rate": (
        10.0,
        _desc(
            "mujoco: scene/objects (ground truth) rate in simulated Hz (0 = only after a reset)",
            float_range=(0.0, 100.0),
        ),
    ),
    "seed": (0, _desc("mujoco: seed of the initial random object layout", int_range=(0, 2**31 - 1))),
    "initial_positions": (list(READY_POSE), _desc("mujoco: initial joint positions (7, rad)")),
    "base_frame_id": ("panda_link0", _desc("frame_id of ee_pose and scene/objects (the robot base)")),
    "ee_frame": ("tcp", _desc("ee_pose of the 'tcp' (between the closed finger tips) or the 'flange'",
                              choices=EE_FRAMES)),
    "command_timeout": (
        0.1,
        _desc(
            "Watchdog: brake to zero after this long without a valid command (s)", float_range=(0.001, 10.0)
        ),
    ),
    "position_margin": (
        0.1,
        _desc("Distance kept from every joint position limit (rad)", float_range=(0.0, 0.5)),
    ),
    "velocity_scale": (1.0, _desc("Fraction of the Panda's dq_max allowed", float_range=(0.01, 1.0))),
    "acceleration_scale": (1.0, _desc("Fraction of the Panda's ddq_max allowed", float_range=(0.01, 1.0))),
    "jerk_scale": (1.0, _desc("Fraction of the Panda's dddq_max allowed", float_range=(0.01, 1.0))),
    "position_sync_tolerance": (
        0.05,
        _desc(
            "Re-sync the integrated reference to the measured position beyond this drift (rad)",
            float_range=(0.001, 1.0),
        ),
    ),
    "status_rate": (
        1.0,
        _desc(
            "~/status rate when nothing happens (Hz); interventions publish at once", float_range=(0.1, 100.0)
        ),
    ),
    "command_topic": (
        "/joint_velocity_controller/commands",
        _desc("ros2_control: JointGroupVelocityController command topic"),
    ),
    "robot_joint_states_topic": ("/joint_states", _desc("ros2_control: the arm's sensor_msgs/JointState")),
    "state_timeout": (
        0.25,
        _desc(
            "ros2_control: brake when the arm's joint state is older than this (s)", float_range=(0.01, 10.0)
        ),
    ),
}


def _stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _quat_wxyz(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> unit quaternion (w, x, y, z) (Shepperd's method)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


class PandaBridge(Node):
    """See the module docstring and README.md (topics, parameters, services, safety behaviour)."""

    def __init__(self, **kwargs):
        super().__init__("panda_bridge", **kwargs)
        p = self._declare_parameters()
        self._validate(p)
        self.params = p
        self.filter = SafetyFilter(
            SafetyConfig(
                dt=1.0 / p["control_rate"],
                velocity_scale=p["velocity_scale"],
                acceleration_scale=p["acceleration_scale"],
                jerk_scale=p["jerk_scale"],
                position_margin=p["position_margin"],
                command_timeout=p["command_timeout"],
                position_sync_tolerance=p["position_sync_tolerance"],
            )
        )
        self._dt = 1.0 / p["control_rate"]
        self._base_frame = p["base_frame_id"]
        from vla_common.kinematics import PandaKinematics  # Pinocchio: import only when needed

        self._kin = PandaKinematics()
        self._fk = self._kin.fk if p["ee_frame"] == "tcp" else self._kin.flange_fk

        # A deep history: a reliable reader that stalls (a recorder behind a simulation running faster
        # than real time on a loaded machine) gets the states late instead of losing them. 200 lost
        # seconds of states with two training jobs on the same 2 cores; 2000 (~0.6 MB) is 10 s at 200 Hz.
        state_qos = QoSProfile(depth=STATE_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._js_pub = self.create_publisher(JointState, "joint_states", state_qos)
        self._ee_pub = self.create_publisher(PoseStamped, "ee_pose", state_qos)
        self._status_pub = self.create_publisher(SafetyStatus, "~/status", 10)
        self.create_subscription(Float64MultiArray, "joint_velocity_cmd", self._on_command, 10)
        self.create_service(SetBool, "~/estop", self._on_estop)
        self.create_service(ResetScene, "~/reset", self._on_reset)
        self._published_code = -1
        self._status_text = ""
        self._published_rejected = 0
        self.states_published = 0
        self._mj = None
        self._rc = None
        self._camera = None
        self._closed = False
        if p["backend"] == "mujoco":
            self._setup_mujoco(p)
        else:
            self._setup_ros2_control(p)
        self.create_timer(1.0 / p["status_rate"], self._publish_status)
        self._publish_status()

    # ------------------------------------------------------------------------------------ parameters
    def _declare_parameters(self) -> dict:
        overrides = getattr(self, "_parameter_overrides", {})
        values = {}
        for name, (default, descriptor) in PARAMETERS.items():
            # YAML/CLI "state_rate: 500" is an integer; accept it for a floating-point parameter.
            given = overrides.get(name)
            if isinstance(default, float) and given is not None and given.type_ == Parameter.Type.INTEGER:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(given.value))
            try:
                values[name] = self.declare_parameter(name, default, descriptor).value
            except Exception as exc:  # out of range / wrong type from overrides: refuse clearly
                raise ConfigError(f"parameter '{name}': {exc}") from exc
        return values

    @staticmethod
    def _validate(p: dict) -> None:
        if p["backend"] not in BACKENDS:
            raise ConfigError(f"parameter 'backend' must be one of {BACKENDS}, got {p['backend']!r}")
        if p["ee_frame"] not in EE_FRAMES:
            raise ConfigError(f"parameter 'ee_frame' must be one of {EE_FRAMES}, got {p['ee_frame']!r}")
        if p["state_rate"] > p["control_rate"]:
            raise ConfigError(
                f"parameter 'state_rate' ({p['state_rate']:g} Hz) must not exceed "
                f"'control_rate' ({p['control_rate']} Hz)"
            )
        if p["camera_rate"] > p["control_rate"]:
            raise ConfigError("parameter 'camera_rate' must not exceed 'control_rate'")
        q0 = np.asarray(p["initial_positions"], dtype=float)
        if q0.shape != (NUM_JOINTS,) or not np.all(np.isfinite(q0)):
            raise ConfigError(
                f"parameter 'initial_positions' must be {NUM_JOINTS} finite values (rad), "
                f"got {list(p['initial_positions'])}"
            )
        bad = [JOINT_NAMES[i] for i in np.flatnonzero((q0 < Q_MIN) | (q0 > Q_MAX))]
        if bad:
            raise ConfigError(f"parameter 'initial_positions' is outside the joint limits at {bad}")
        for name in ("base_frame_id", "command_topic", "robot_joint_states_topic"):
            if not p[name]:
                raise ConfigError(f"parameter '{name}' must not be empty")

    # ------------------------------------------------------------------------------------- mujoco
    def _setup_mujoco(self, p: dict) -> None:
        from vla_sim.camera_worker import CameraWorker

        from vla_panda_bridge.backend_mujoco import MujocoBackend

        self._mj = MujocoBackend(self._dt, seed=p["seed"], q0=p["initial_positions"])
        self._dt_ns = round(1e9 * self._mj.physics_dt)
        self._steps = 0  # physics steps since start: the sim clock
        self._clock_origin_ns = time.time_ns()  # sim time starts at the wall time of startup
        self._steps_per_state = max(1, round(p["control_rate"] / p["state_rate"]))
        effective = p["control_rate"] / self._steps_per_state
        if abs(effective - p["state_rate"]) > 1e-3 * p["state_rate"]:
            self.get_logger().warn(
                f"state_rate {p['state_rate']:g} Hz is not a divisor of control_rate; "
                f"publishing every {self._steps_per_state} steps = {effective:.4g} Hz"
            )
        self._pacer = SimPacer(self._steps_per_state * self._dt, p["real_time_factor"])
        self._frame_steps = p["control_rate"] / p["camera_rate"] if p["camera_rate"] > 0 else 0.0
        self._frame_index = 0
        self._scene_steps = p["control_rate"] / p["scene_rate"] if p["scene_rate"] > 0 else 0.0
        self._scene_index = 0
        self._scene_pub = self.create_publisher(SceneObjectArray, "scene/objects", 10)
        self._clock_pub = (
            self.create_publisher(Clock, "/clock", QoSProfile(depth=10)) if p["publish_clock"] else None
        )
        if p["camera_rate"] > 0:
            cam_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
            self._image_pub = self.create_publisher(Image, "camera/image_raw", cam_qos)
            self._info_pub = self.create_publisher(CameraInfo, "camera/camera_info", cam_qos)
            self._camera = CameraWorker(
                p["camera_width"],
                p["camera_height"],
                self._mj.physics_dt,
                self._publish_frame,
                lambda m: self.get_logger().error(m, throttle_duration_sec=2.0),
            )
            self._camera_info = self._make_camera_info()
        self.filter.reset(self._mj.sim.q_target)
        self._publish_scene()
        self._publish_state()
        self._request_frame()
        self._wall_start = time.monotonic()
        self._pacer.start(self._wall_start, 0.0)
        self._tick_timer = self.create_timer(self._pacer.timer_period(), self._tick)
        cam = (
            f"camera {p['camera_width']}x{p['camera_height']} at {p['camera_rate']:g} Hz"
            if self._camera
            else "camera off"
        )
        rtf = "as fast as possible" if p["real_time_factor"] == 0 else f"x{p['real_time_factor']:g}"
        self.get_logger().info(
            f"mujoco Panda: {p['control_rate']} Hz physics+safety, joint_states {effective:g} Hz, "
            f"real time {rtf}, {cam}; {len(self._mj.layout)} objects "
            f"({', '.join(o.class_id for o in self._mj.layout)})"
        )

    def sim_time_ns(self) -> int:
        return self._clock_origin_ns + self._steps * self._dt_ns

    def _sim_seconds(self) -> float:
        return self._steps * self._dt

    def _tick(self) -> None:
        """Timer: advance whole state periods of simulated time (see SimPacer), publishing as it goes."""
        units = self._pacer.units_due(time.monotonic(), self._sim_seconds())
        sim = self._mj.sim
        for _ in range(units):
            for k in range(self._steps_per_state):
                # The servo targets integrate exactly what the filter integrates: measure once a unit.
                q = sim.q_target if k == 0 else None
                dq, code, text = self.filter.filter(None, q, self._sim_seconds())
                sim.set_velocity_command(dq)
                sim.step(1)
                self._steps += 1
                if code != self._published_code:
                    self._publish_status(code, text)
                if self._frame_steps and self._steps >= (self._frame_index + 1) * self._frame_steps - 1e-9:
                    self._frame_index += 1
                    self._request_frame()
                if self._scene_steps and self._steps >= (self._scene_index + 1) * self._scene_steps - 1e-9:
                    self._scene_index += 1
                    self._publish_scene()
            self._publish_state()
        if self._clock_pub is not None and units:
            self._clock_pub.publish(Clock(clock=_stamp(self.sim_time_ns())))

    def _request_frame(self) -> None:
        if self._camera is None:
            return
        if self.params["real_time_factor"] == 0.0:
            self._camera.wait_idle(timeout=5.0)  # as fast as possible, but every frame
        self._camera.request(self._mj.qpos(), self.sim_time_ns())

    def _publish_frame(self, rgb: np.ndarray, stamp_ns: int) -> None:
        """Camera worker thread: publish one rendered frame and its camera info."""
        if self._closed:
            return
        h, w = rgb.shape[:2]
        img = Image()
        img.header.stamp = _stamp(stamp_ns)
        img.header.frame_id = self._camera.frame_id
        img.height, img.width = h, w
        img.encoding = "rgb8"
        img.is_bigendian = 0
        img.step = 3 * w
        img.data = rgb.tobytes()
        info = self._camera_info
        info.header.stamp = img.header.stamp
        self._image_pub.publish(img)
        self._info_pub.publish(info)

    def _make_camera_info(self) -> CameraInfo:
        fx, fy, cx, cy = self._camera.intrinsics
        w, h = self._camera.size
        info = CameraInfo()
        info.header.frame_id = self._camera.frame_id
        info.width, info.height = w, h
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        return info

    def _publish_scene(self) -> None:
        msg = SceneObjectArray()
        msg.header.stamp = _stamp(self.sim_time_ns())
        msg.header.frame_id = self._base_frame
        msg.objects = [self._scene_object(o) for o in self._mj.object_poses()]
        self._scene_pub.publish(msg)

    @staticmethod
    def _scene_object(o: ObjectPose) -> SceneObject:
        s = SceneObject(class_id=o.class_id, x=float(o.x), y=float(o.y), yaw=float(o.yaw))
        s.pose = Pose()
        s.pose.position.x, s.pose.position.y, s.pose.position.z = float(o.x), float(o.y), float(o.z)
        w, x, y, z = (float(v) for v in o.quat)
        s.pose.orientation.w, s.pose.orientation.x, s.pose.orientation.y, s.pose.orientation.z = w, x, y, z
        return s

    # ------------------------------------------------------------------------------- ros2_control
    def _setup_ros2_control(self, p: dict) -> None:
        from vla_panda_bridge.backend_ros2_control import Ros2ControlBackend

        self._rc = Ros2ControlBackend(self, p["command_topic"], p["robot_joint_states_topic"])
        in_topic = self.resolve_topic_name(p["robot_joint_states_topic"])
        out_topic = self.resolve_topic_name("joint_states")
        self._relay = in_topic != out_topic
        if not self._relay:
            self.get_logger().info(f"the arm's joint states are already on {out_topic}; not republishing")
        self._rc_state_stale = True
        self.create_timer(self._dt, self._control_tick)
        self.create_timer(1.0 / p["state_rate"], self._relay_state)
        self.get_logger().info(
            f"ros2_control: {p['control_rate']} Hz safety -> {self.resolve_topic_name(p['command_topic'])}; "
            f"state from {in_topic}"
        )

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _control_tick(self) -> None:
        sample = self._rc.read()
        now = self._now_s()
        if sample is not None and now - self._rc.received_at <= self.params["state_timeout"]:
            q, stale = sample.position, False
        else:
            q, stale = _NO_STATE, True                   # invalid on purpose: the filter brakes
            if not self._rc_state_stale:
                self.get_logger().warn(f"no joint state from {self.params['robot_joint_states_topic']} "
                                       f"for {self.params['state_timeout']:g} s: braking to zero")
        self._rc_state_stale = stale
        dq, code, text = self.filter.filter(None, q, now)
        self._rc.write(dq)
        if code != self._published_code:
            self._publish_status(code, text)

    def _relay_state(self) -> None:
        if self._rc.read() is not None:
            self._publish_state()

    # ----------------------------------------------------------------------------------- shared
    def _on_command(self, msg: Float64MultiArray) -> None:
        now = self._sim_seconds() if self._mj is not None else self._now_s()
        code, text = self.filter.submit(msg.data, now)
        if code != safety.OK:
            self.get_logger().warn(text, throttle_duration_sec=1.0)
            self._publish_status(code, text)

    def _state_stamp_ns(self, sample) -> int:
        if self._mj is not None:
            return self.sim_time_ns()
        return int(round(sample.stamp * 1e9)) or self.get_clock().now().nanoseconds

    def _publish_state(self) -> None:
        sample = self._mj.read() if self._mj is not None else self._rc.read()
        if sample is None:
            return
        stamp = _stamp(self._state_stamp_ns(sample))
        if self._mj is not None or self._relay:
            js = JointState()
            js.header.stamp = stamp
            js.name = list(JOINT_NAMES)
            js.position = sample.position.tolist()
            js.velocity = sample.velocity.tolist()
            js.effort = sample.effort.tolist()
            self._js_pub.publish(js)
            self.states_published += 1
        pos, rot = self._fk(sample.position)
        pose = PoseStamped()
        pose.header.stamp = stamp
        pose.header.frame_id = self._base_frame
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in pos)
        w, x, y, z = _quat_wxyz(rot)
        pose.pose.orientation.w, pose.pose.orientation.x = w, x
        pose.pose.orientation.y, pose.pose.orientation.z = y, z
        self._ee_pub.publish(pose)

    def _publish_status(self, code: int | None = None, text: str | None = None) -> None:
        f = self.filter
        if code is None:
            code, text = f.code, self._status_text
        else:
            self._status_text = text or ""
        msg = SafetyStatus()
        ns = self.sim_time_ns() if self._mj is not None else self.get_clock().now().nanoseconds
        msg.header.stamp = _stamp(ns)
        msg.code = int(code)
        msg.text = text or safety.CODE_NAMES.get(code, "")
        msg.last_intervention = int(f.last_intervention)
        msg.commands_received = f.commands_received
        msg.commands_rejected = f.commands_rejected
        msg.interventions = f.interventions
        msg.estop_active = f.estop_active
        self._status_pub.publish(msg)
        self._published_code = code

    def _on_estop(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.filter.set_estop(request.data)
        response.success = True
        response.message = (
            "e-stop latched: braking to zero, commands ignored until released"
            if request.data
            else "e-stop released: send a new command to move"
        )
        if request.data:
            self.get_logger().warn(response.message)
        else:
            self.get_logger().info(response.message)
        self._publish_status(safety.ESTOP if request.data else safety.OK, response.message)
        return response

    def _on_reset(self, request: ResetScene.Request, response: ResetScene.Response) -> ResetScene.Response:
        if self._mj is None:
            response.success = False
            response.message = "~/reset needs the mujoco backend (a real arm cannot be reset)"
            return response
        try:
            objects = [
                ObjectPose(o.class_id, float(o.x), float(o.y), float(o.yaw)) for o in request.objects
            ] or None
            seed = int(request.seed) if request.use_seed and objects is None else None
            q0 = list(request.initial_positions) or None
            layout = self._mj.reset(seed=seed, objects=objects, q0=q0)
        except ValueError as exc:
            response.success = False
            response.message = f"reset refused, scene unchanged: {exc}"
            response.objects = [self._scene_object(o) for o in self._mj.object_poses()]
            self.get_logger().warn(response.message)
            return response
        self.filter.reset(self._mj.sim.q_target)
        self._publish_scene()
        self._publish_state()
        self._request_frame()
        response.success = True
        response.objects = [self._scene_object(o) for o in layout]
        response.message = f"reset: {', '.join(o.class_id for o in layout) or 'no objects'}"
        self.get_logger().info(response.message)
        return response

    # ---------------------------------------------------------------------------------- shutdown
    def shutdown_motion(self) -> None:
        """Zero command on shutdown. A real arm is braked through the safety filter first (a jump to
        zero would trip its reflexes), bounded by the filter's stopping time."""
        if self._closed:
            return
        self._closed = True
        if self._camera is not None:
            self._camera.close()
        if self._mj is not None:
            self._mj.close()
            wall = time.monotonic() - self._wall_start
            cam = (f", camera {self._camera.frames} frames ({self._camera.dropped} dropped while rendering)"
                   if self._camera is not None else "")
            sim_s = self._sim_seconds()
            print(f"panda_bridge: {sim_s:.1f} s simulated in {wall:.1f} s (x{sim_s / max(wall, 1e-9):.2f}, "
                  f"fell behind {self._pacer.lag_events} times){cam}; command zeroed", file=sys.stderr)
            return
        if self._rc is not None:
            self.filter.set_estop(True)
            deadline = time.monotonic() + self.filter.stopping_time_bound()
            try:
                while not self.filter.is_stopped and time.monotonic() < deadline:
                    sample = self._rc.read()
                    dq, _, _ = self.filter.filter(
                        None, None if sample is None else sample.position, self._now_s()
                    )
                    self._rc.write(dq)
                    time.sleep(self._dt)
                self._rc.close()
            except Exception as exc:  # context already gone: nothing more can be sent
                print(f"panda_bridge: could not send the final zero command: {exc}", file=sys.stderr)

    def destroy_node(self) -> None:
        self.shutdown_motion()
        super().destroy_node()


def main(args=None) -> int:
    # Our own signal handling: rclpy's would invalidate the context before the zero command goes out.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)      # also when started with SIGINT ignored (background jobs)
    node = None
    code = 0
    try:
        node = PandaBridge()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ConfigError as exc:
        print(f"panda_bridge: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        try:
            if node is not None:
                node.destroy_node()
            if rclpy.ok():
                rclpy.shutdown()
        except KeyboardInterrupt:
            pass
    return code


if __name__ == "__main__":
    sys.exit(main())

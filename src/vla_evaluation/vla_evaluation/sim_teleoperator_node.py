"""`ros2 run vla_latent_controller sim_teleoperator`: the paper's simulated user on a real joystick topic.

It publishes `sensor_msgs/Joy` on `joy` at the controller's rate, choosing each stick value greedily
(see `sim_teleoperator.py`) so that the controller's decoded command brings the arm nearest the
current joint-space waypoint. It drives the system exactly as a person would: the only thing it
sends is the stick. To choose, it reads `joint_states`, the ground-truth `scene/objects` (for the
task planner's waypoints, as the paper's teleoperator does) and the context the controller latched
(`controller_status`: class and image position of the detection; for CNN encoders the first camera
image of the episode).

Episodes start with `~/start_episode` (vla_interfaces/StartEpisode, field `task`) or the `task`
parameter at startup; `~/stop` ends one early. Stick released (0) at the time limit and on shutdown.
"""
from __future__ import annotations

import math

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import Image, JointState, Joy
from std_srvs.srv import Trigger
from vla_common.robot import DQ_MAX

from vla_evaluation.sim_teleoperator import (
    DEFAULT_CANDIDATES,
    DEFAULT_HORIZON,
    DEFAULT_SWITCH_TIME,
    DEFAULT_TIME_LIMIT,
    SimTeleoperator,
    StickToCommand,
    WaypointSchedule,
    teleop_waypoints,
)
from vla_interfaces.msg import ControllerStatus, SceneObjectArray, TeleopStatus
from vla_interfaces.srv import StartEpisode

JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))


def default_model_path() -> str:
    """The model shipped with the package (share/vla_latent_controller/models/default)."""
    from vla_evaluation.resources import latent_model_dir

    return str(latent_model_dir("default"))


def _desc(text: str, lo: float | None = None, hi: float | None = None, integer: bool = False,
          read_only: bool = False) -> ParameterDescriptor:
    d = ParameterDescriptor(description=text, read_only=read_only)
    if lo is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


class SimTeleoperatorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("sim_teleoperator", **kwargs)
        p = self.declare_parameter
        p("model_path", "", _desc("latent-action model directory (the controller's); empty: the shipped one",
                                  read_only=True))
        p("task", "", _desc("task to start at once, e.g. bread/push_east; empty: wait for ~/start_episode"))
        p("rate", 100.0, _desc("stick publishing rate (Hz): the controller's rate", 1.0, 1000.0))
        p("axis", 0, _desc("index of the stick axis in Joy.axes (the controller's `axis`)", 0, 15, True))
        p("num_axes", 2, _desc("length of Joy.axes", 1, 16, True))
        p("enable_button", -1, _desc("deadman button to hold pressed (-1: none)", -1, 31, True))
        p("num_buttons", 4, _desc("length of Joy.buttons", 0, 32, True))
        p("deadband", 0.1, _desc("the controller's stick deadband", 0.0, 0.9))
        p("axis_scale", 1.0, _desc("the controller's axis_scale", -10.0, 10.0))
        p("action_scale", 1.0, _desc("the controller's action_scale (decoder output -> rad/s)", 0.0, 100.0))
        p("max_joint_speed", 1.5, _desc("the controller's joint-speed norm clamp (rad/s)", 0.01, 5.0))
        p("n_candidates", DEFAULT_CANDIDATES, _desc("stick values tried over [-1, 1] (odd)", 3, 401, True))
        p("horizon", DEFAULT_HORIZON,
          _desc("look-ahead of the projected state, the paper's dt (s)", 0.01, 10.0))
        p("switch_time", DEFAULT_SWITCH_TIME,
          _desc("time on the pre-push waypoint, the paper's k (s)", 0.0, 600.0))
        p("time_limit", DEFAULT_TIME_LIMIT, _desc("episode length (s)", 0.1, 3600.0))
        p("max_stick_rate", 0.0, _desc("how fast the simulated hand moves the stick (units/s); 0: unlimited "
                                      "(the paper's choice)", 0.0, 1000.0))
        p("plan_seed", 0, _desc("seed of the planner's waypoint variation", 0, 2**31 - 1, True))
        p("start_timeout", 10.0, _desc("give up starting when inputs are missing this long (s)", 0.1, 600.0))
        p("controller_status_topic", "controller_node/status",
          _desc("the controller's ~/status topic (ControllerStatus)", read_only=True))
        p("use_controller_context", True, _desc("take the latched class and position from controller_status "
                                                "(false: the detector encoder needs them, so it fails)"))
        self._read_params()
        self.add_on_set_parameters_callback(self._on_params)

        from vla_common.kinematics import PandaKinematics
        from vla_latent_controller.model import LatentModel

        path = self.get_parameter("model_path").value or default_model_path()
        self.model = LatentModel.load(path)  # ModelError with the reason: stops the node at startup
        self.kin = PandaKinematics()
        self.get_logger().info(f"model {path} ({self.model.encoder}, classes {self.model.classes})")

        self.q: np.ndarray | None = None
        self.objects: dict[str, object] = {}
        self.ctrl: ControllerStatus | None = None
        self.ctrl_time: Time | None = None
        self.image: np.ndarray | None = None
        self.image_time: Time | None = None

        self.joy_pub = self.create_publisher(Joy, "joy", 10)
        self.status_pub = self.create_publisher(TeleopStatus, "~/status", 10)
        self.create_subscription(JointState, "joint_states", self._on_joints, qos_profile_sensor_data)
        self.create_subscription(SceneObjectArray, "scene/objects", self._on_objects, qos_profile_sensor_data)
        self.create_subscription(ControllerStatus, self.get_parameter("controller_status_topic").value,
                                 self._on_ctrl, qos_profile_sensor_data)
        if self.model.needs_image:
            self.create_subscription(Image, "camera/image_raw", self._on_image, qos_profile_sensor_data)
        self.create_service(StartEpisode, "~/start_episode", self._srv_start)
        self.create_service(Trigger, "~/stop", self._srv_stop)

        self.state = TeleopStatus.IDLE
        self.task = ""
        self.reason = ""
        self.request_time: Time | None = None
        self.t0: Time | None = None
        self.tele: SimTeleoperator | None = None
        self.last_step = None
        self._status_every = max(1, int(round(self.rate / 10.0)))
        self._ticks = 0
        self.timer = self.create_timer(1.0 / self.rate, self._tick)
        if self.get_parameter("task").value:
            self._request(self.get_parameter("task").value)

    # ------------------------------------------------------------------ parameters
    def _read_params(self) -> None:
        g = self.get_parameter
        self.rate = float(g("rate").value)
        self.axis = int(g("axis").value)
        self.num_axes = max(int(g("num_axes").value), self.axis + 1)
        self.enable_button = int(g("enable_button").value)
        self.num_buttons = max(int(g("num_buttons").value), self.enable_button + 1)
        self.n_candidates = int(g("n_candidates").value)
        if self.n_candidates % 2 == 0:
            raise ValueError(f"n_candidates must be odd (0 must be a candidate), got {self.n_candidates}")

    def _on_params(self, params):
        from rcl_interfaces.msg import SetParametersResult

        for prm in params:
            if prm.name == "n_candidates" and int(prm.value) % 2 == 0:
                return SetParametersResult(successful=False, reason="n_candidates must be odd")
            if prm.name == "rate":
                return SetParametersResult(successful=False, reason="rate is fixed at startup")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ inputs
    def _on_joints(self, msg: JointState) -> None:
        try:
            idx = [list(msg.name).index(n) for n in JOINT_NAMES]
            q = np.array([msg.position[i] for i in idx], dtype=float)
        except (ValueError, IndexError):
            return  # another robot's or a partial joint state: ignored
        if np.all(np.isfinite(q)):
            self.q = q

    def _on_objects(self, msg: SceneObjectArray) -> None:
        from vla_common.objects import ObjectPose

        self.objects = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw) for o in msg.objects}

    def _on_ctrl(self, msg: ControllerStatus) -> None:
        self.ctrl = msg
        self.ctrl_time = self.get_clock().now()

    def _on_image(self, msg: Image) -> None:
        if msg.encoding not in ("rgb8", "bgr8") or msg.height * msg.step > len(msg.data):
            return
        a = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :msg.width * 3]
        a = a.reshape(msg.height, msg.width, 3)
        self.image = a[:, :, ::-1].copy() if msg.encoding == "bgr8" else a.copy()
        self.image_time = self.get_clock().now()

    # ------------------------------------------------------------------ episodes
    def _srv_start(self, req: StartEpisode.Request, res: StartEpisode.Response):
        try:
            self._request(req.task)
        except ValueError as e:
            res.success, res.message = False, str(e)
            return res
        res.success, res.message = True, f"started {self.task}: waiting for inputs"
        return res

    def _srv_stop(self, req: Trigger.Request, res: Trigger.Response):
        was = self.state
        self._finish(TeleopStatus.DONE if was == TeleopStatus.RUNNING else TeleopStatus.IDLE, "stopped")
        active = was in (TeleopStatus.RUNNING, TeleopStatus.WAITING)
        res.success, res.message = True, "stopped" if active else "idle"
        return res

    def _request(self, task: str) -> None:
        from vla_common.tasks import parse_task

        parse_task(task)  # ValueError with the known tasks
        self.task = task
        self.state = TeleopStatus.WAITING
        self.reason = "waiting for joint states, scene and context"
        self.request_time = self.get_clock().now()
        self.tele = None
        self.last_step = None

    def _fresh(self, stamp: Time | None) -> bool:
        return stamp is not None and self.request_time is not None and stamp >= self.request_time

    def _try_start(self) -> None:
        from vla_common.tasks import parse_task
        from vla_latent_controller.context import ContextError, Det
        from vla_sim.planner import plan_task

        now = self.get_clock().now()
        waited = (now - self.request_time).nanoseconds * 1e-9
        spec = parse_task(self.task)
        missing = []
        if self.q is None:
            missing.append("joint_states")
        if spec.object_class not in self.objects:
            missing.append(f"{spec.object_class} in scene/objects")
        need_ctrl = self.get_parameter("use_controller_context").value and self.model.needs_class
        ctrl = self.ctrl if self._fresh(self.ctrl_time) else None
        if need_ctrl and (ctrl is None or not ctrl.latched_class):
            missing.append("a latched detection on controller_status")
        if self.model.needs_image and not self._fresh(self.image_time):
            missing.append("a camera image")
        if missing:
            self.reason = "waiting for " + ", ".join(missing)
            if waited > float(self.get_parameter("start_timeout").value):
                self._finish(TeleopStatus.FAILED, "gave up: " + self.reason)
                self.get_logger().warn(f"{self.task}: {self.reason}")
            return
        try:
            cls = ctrl.latched_class if ctrl is not None and ctrl.latched_class else None
            det = Det(cls, 1.0, float(ctrl.latched_x), float(ctrl.latched_y)) if cls else None
            context = self.model.context(det=det, image_size=(1, 1), image=self.image, class_id=cls)
            g = self.get_parameter
            command = StickToCommand(self.model, context, cls, g("deadband").value, g("axis_scale").value,
                                     g("action_scale").value, g("max_joint_speed").value, DQ_MAX)
            plan = plan_task(self.kin, spec, self.objects[spec.object_class], self.q,
                             np.random.default_rng(int(g("plan_seed").value)))
            waypoints = teleop_waypoints(plan)
            schedule = WaypointSchedule(waypoints, float(g("switch_time").value),
                                        float(g("time_limit").value))
            self.tele = SimTeleoperator(command, schedule, float(g("horizon").value), self.n_candidates,
                                        float(g("max_stick_rate").value))
        except (ContextError, ValueError, RuntimeError) as e:
            self._finish(TeleopStatus.FAILED, f"cannot start: {e}")
            self.get_logger().error(f"{self.task}: {self.reason}")
            return
        self.t0 = now
        self.state = TeleopStatus.RUNNING
        self.reason = f"context {cls or self.model.encoder}"
        self.get_logger().info(f"{self.task}: running ({len(waypoints)} waypoints, {self.reason})")

    def _finish(self, state: int, reason: str) -> None:
        if self.state in (TeleopStatus.RUNNING, TeleopStatus.WAITING):
            self._publish_joy(0.0)  # release the stick
        self.state = state
        self.reason = reason
        self._publish_status()

    # ------------------------------------------------------------------ loop
    def _tick(self) -> None:
        self._ticks += 1
        if self.state == TeleopStatus.WAITING:
            self._try_start()
        if self.state == TeleopStatus.RUNNING:
            t = (self.get_clock().now() - self.t0).nanoseconds * 1e-9
            q = self.q if self.q is not None else np.full(7, np.nan)
            step = self.tele.act(t, q)
            self.last_step = step
            if step.done:
                self._finish(TeleopStatus.DONE, "time limit")
                return
            self._publish_joy(step.axis)
        if self._ticks % self._status_every == 0:
            self._publish_status()

    def _publish_joy(self, value: float) -> None:
        msg = Joy()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "sim_teleoperator"
        axes = [0.0] * self.num_axes
        axes[self.axis] = float(value)
        buttons = [0] * self.num_buttons
        if self.enable_button >= 0:
            held = self.state in (TeleopStatus.RUNNING, TeleopStatus.WAITING)
            buttons[self.enable_button] = 1 if held else 0
        msg.axes, msg.buttons = axes, buttons
        self.joy_pub.publish(msg)

    def _publish_status(self) -> None:
        msg = TeleopStatus()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.state, msg.task, msg.reason = self.state, self.task, self.reason
        if self.tele is not None:
            sched = self.tele.schedule
            msg.waypoint_count = len(sched.waypoints)
            msg.final_waypoint = [float(v) for v in sched.final]
            if self.t0 is not None:
                msg.elapsed = min((self.get_clock().now() - self.t0).nanoseconds * 1e-9, sched.time_limit)
            if self.last_step is not None:
                msg.waypoint_index = int(self.last_step.waypoint_index)
                msg.waypoint = [float(v) for v in sched.waypoints[self.last_step.waypoint_index]]
                msg.axis = float(self.last_step.axis) if self.state == TeleopStatus.RUNNING else 0.0
                d = self.last_step.distance
                msg.distance = float(d) if math.isfinite(d) else 0.0
        self.status_pub.publish(msg)

    def release(self) -> None:
        """Zero stick on shutdown."""
        try:
            self._publish_joy(0.0)
        except Exception:  # noqa: BLE001 - context may already be gone
            pass


def main(args=None) -> None:
    rclpy.init(args=args)
    node = None
    from rclpy.executors import ExternalShutdownException

    try:
        node = SimTeleoperatorNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as e:  # noqa: BLE001 - a startup error (bad model, bad parameter) ends with a message
        import sys

        print(f"sim_teleoperator: {e}", file=sys.stderr)
        raise SystemExit(1) from None
    finally:
        if node is not None:
            node.release()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()

"""`ros2 run vla_evaluation sim_teleoperator`: the paper's simulated user on a real joystick topic.

It publishes `sensor_msgs/Joy` on `joy` at the controller's rate, choosing each stick value greedily
(see `sim_teleoperator.py`) so that the controller's decoded command brings the arm nearest the
current joint-space waypoint. It drives the system exactly as a person would: the only thing it
sends is the stick. To choose, it reads `joint_states`, the ground-truth `scene/objects` (for the
task planner's waypoints, as the paper's teleoperator does) and the context the controller latched
(`controller_status`: class and image position of the detection; for CNN encoders the first camera
image of the episode).

Episodes start with `~/start_episode` (vla_interfaces/StartEpisode, field `task`) or the `task`
parameter at startup; `~/stop` ends one early. Stick released (0) at the time limit and on shutdown.
Every parameter except `rate`, `task` and `controller_status_topic` may change at run time; the
episode settings apply from the next episode, and `model_path` is refused while an episode runs.
"""
from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.time import Time
from sensor_msgs.msg import Image, JointState, Joy
from std_srvs.srv import Trigger
from vla_common.catalogue import HAND_KINDS, CatalogueError, load_catalogue
from vla_common.detection import Detection
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import DQ_MAX, JOINT_NAMES
from vla_common.ros.node_main import ConfigError, StartupError, run_node
from vla_common.ros.parameters import Param, ParameterTable
from vla_common.ros.qos import IMAGE_QOS, SENSOR_QOS
from vla_common.tasks import place_target
from vla_latent_controller.artifacts import ModelError
from vla_latent_controller.context import ContextError
from vla_latent_controller.model import LatentModel
from vla_latent_controller.teleop import TeleopParams
from vla_sim.planner import plan_task

from vla_evaluation.resources import latent_model_dir
from vla_evaluation.sim_fine import FineAlign
from vla_evaluation.sim_grasp import GraspButton, hand_phases, hand_seen
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
from vla_interfaces.msg import ControllerStatus, GripperStatus, SafetyStatus, SceneObjectArray, TeleopStatus
from vla_interfaces.srv import SetMode, StartEpisode

NODE_NAME = "sim_teleoperator"
ACTIVE = (TeleopStatus.RUNNING, TeleopStatus.WAITING)
RETARGET = 0.005   # m: the object moved this far while aligning: align again on where it is now
TRIGGERS = ("timer", "joint_states")


def _odd(n: int) -> str | None:
    return None if n % 2 == 1 else f"must be odd (0 must be a candidate), got {n}"


_CONTROLLER = TeleopParams()  # the stick mapping mirrors the controller's: its defaults, declared there

PARAMETERS = ParameterTable([
    Param("model_path", "", "latent-action model directory (the controller's); empty: the shipped one; "
          "refused while an episode runs", dynamic=True),
    Param("task", "", "task to start at once, e.g. bread/push_east; empty: wait for ~/start_episode"),
    Param("catalogue", "", "object catalogue YAML with the tasks and the objects' shapes (the planner's); "
          "empty: the default (the paper's five)"),
    Param("rate", 100.0, "stick publishing rate (Hz): the controller's rate", range=(1.0, 1000.0)),
    Param("axis", _CONTROLLER.axis,
          "index of the stick axis in Joy.axes (the controller's `axis`)", range=(0, 15),
          dynamic=True),
    Param("num_axes", 2, "length of Joy.axes", range=(1, 16), dynamic=True),
    Param("enable_button", _CONTROLLER.enable_button,
          "deadman button held pressed during an episode (-1: none)", range=(-1, 31),
          dynamic=True),
    Param("grasp_button", _CONTROLLER.grasp_button,
          "button pressed to toggle the hand in tasks with the hand (the controller's "
          "grasp_button; -1: none, those tasks then fail)", range=(-1, 31), dynamic=True),
    Param("num_buttons", 4, "length of Joy.buttons", range=(0, 32), dynamic=True),
    Param("fine_align", True, "tasks with the hand: where the latent's path stops short of the grasp or "
          "place point, switch the controller to end-effector mode and align the hand one axis at a "
          "time, as a person does (sim_fine); false: press where the path settles", dynamic=True),
    Param("ee_mode_button", _CONTROLLER.ee_mode_button,
          "the controller's ee_mode_button, pressed to choose the end-effector axis", range=(0, 31),
          dynamic=True),
    Param("set_mode_service", "controller_node/set_mode",
          "the controller's ~/set_mode service (vla_interfaces/SetMode), for fine alignment"),
    Param("deadband", _CONTROLLER.deadband,
          "the controller's stick deadband", range=(0.0, 0.9), dynamic=True),
    Param("axis_scale", _CONTROLLER.axis_scale,
          "the controller's axis_scale", range=(-10.0, 10.0), dynamic=True),
    Param("action_scale", _CONTROLLER.action_scale,
          "the controller's action_scale (decoder output -> rad/s)", range=(0.0, 100.0),
          dynamic=True),
    Param("path_fraction", _CONTROLLER.path_fraction, "the controller's path_fraction (0: the model's)",
          range=(0.0, 1.0), dynamic=True),
    Param("max_joint_speed", _CONTROLLER.max_joint_speed,
          "the controller's joint-speed norm clamp (rad/s)", range=(0.01, 5.0),
          dynamic=True),
    Param("n_candidates", DEFAULT_CANDIDATES, "stick values tried over [-1, 1] (odd)", range=(3, 401),
          dynamic=True, check=_odd),
    Param("horizon", DEFAULT_HORIZON, "look-ahead of the projected state, the paper's dt (s)",
          range=(0.01, 10.0), dynamic=True),
    Param("switch_time", DEFAULT_SWITCH_TIME, "time on the pre-push waypoint, the paper's k (s)",
          range=(0.0, 600.0), dynamic=True),
    Param("time_limit", DEFAULT_TIME_LIMIT, "episode length (s)", range=(0.1, 3600.0), dynamic=True),
    Param("max_stick_rate", 0.0, "how fast the simulated hand moves the stick (units/s); 0: unlimited "
          "(the paper's choice)", range=(0.0, 1000.0), dynamic=True),
    Param("hold", 0.0, "hold the stick at this value for the whole episode instead of steering to the "
          "waypoints (0: steer)", range=(-1.0, 1.0), dynamic=True),
    Param("plan_seed", 0, "seed of the planner's waypoint variation", range=(0, 2**31 - 1), dynamic=True),
    Param("start_timeout", 10.0, "give up starting when inputs are missing this long (s)",
          range=(0.1, 600.0), dynamic=True),
    Param("controller_status_topic", "controller_node/status",
          "the controller's ~/status topic (ControllerStatus)"),
    Param("safety_status_topic", "panda_bridge/status",
          "the bridge's ~/status topic (SafetyStatus): AWAITING_ZERO there releases the stick"),
    Param("use_controller_context", True, "take the latched class and position from controller_status "
          "(false: the detector encoder needs them, so it fails)", dynamic=True),
    Param("trigger", "timer", "timer: a stick value every 1/rate s; joint_states: one for every joint state, "
          "from that state (for a simulation stepped in lockstep with the commands)",
          choices=TRIGGERS),
    Param("lockstep", False, "answer the bridge's lockstep simulation: trigger joint_states, and exactly one "
          "Joy for every joint state, stamped with it (the stick at rest between episodes: the controller "
          "waits for it), from inputs that every run sees alike (vla_common.lockstep)"),
])


def default_model_path() -> str:
    """The model shipped with the controller (share/vla_latent_controller/models/default)."""
    return str(latent_model_dir("default"))


def load_model(path: str) -> LatentModel:
    return LatentModel.load(path or default_model_path())


class SimTeleoperatorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.p = PARAMETERS.declare(self, self._on_parameter)
        try:
            self.catalogue = load_catalogue(self.p["catalogue"])
        except CatalogueError as e:
            raise ConfigError(f"parameter 'catalogue': {e}") from e
        path = self.p["model_path"] or default_model_path()
        try:
            self.model = load_model(path)
        except (ModelError, OSError, ValueError) as e:
            raise StartupError(f"cannot load model {path!r}: {e}") from e
        self.kin = PandaKinematics()
        self.get_logger().info(f"model {self.model.artifacts.path} ({self.model.encoder}, "
                               f"classes {self.model.classes})")

        self.q: np.ndarray | None = None
        self.objects: dict[str, ObjectPose] = {}
        self._spec, self._place_from = None, None     # the episode's task and its object's start
        self.ctrl: ControllerStatus | None = None
        self.ctrl_time: Time | None = None
        self.bridge_code: int | None = None   # the bridge's latest SafetyStatus code
        self.image: np.ndarray | None = None
        self.image_time: Time | None = None
        self._image_sub = None
        self._state_time: Time | None = None  # trigger joint_states: the latest joint state's stamp
        self._lockstep = bool(self.p["lockstep"])
        self._images: list[tuple[Time, np.ndarray]] = []  # lockstep: frames not yet usable (stamped later)
        self._joy_sent: Time | None = None    # the stamp of the last Joy published
        reliable = QoSProfile(depth=100)      # lockstep: a lost message is a hang or a different input
        sensor = reliable if self._lockstep else SENSOR_QOS

        self.joy_pub = self.create_publisher(Joy, "joy", 10)
        self.status_pub = self.create_publisher(TeleopStatus, "~/status", 10)
        self.create_subscription(JointState, "joint_states", self._on_joints, sensor)
        self.create_subscription(SceneObjectArray, "scene/objects", self._on_objects, sensor)
        self._ctrl_sub = self.create_subscription(ControllerStatus, self.p["controller_status_topic"],
                                                  self._on_ctrl, sensor)
        self.create_subscription(SafetyStatus, self.p["safety_status_topic"], self._on_safety, 10)
        self.hand: GripperStatus | None = None      # the bridge's gripper/status (what a person sees)
        self._hand_failed = False                   # a grasp failure not yet shown to the button core
        self.create_subscription(GripperStatus, "gripper/status", self._on_hand, 10)
        self.grasp: GraspButton | None = None       # tasks with the hand: when to press grasp_button
        self._hand_seen: str | None = None           # the hand as the user last saw it (sim_grasp.hand_seen)
        self._plan = None
        self._phase_t0 = 0.0
        self._episode_limit = float(self.p["time_limit"])   # the running episode's (s)
        self._press = False
        self._fine: FineAlign | None = None          # aligning in end-effector mode (sim_fine)
        self._axis_press = False                     # press ee_mode_button in the next Joy
        self._mode_client = self.create_client(SetMode, self.p["set_mode_service"])
        self._mode_call = None                       # a set_mode request in flight
        self._mode_asked = -math.inf                 # when (s, node clock) it was sent
        self._switched = False                       # this node put the controller in end-effector mode
        self._update_image_subscription()
        self.create_service(StartEpisode, "~/start_episode", self._srv_start)
        self.create_service(Trigger, "~/stop", self._srv_stop)

        self.state = TeleopStatus.IDLE
        self.task = ""
        self.reason = ""
        self.request_time: Time | None = None
        self.t0: Time | None = None
        self.t_end: Time | None = None   # when the running episode ended (its statuses' elapsed stops)
        self.tele: SimTeleoperator | None = None
        self.last_step = None
        rate = float(self.p["rate"])
        self._status_every = max(1, int(round(rate / 10.0)))
        self._ticks = 0
        timed = self.p["trigger"] == "timer" and not self._lockstep
        self.timer = self.create_timer(1.0 / rate, self._tick) if timed else None
        if self.p["task"]:
            try:
                self._request(self.p["task"])
            except ValueError as e:
                raise StartupError(f"parameter 'task': {e}") from e

    # ------------------------------------------------------------------ parameters
    def _on_parameter(self, name: str, value: Any) -> str | None:
        """Apply a run-time change (episode settings: from the next episode on), or say why not."""
        if name == "model_path":
            if self.state in ACTIVE:
                return f"an episode ({self.task}) is running; stop it first"
            try:
                self.model = load_model(value)
            except (ModelError, OSError, ValueError) as e:
                return f"cannot load model {value!r}: {e}"
            self._update_image_subscription()
            self.get_logger().info(f"model {self.model.artifacts.path} ({self.model.encoder})")
        self.p[name] = value
        return None

    def _update_image_subscription(self) -> None:
        if self.model.needs_image and self._image_sub is None:
            self._image_sub = self.create_subscription(Image, "camera/image_raw", self._on_image,
                                                       IMAGE_QOS)

    # ------------------------------------------------------------------ inputs
    def _on_joints(self, msg: JointState) -> None:
        try:
            idx = [list(msg.name).index(n) for n in JOINT_NAMES]
            q = np.array([msg.position[i] for i in idx], dtype=float)
        except (ValueError, IndexError):
            return  # another robot's or a partial joint state: ignored
        if np.all(np.isfinite(q)):
            self.q = q
            if self.timer is None:  # trigger joint_states: decide on this very state, at its time
                self._state_time = Time.from_msg(msg.header.stamp, clock_type=self.get_clock().clock_type)
                if self._lockstep:
                    self._use_images_before(self._state_time)
                    self._joy_sent = None
                self._tick()
                if self._lockstep and self._joy_sent is None:
                    self._publish_joy(0.0)    # the step's answer: a Joy for every state (step 0 comes
                    #                           again until answered: the controller may have missed it)

    def _now(self) -> Time:
        """The node's time: with trigger joint_states the latest joint state's stamp (its simulated
        time, whatever /clock says yet), else the clock's."""
        return self._state_time if self._state_time is not None else self.get_clock().now()

    def _on_objects(self, msg: SceneObjectArray) -> None:
        self.objects = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw) for o in msg.objects}

    def _on_ctrl(self, msg: ControllerStatus) -> None:
        self.ctrl = msg
        self.ctrl_time = self._now()

    def _on_safety(self, msg: SafetyStatus) -> None:
        self.bridge_code = msg.code

    def _on_hand(self, msg: GripperStatus) -> None:
        if msg.state == GripperStatus.GRASP_FAILED and (self.hand is None or self.hand.state != msg.state):
            self._hand_failed = True
        self.hand = msg

    def _on_image(self, msg: Image) -> None:
        if msg.encoding not in ("rgb8", "bgr8") or msg.height * msg.step > len(msg.data):
            return
        a = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :msg.width * 3]
        a = a.reshape(msg.height, msg.width, 3)
        image = a[:, :, ::-1].copy() if msg.encoding == "bgr8" else a.copy()
        if self._lockstep:   # usable from the first step after its stamp, whenever it arrived
            self._images.append((Time.from_msg(msg.header.stamp, clock_type=self.get_clock().clock_type),
                                 image))
            return
        self.image = image
        self.image_time = self._now()

    def _use_images_before(self, t: Time) -> None:
        """Lockstep: the latest frame stamped before the step `t` becomes the image seen (at its stamp)."""
        ready = [(stamp, im) for stamp, im in self._images if stamp < t]
        if ready:
            self.image_time, self.image = max(ready, key=lambda x: x[0].nanoseconds)
            self._images = [(stamp, im) for stamp, im in self._images if not stamp < t]

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
        res.success, res.message = True, "stopped" if was in ACTIVE else "idle"
        return res

    def _request(self, task: str) -> None:
        self.catalogue.task(task)  # CatalogueError (a ValueError) with the known tasks
        self.task = task
        self.state = TeleopStatus.WAITING
        self.reason = "waiting for joint states, scene and context"
        # trigger joint_states before the first state: the request's time is that state's (in _try_start)
        self.request_time = None if self.timer is None and self._state_time is None else self._now()
        self.tele = None
        self.last_step = None

    def _fresh(self, stamp: Time | None) -> bool:
        return stamp is not None and self.request_time is not None and stamp >= self.request_time

    def _missing_inputs(self, spec) -> list[str]:
        missing = []
        if self.q is None:
            missing.append("joint_states")
        if spec.object_class not in self.objects:
            missing.append(f"{spec.object_class} in scene/objects")
        if self.p["use_controller_context"] and self.model.needs_class and self._latched() is None:
            topic = self._ctrl_sub.topic_name
            missing.append(f"a latched detection on {topic}" if self._fresh(self.ctrl_time) else
                           f"any controller status on {topic} (a controller with another name or "
                           "namespace: set controller_status_topic)")
        if self.model.needs_image and not self._fresh(self.image_time):
            missing.append("a camera image")
        return missing

    def _latched(self) -> ControllerStatus | None:
        """The controller's status since this episode's request, if it has latched a class."""
        ctrl = self.ctrl if self._fresh(self.ctrl_time) else None
        return ctrl if ctrl is not None and ctrl.latched_class else None

    def _try_start(self) -> None:
        now = self._now()
        if self.request_time is None or self.request_time.nanoseconds == 0:
            # requested before the first /clock (use_sim_time): the wait starts with simulated time
            self.request_time = now
        spec = self.catalogue.task(self.task)
        missing = self._missing_inputs(spec)
        if missing:
            self.reason = "waiting for " + ", ".join(missing)
            if (now - self.request_time).nanoseconds * 1e-9 > float(self.p["start_timeout"]):
                self._finish(TeleopStatus.FAILED, "gave up: " + self.reason)
                self.get_logger().warn(f"{self.task}: {self.reason}")
            return
        try:
            self.tele, cls = self._make_teleoperator(spec)
        except (ContextError, ValueError, RuntimeError) as e:
            self._finish(TeleopStatus.FAILED, f"cannot start: {e}")
            self.get_logger().error(f"{self.task}: {self.reason}")
            return
        self.t0, self.t_end = now, None
        self.state = TeleopStatus.RUNNING
        self.reason = f"context {cls or self.model.encoder}"
        self.get_logger().info(f"{self.task}: running ({len(self.tele.schedule.waypoints)} waypoints, "
                               f"{self.reason})")

    def _make_teleoperator(self, spec) -> tuple[SimTeleoperator, str | None]:
        """The episode's simulated user: the controller's mapping with the latched context, aiming at
        the planner's waypoints for the object where it is now."""
        p, ctrl = self.p, self._latched()
        cls = ctrl.latched_class if ctrl is not None else None
        det = Detection(cls, 1.0, float(ctrl.latched_x), float(ctrl.latched_y)) if cls else None
        context = self.model.context(det=det, image_size=(1, 1), image=self.image, class_id=cls)
        command = StickToCommand(self.model, context, cls, p["deadband"], p["axis_scale"], p["action_scale"],
                                 p["max_joint_speed"], DQ_MAX, p["path_fraction"])
        plan = plan_task(self.kin, spec, self.objects[spec.object_class], self.q,
                         np.random.default_rng(int(p["plan_seed"])), self.catalogue)
        self._spec, self._place_from = spec, self.objects[spec.object_class]
        self._command, self._plan, self.grasp, self._hand_seen = command, plan, None, None
        self._episode_limit = float(p["time_limit"])
        self._fine = None
        if spec.kind in HAND_KINDS:
            self.grasp = GraspButton(hand_phases(plan), fine=bool(p["fine_align"]))
            return self._phase_teleoperator(0.0), cls
        schedule = WaypointSchedule(teleop_waypoints(plan), float(p["switch_time"]), float(p["time_limit"]))
        tele = SimTeleoperator(command, schedule, float(p["horizon"]), int(p["n_candidates"]),
                               float(p["max_stick_rate"]), float(p["hold"]))
        return tele, cls

    def _phase_teleoperator(self, t: float) -> SimTeleoperator:
        """Tasks with the hand: the user aims at the current phase's waypoints, each for twice the
        plan's time (the latent is slower than the script), the last until the button ends the phase."""
        p, plan, idx = self.p, self._plan, self.grasp.current.waypoint_indices
        self._phase_t0 = t
        times = np.asarray(plan.times, dtype=float)
        left = max(float(p["time_limit"]) - t, 1e-3)
        base = times[idx[0] - 1] if idx[0] > 0 else 0.0
        switch = [min(2.0 * (times[i] - base), left * (k + 1) / len(idx)) for k, i in enumerate(idx[:-1])]
        switch = list(np.maximum.accumulate(switch)) if switch else None
        schedule = WaypointSchedule([plan.waypoints[i] for i in idx], 0.0, left, switch_times=switch)
        return SimTeleoperator(self._command, schedule, float(p["horizon"]), int(p["n_candidates"]),
                               float(p["max_stick_rate"]), float(p["hold"]))

    def _grasp_step(self, t: float) -> None:
        """Tasks with the hand: press grasp_button where a person would; a new phase, new waypoints."""
        if self.grasp is None or self.hand is None or self.q is None:
            return
        phase = self.grasp.phase
        failed, self._hand_failed = self._hand_failed, False
        self._hand_seen = hand_seen(self.hand.state, self.hand.width)
        tcp = self.kin.fk(self.q)[0]
        self.grasp.object_shift = self._object_shift()
        self._press = self.grasp.step(t, tcp, self._hand_seen, failed, self._to_target())
        if self.grasp.phase != phase:
            self._fine = None   # back to the latent for the next phase
            self.tele = self._phase_teleoperator(t)
            self.get_logger().info(f"{self.task}: hand phase {self.grasp.phase} ({self.grasp.current.want})")
        elif self.grasp.wants_fine(t, tcp, self._hand_seen):
            end = self.grasp.end_point()
            if self._fine is None:
                short = 100 * np.linalg.norm(tcp - end)
                self.get_logger().info(f"{self.task}: the latent stopped {short:.1f} cm short; aligning in "
                                       "end-effector mode")
            elif np.linalg.norm(end - self._fine.goal) > RETARGET:
                self.get_logger().info(f"{self.task}: the object moved; aligning on where it is now")
            else:
                return
            self._fine = FineAlign(end, tcp, float(self.p["deadband"]))

    def _object_shift(self) -> np.ndarray:
        """How far (m, x and y) the task's object has moved since the episode planned its waypoints."""
        spec, start = self._spec, self._place_from
        obj = self.objects.get(spec.object_class) if spec is not None else None
        if start is None or obj is None:
            return np.zeros(3)
        return np.array([obj.x - start.x, obj.y - start.y, 0.0])

    def _to_target(self) -> float:
        """A pick-and-place: how far (m) the object is from where it is to be put down, as a person
        sees it (scene/objects); inf for other tasks."""
        spec, start = self._spec, self._place_from
        obj = self.objects.get(spec.object_class) if spec is not None else None
        if spec is None or start is None or spec.kind != "pick_place" or obj is None:
            return float("inf")
        return float(np.linalg.norm(np.array([obj.x, obj.y]) - place_target(spec, start)))

    def _finish(self, state: int, reason: str) -> None:
        if self.state in ACTIVE:
            self._publish_joy(0.0)  # release the stick
            self.t_end = self._now()
        self._fine = None
        if self._switched:
            self._in_mode("latent")   # the controller as the episode found it
        self.state = state
        self.reason = reason
        self._publish_status()

    # ------------------------------------------------------------------ loop
    def _tick(self) -> None:
        self._ticks += 1
        if self.state == TeleopStatus.WAITING:
            self._try_start()
            if self.state == TeleopStatus.WAITING:
                self._publish_joy(0.0)                # a person waits with the stick at rest
            elif self.state == TeleopStatus.RUNNING:
                self._publish_status()                # the start at once (its time is the episode's)
                # the periodic status counts from the episode's start: in lockstep step 0 comes again
                # until every node answered it (a count of wall time), so a count from the node's start
                # put the statuses at other steps in a quiet and a busy run
                self._ticks = 0
        if self.state == TeleopStatus.RUNNING:
            t = (self._now() - self.t0).nanoseconds * 1e-9
            q = self.q if self.q is not None else np.full(7, np.nan)
            self._grasp_step(t)
            step = self.tele.act(t - self._phase_t0 if self.grasp is not None else t, q)
            self.last_step = step
            if step.done:
                self._finish(TeleopStatus.DONE, "time limit")
                return
            axis = step.axis
            want = "end_effector" if self._fine is not None else ("latent" if self._switched else None)
            if want is not None and not self._in_mode(want):
                axis = 0.0    # a person switching modes has the hand off the stick
            elif self._fine is not None:
                fine = self._fine.step(t, self.kin.fk(q)[0], self.ctrl.ee_axis)
                axis, self._axis_press = fine.axis_value, fine.press_axis_button
            self._publish_joy(0.0 if self._asked_for_neutral() or self._waits_for_hand() else axis)
        if self._ticks % self._status_every == 0:
            self._publish_status()

    def _in_mode(self, mode: str) -> bool:
        """Whether the controller is in `mode` (its status); if not, ask it to switch (at most one request
        in flight, one a second). Only modes this node chose: after end-effector mode, latent again."""
        if self.ctrl is not None and self.ctrl.mode == mode:
            self._switched = mode != "latent"
            return True
        self._switched = True
        now = self._now().nanoseconds * 1e-9
        if (self._mode_call is None or self._mode_call.done()) and now - self._mode_asked >= 1.0:
            self._mode_asked = now
            if self._mode_client.service_is_ready():
                self._mode_call = self._mode_client.call_async(SetMode.Request(mode=mode))
            else:
                self.get_logger().warn(f"no {self._mode_client.srv_name} service: "
                                       f"cannot switch to {mode} mode")
        return False

    def _waits_for_hand(self) -> bool:
        """Tasks with the hand: the stick rests while the hand closes or opens (GraspButton.holds_still)."""
        seen = self._hand_seen
        return self.grasp is not None and seen is not None and self.grasp.holds_still(seen)

    def _asked_for_neutral(self) -> bool:
        """The controller or the bridge says a stop happened and motion waits for the stick at
        neutral: a person reading that (or seeing the arm stop) lets go of the stick (the arming rule,
        vla_common.arming)."""
        if self.bridge_code == SafetyStatus.AWAITING_ZERO:
            return True
        return self.ctrl is not None and self.ctrl.code == ControllerStatus.AWAITING_NEUTRAL

    def _publish_joy(self, value: float) -> None:
        axis = int(self.p["axis"])
        enable = int(self.p["enable_button"])
        msg = Joy()
        self._joy_sent = self._now()
        msg.header.stamp = self._joy_sent.to_msg()
        msg.header.frame_id = ""  # a Joy has no geometry: no TF frame (test_frames)
        axes = [0.0] * max(int(self.p["num_axes"]), axis + 1)
        axes[axis] = float(value)
        buttons = [0] * max(int(self.p["num_buttons"]), enable + 1)
        if enable >= 0:
            buttons[enable] = 1 if self.state in ACTIVE else 0
        grasp = int(self.p["grasp_button"])
        if 0 <= grasp < len(buttons):
            buttons[grasp] = 1 if self._press and self.state == TeleopStatus.RUNNING else 0
        mode_button = int(self.p["ee_mode_button"])
        if self._axis_press and self.state == TeleopStatus.RUNNING:
            buttons += [0] * (mode_button + 1 - len(buttons))
            buttons[mode_button] = 1
        self._press = self._axis_press = False
        msg.axes, msg.buttons = axes, buttons
        self.joy_pub.publish(msg)

    def _publish_status(self) -> None:
        msg = TeleopStatus()
        msg.header.stamp = self._now().to_msg()
        msg.state, msg.task, msg.reason = self.state, self.task, self.reason
        if self.tele is not None:
            sched = self.tele.schedule
            msg.waypoint_count = len(sched.waypoints)
            msg.final_waypoint = [float(v) for v in sched.final]
            if self.t0 is not None:
                # the episode's time limit (a task with the hand has a schedule per phase, each
                # with the time left when it began); once it ended, its length: every later status
                # says when it ended, so a reader that missed the first one still knows (lockstep)
                until = self.t_end if self.t_end is not None and self.state not in ACTIVE else self._now()
                msg.elapsed = min((until - self.t0).nanoseconds * 1e-9, self._episode_limit)
            if self.last_step is not None:
                msg.waypoint_index = int(self.last_step.waypoint_index)
                msg.waypoint = [float(v) for v in sched.waypoints[self.last_step.waypoint_index]]
                msg.axis = float(self.last_step.axis) if self.state == TeleopStatus.RUNNING else 0.0
                d = self.last_step.distance
                msg.distance = float(d) if math.isfinite(d) else 0.0
        self.status_pub.publish(msg)

    def on_shutdown(self) -> None:
        """Release the stick (run_node calls this while the context is still valid)."""
        self._publish_joy(0.0)


def main(args: list[str] | None = None) -> int:
    return run_node(SimTeleoperatorNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())

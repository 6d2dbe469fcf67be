"""`--mode graph`: the graph users launch, `vla_evaluation demo.launch.yaml`, driven like a person drives it.

The launch file starts, through vla_launch (the same Launcher, parameter files and commands as
`vla launch vla_evaluation demo.launch.yaml`):
  panda_bridge (MuJoCo physics, safety layer, camera rendering, /clock at `real_time_factor`)
  detector_node (ONNX detector on the rendered images)
  controller_node (latent-action decoder; joy -> joint_velocity_cmd)
  sim_teleoperator (the paper's simulated user; publishes joy)
all but the bridge on simulated time, so the graph runs faster than real time and stays consistent.
In lockstep (the default, `GraphConfig.lockstep`) the bridge owns time: it moves one joint state at a
time, once the controller has answered it, and the controller answers once the teleoperator's joy for
that state is in (vla_common.lockstep); the outcome and every measure of an episode are then a
function of its seeds and the code, whatever the machine's load. What is fixed at startup (rates,
real-time factor, models) goes in as launch arguments; the teleoperator's and the controller's
settings and a model change go through their parameter services.

This process hosts a small orchestrator node: per episode it resets the scene to a fresh layout
through the bridge's `~/reset`, waits for detections of the new scene, asks the controller to latch
them (`~/redetect`), starts the teleoperator on the task, and measures: final state error, success
from the ground-truth `scene/objects`, time to success, the bridge's safety interventions
(`~/status`) and limit violations measured on `joint_states`, plus the TCP path and camera frames.
"""
from __future__ import annotations

import bisect
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger
from vla_common.catalogue import TaskSpec, load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import JOINT_NAMES, READY_POSE
from vla_common.ros.convert import reset_request
from vla_common.ros.qos import IMAGE_QOS, SENSOR_QOS
from vla_common.tasks import parse_task

from vla_evaluation.graph_runner import GraphRunner
from vla_evaluation.kinematic import TeleopSettings, plan_waypoints, plannable_layout
from vla_evaluation.lockstep_client import (
    LockstepClient,
    await_detector,
    lockstep_says,
    stamp_ns,
    steps_to_grid,
)
from vla_evaluation.metrics import (
    EpisodeResult,
    LimitMonitor,
    SafetyTally,
    SuccessTracker,
    final_state_error,
    judge_task,
)
from vla_interfaces.msg import (
    ControllerStatus,
    DetectionArray,
    SafetyStatus,
    SceneObjectArray,
    TeleopStatus,
)
from vla_interfaces.srv import ResetScene, StartEpisode

BRIDGE, DETECTOR, CONTROLLER, TELEOP = "panda_bridge", "detector_node", "controller_node", "sim_teleoperator"
LAUNCH_FILE = ("vla_evaluation", "demo.launch.yaml")
CAMERA_SIZE = (640, 480)  # the bridge's camera (config/panda_bridge.yaml)
# Lockstep: the fixed counts of steps between what the orchestrator does (vla_common.lockstep).
STARTUP_S = 0.2   # sim s run once at startup: every node's status published, nothing else moved
DETECTOR_FIRST_WAIT_S = 60.0  # wall s for the detections of the first frame once the detector listens
START_TRIES = 3               # launches of a lockstep graph whose detector missed its first frame
FINAL_S = 0.1     # sim s after an episode's end before its final state is read (the next scene update)
RELIABLE = 1000   # lockstep: the orchestrator's subscriptions keep every message (reliable, this deep)


class GraphError(RuntimeError):
    """The graph could not be started or an episode could not be run; the message says why."""


class FirstFrameMissedError(GraphError):
    """A lockstep graph's detector did not answer its first frame: launched again (GraphEvaluator.start)."""


@dataclass
class GraphConfig:
    model_path: str
    detector_model: str
    real_time_factor: float = 0.0  # 0: as fast as the CPU allows (lockstep); paced for a person above 0
    lockstep: bool = False  # the simulation waits for the controller every step: results repeat at any load
    rate: float = 100.0  # controller and teleoperator (Hz of sim time)
    state_rate: float = 100.0
    camera_rate: float = 5.0
    settle_time: float = 0.5  # sim seconds after a reset before the first detection counts
    settings: TeleopSettings = field(default_factory=lambda: TeleopSettings(rate=100.0))
    stop_on_success: bool = False  # end an episode early (after `linger` s) once the task succeeded
    linger: float = 1.0
    keep_frames: bool = False  # keep camera frames (for the demo video)
    log_dir: Path | None = None
    domain_id: int | None = None  # None: keep ROS_DOMAIN_ID if set, else pick a random free-ish one
    startup_timeout: float = 90.0
    # The controller's joy timeout (sim s): above its 0.1 s default so that a busy 2-core machine
    # stalling a process for a moment does not zero the command mid-episode.
    joy_timeout: float = 0.25
    log_level: str = "info"
    extra_params: dict[str, dict] = field(default_factory=dict)  # node -> run-time parameters
    catalogue: str = ""  # object catalogue YAML ("": the default): the scene, detector and teleoperator
    operator_port: int | None = None  # also start the operator station on 127.0.0.1:port (None: not)
    record_dir: Path | None = None  # also start the recorder (one bag per ~/start_episode) into this folder
    # start the simulated user (the oracle); False where another node drives (the study's participant):
    # an idle teleoperator still follows joint_states and loads every model the controller is given
    teleoperator: bool = True

    def launch_arguments(self) -> dict[str, object]:
        """demo.launch.yaml's arguments: what the nodes read once, at startup."""
        station = ({} if self.operator_port is None else
                   {"use_operator_station": True, "operator_port": int(self.operator_port)})
        if self.record_dir is not None:
            station.update(use_recorder=True, record_dir=str(Path(self.record_dir).absolute()))
        if not self.teleoperator:
            station["use_teleoperator"] = False
        return {"catalogue": str(Path(self.catalogue).absolute()) if self.catalogue else "",
                "use_sim_time": True, "real_time_factor": float(self.real_time_factor),
                "lockstep": bool(self.lockstep), "lockstep_hold": bool(self.lockstep),
                "state_rate": float(self.state_rate), "camera_rate": float(self.camera_rate),
                "rate": float(self.rate), "detector_model": str(self.detector_model),
                "controller_model": str(self.model_path), "log_level": self.log_level, **station}

    def node_parameters(self) -> dict[str, dict]:
        """Run-time parameters set through the nodes' parameter services once the graph is up. The
        teleoperator's stick mapping is the controller's, so that it predicts what the controller does."""
        s = self.settings
        stick = {"deadband": float(s.deadband), "axis_scale": float(s.axis_scale),
                 "action_scale": float(s.action_scale), "max_joint_speed": float(s.max_joint_speed),
                 "path_fraction": float(s.path_fraction)}
        params = {
            CONTROLLER: {"goal_selection": s.goal_selection, "joy_timeout": float(self.joy_timeout), **stick},
            TELEOP: {"horizon": float(s.horizon), "n_candidates": int(s.n_candidates),
                     "switch_time": float(s.switch_time), "time_limit": float(s.time_limit),
                     "max_stick_rate": float(s.max_stick_rate), "hold": float(s.hold),
                     "fine_align": bool(s.fine_align), **stick},
        }
        for node, extra in self.extra_params.items():
            params.setdefault(node, {}).update(extra)
        if not self.teleoperator:
            params.pop(TELEOP, None)
        return params

    def steps(self, seconds: float) -> int:
        """Lockstep: the steps (joint states) in `seconds` of simulated time."""
        return max(0, round(seconds * self.state_rate))

    def frame_steps(self) -> int:
        """Lockstep: the steps between camera frames (the bridge counts them from each reset)."""
        return max(1, round(self.state_rate / self.camera_rate)) if self.camera_rate > 0 else 0

    def model_nodes(self) -> tuple[str, ...]:
        """The nodes that load the latent model (its `model_path`)."""
        return (CONTROLLER, TELEOP) if self.teleoperator else (CONTROLLER,)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def image_to_rgb(msg: Image) -> np.ndarray | None:
    """An rgb8/bgr8 Image as an (H, W, 3) RGB array, or None for another encoding."""
    if msg.encoding not in ("rgb8", "bgr8"):
        return None
    a = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :msg.width * 3]
    a = a.reshape(msg.height, msg.width, 3)
    return (a[:, :, ::-1] if msg.encoding == "bgr8" else a).copy()


class GraphObserver:
    """The orchestrator's ROS side: subscriptions, service clients and the latest values seen."""

    def __init__(self, ctx, keep_frames: bool, use_sim_time: bool = True, lockstep: bool = False) -> None:
        """`use_sim_time`: follow /clock (a simulated graph); False on a real robot's graph. `lockstep`:
        keep every message (reliable), since what an episode measures is everything the bridge sent."""
        self.node = Node("vla_evaluation", context=ctx,
                         parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, use_sim_time)])
        self.cond = threading.Condition()
        self.q = None
        self.dq = None
        self.q_stamp = -math.inf
        self.objects: dict[str, ObjectPose] = {}
        self.objects_stamp = -math.inf
        self.detections = None
        self.detections_stamp = -math.inf
        self.ctrl = None
        self.ctrl_recv = -math.inf
        self.teleop = None
        self.teleop_recv = -math.inf
        self._teleop_seen: deque = deque(maxlen=64)   # (stamp, status): the trace pairs states by stamp
        self.safety = None
        self.monitor: EpisodeMonitor | None = None
        n, sensor = self.node, (RELIABLE if lockstep else SENSOR_QOS)
        n.create_subscription(JointState, "joint_states", self._joints, sensor)
        n.create_subscription(SceneObjectArray, "scene/objects", self._objects, sensor)
        n.create_subscription(DetectionArray, "detections", self._dets, sensor)
        n.create_subscription(ControllerStatus, f"{CONTROLLER}/status", self._ctrl, sensor)
        n.create_subscription(TeleopStatus, f"{TELEOP}/status", self._teleop, sensor)
        n.create_subscription(SafetyStatus, f"{BRIDGE}/status", self._safety, sensor)
        if keep_frames:
            n.create_subscription(Image, "camera/image_raw", self._image, IMAGE_QOS)
        self.reset_cli = n.create_client(ResetScene, f"{BRIDGE}/reset")
        # lockstep: run the simulation a count of steps at a time (before spinning: the executor takes
        # the node's entities as they are then)
        self.steps = LockstepClient(n, self.cond, lambda: self.q_stamp, GraphError) if lockstep else None
        self.redetect_cli = n.create_client(Trigger, f"{CONTROLLER}/redetect")
        self.start_cli = n.create_client(StartEpisode, f"{TELEOP}/start_episode")
        self.stop_cli = n.create_client(Trigger, f"{TELEOP}/stop")
        self.param_clis = {name: n.create_client(SetParameters, f"{name}/set_parameters")
                           for name in (CONTROLLER, TELEOP)}

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def _joints(self, msg) -> None:
        names = list(msg.name)
        try:
            idx = [names.index(n) for n in JOINT_NAMES]
        except ValueError:
            return
        q = np.array([msg.position[i] for i in idx])
        dq = np.array([msg.velocity[i] for i in idx]) if len(msg.velocity) == len(names) else None
        with self.cond:
            self.q, self.dq, self.q_stamp = q, dq, _stamp(msg)
            self.cond.notify_all()
        if (m := self.monitor) is not None:
            m.on_joint_state(stamp_ns(msg), q, dq)
        self.on_state(msg)

    def on_state(self, msg: JointState) -> None:
        """Each joint state, after the measurements: a subclass that answers it in lockstep (the study's
        participant publishes its Joy for it) does so here, in the order the states came."""

    def _objects(self, msg) -> None:
        # with the height: a pick-and-place is judged put down (an object held over its target is not)
        objs = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw, o.pose.position.z) for o in msg.objects}
        with self.cond:
            self.objects, self.objects_stamp = objs, _stamp(msg)
            self.cond.notify_all()
        if (m := self.monitor) is not None:
            m.on_objects(stamp_ns(msg), objs)

    def _dets(self, msg) -> None:
        with self.cond:
            self.detections, self.detections_stamp = msg, _stamp(msg)
            self.cond.notify_all()

    def _ctrl(self, msg) -> None:
        with self.cond:
            self.ctrl, self.ctrl_recv = msg, self.now()
            self.cond.notify_all()

    def _teleop(self, msg) -> None:
        with self.cond:
            self.teleop, self.teleop_recv = msg, self.now()
            self._teleop_seen.append((stamp_ns(msg), msg))
            if (m := self.monitor) is not None:
                m.on_teleop(stamp_ns(msg), msg)
            self.cond.notify_all()

    def watch(self, monitor: EpisodeMonitor | None) -> None:
        """Measure an episode with `monitor` (None: stop); it starts with the statuses already seen, as
        the first states of the episode pair with a status from before it."""
        with self.cond:
            if monitor is not None:
                for stamp, msg in self._teleop_seen:
                    monitor.on_teleop(stamp, msg)
            self.monitor = monitor

    def _safety(self, msg) -> None:
        with self.cond:
            self.safety = msg
        if (m := self.monitor) is not None:
            m.on_safety(msg)

    def _image(self, msg) -> None:
        m = self.monitor
        if m is not None and m.keep_frames and (frame := image_to_rgb(msg)) is not None:
            m.on_frame(stamp_ns(msg), frame)

    def wait_for(self, predicate: Callable[[], bool], timeout: float, what: str,
                 alive: Callable[[], None] | None = None) -> None:
        deadline = time.monotonic() + timeout
        with self.cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise GraphError(f"timed out after {timeout:.0f} s waiting for {what}")
                self.cond.wait(min(left, 0.5))
                if alive is not None:
                    self.cond.release()
                    try:
                        alive()
                    finally:
                        self.cond.acquire()

    def call(self, client, request, timeout: float, what: str):
        return self.request(client, request, timeout, what)()

    def request(self, client, request, timeout: float, what: str) -> Callable[[], object]:
        """Send a service request now; the returned function waits for (at most `timeout`) and gives
        its response, so that the caller can do other work while the service answers."""
        if not client.wait_for_service(timeout_sec=timeout):
            raise GraphError(f"service {client.srv_name} not available ({what})")
        done = threading.Event()
        fut = client.call_async(request)
        fut.add_done_callback(lambda _f: done.set())

        def response():
            if not done.wait(timeout):
                raise GraphError(f"service {client.srv_name} did not answer within {timeout:.0f} s ({what})")
            return fut.result()
        return response

    def set_parameters(self, node: str, values: dict, timeout: float = 10.0) -> None:
        """Set run-time parameters of a node through its parameter service; GraphError if refused."""
        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        res = self.call(self.param_clis[node], req, timeout, f"setting {sorted(values)}")
        refused = [f"{k}: {r.reason}" for k, r in zip(values, res.results) if not r.successful]
        if refused:
            raise GraphError(f"{node} refused parameters: {'; '.join(refused)}")


@dataclass
class EpisodeRecord:
    """What an episode leaves besides its metrics: the TCP path and camera frames (for the demo)."""

    result: EpisodeResult
    tcp_path: np.ndarray  # (T, 3) TCP positions
    tcp_times: np.ndarray  # (T,) s since the episode started
    frames: list[tuple[float, np.ndarray]] = field(default_factory=list)
    trace: np.ndarray | None = None  # (T, 11): t, q1..q7, stick, waypoint index, projected distance


class EpisodeMonitor:
    """What an episode is measured by, fed from the observer's callbacks from `start_ns` on: limit
    violations and the TCP path on joint_states, success on scene/objects, safety on the bridge's
    status, and the camera frames. Stamps in integer ns: an episode's times (`since`) are then the same
    floats whenever it runs (differences of seconds round by how long the graph has run: issue 33)."""

    def __init__(self, spec: TaskSpec, start_pose: ObjectPose, kin, path_every: int, keep_frames: bool):
        self.spec, self.kin, self.keep_frames = spec, kin, keep_frames
        self.tracker = SuccessTracker(spec, start_pose)
        self.limits = LimitMonitor()
        self.tally = SafetyTally()
        self.path: list[np.ndarray] = []
        self.path_t: list[float] = []
        self._states: list[tuple[float, int, np.ndarray]] = []  # (t, stamp ns, q) sampled for the trace
        self._teleop: list[tuple[int, float, int, float]] = []     # (stamp ns, stick, waypoint, distance)
        self.frames: list[tuple[float, np.ndarray]] = []
        self.start_ns: int | None = None   # the episode's start (its first step's stamp)
        self.every = max(1, int(path_every))
        self._count = 0

    @property
    def t_start(self) -> float:
        """The episode's start in seconds (inf until set)."""
        return math.inf if self.start_ns is None else self.start_ns * 1e-9

    @t_start.setter
    def t_start(self, seconds: float) -> None:
        self.start_ns = round(seconds * 1e9)

    def since(self, stamp_ns: int) -> float:
        """Seconds from the episode's start to `stamp_ns`."""
        return (int(stamp_ns) - self.start_ns) * 1e-9

    def _started(self, stamp_ns: int) -> bool:
        return self.start_ns is not None and stamp_ns >= self.start_ns

    def on_joint_state(self, stamp: int, q: np.ndarray, dq: np.ndarray | None) -> None:
        if not self._started(stamp):
            return
        self.limits.update(q, dq)
        self._count += 1
        if self._count % self.every == 0:
            t = self.since(stamp)
            self.path.append(self.kin.fk(q)[0])
            self.path_t.append(t)
            self._states.append((t, stamp, np.asarray(q, dtype=float)))

    def on_teleop(self, stamp: int, msg) -> None:
        """A teleoperator status (any time: the trace pairs by stamp once the episode is over)."""
        self._teleop.append((stamp, float(msg.axis), int(msg.waypoint_index), float(msg.distance)))

    @property
    def trace(self) -> list[list[float]]:
        """t, q1..q7, stick, waypoint index, projected distance: each sampled state with the
        teleoperator's latest status stamped before it (what it said when that state was published).
        Paired by stamp after the fact, not on arrival: the status and the state come from two writers,
        and which arrives first depends on the load."""
        said = sorted(self._teleop)
        stamps = [s[0] for s in said]
        rows = []
        for t, stamp, q in self._states:
            i = bisect.bisect_left(stamps, stamp) - 1
            if i >= 0:
                rows.append([t, *q, said[i][1], said[i][2], said[i][3]])
        return rows

    def on_objects(self, stamp: int, objs: dict[str, ObjectPose]) -> None:
        if self._started(stamp) and self.spec.object_class in objs:
            self.tracker.update(self.since(stamp), objs[self.spec.object_class])

    def on_safety(self, msg) -> None:
        self.tally.update(int(msg.code), int(msg.interventions), bool(msg.estop_active),
                          int(msg.commands_rejected))

    def on_frame(self, stamp: int, frame: np.ndarray) -> None:
        if self._started(stamp):
            self.frames.append((self.since(stamp), frame))


class GraphEvaluator:
    """Runs evaluation episodes on the live graph (use as a context manager)."""

    def __init__(self, config: GraphConfig, log: Callable[[str], None] = print,
                 observer: Callable[..., GraphObserver] = GraphObserver) -> None:
        """`observer(context, keep_frames)`: the orchestrator's node (a subclass may add publishers,
        as the user study's participant does)."""
        self.catalogue = load_catalogue(config.catalogue)
        self.config = config
        self.log = log
        self.observer = observer
        self.runner: GraphRunner[GraphObserver] | None = None
        self.reset_stamp = math.nan   # lockstep: the simulated time (s) of the last reset
        self.obs: GraphObserver | None = None
        self.kin = PandaKinematics()

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> GraphEvaluator:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        """Launch demo.launch.yaml, join its ROS domain, wait until every node answers, configure. A
        lockstep graph whose detector missed its first frame is closed and launched again (at most
        START_TRIES times): its controller would wait for that frame's detections (FirstFrameMissedError)."""
        for attempt in range(1, START_TRIES + 1):
            try:
                return self._start_once()
            except FirstFrameMissedError as e:
                if attempt == START_TRIES:
                    raise
                self.log(f"[graph] {e}; launching the graph again ({attempt + 1}/{START_TRIES})")

    def _start_once(self) -> None:
        cfg = self.config
        log_path = Path(cfg.log_dir) / "graph.log" if cfg.log_dir else None
        self.runner = GraphRunner(LAUNCH_FILE, cfg.launch_arguments(), domain=cfg.domain_id,
                                  log_path=log_path, error=GraphError)
        extra = {"lockstep": True} if cfg.lockstep else {}
        try:
            self.obs = self.runner.start(lambda ctx: self.observer(ctx, cfg.keep_frames, **extra))
            self.log(f"[graph] vla launch {' '.join(LAUNCH_FILE)} (ROS_DOMAIN_ID {self.runner.domain}, "
                     f"output in {self.runner.session.log_path})")
            if cfg.lockstep:
                st = self.obs.steps
                st.alive, st.unit = self.alive, 1.0 / cfg.state_rate
                st.why_hung = self._why_hung
                st.real_time_factor = cfg.real_time_factor
            self._wait_ready()
            self.configure()
        except BaseException:
            self.close()
            raise

    def alive(self) -> None:
        """GraphError when a process of the launch has ended, with its last output lines."""
        self.runner.alive()

    def _why_hung(self) -> str:
        """What the graph's nodes last said a lockstep step waited for (their log is gone with it)."""
        session = self.runner.session if self.runner is not None else None
        return lockstep_says(session.tail(lines=0)) if session is not None else ""

    def _wait_ready(self) -> None:
        obs, t = self.obs, self.config.startup_timeout
        t0 = time.monotonic()
        clients = (obs.reset_cli, obs.redetect_cli, *(obs.param_clis[n] for n in self.config.model_nodes()))
        if self.config.teleoperator:
            clients += (obs.start_cli,)
        if obs.steps is not None:
            clients += (obs.steps.client,)
        for cli in clients:
            while not cli.wait_for_service(timeout_sec=0.5):
                self.alive()
                if time.monotonic() - t0 > t:
                    raise GraphError(f"service {cli.srv_name} did not appear within {t:.0f} s")
        if obs.steps is not None:
            self._start_lockstep()
        obs.wait_for(lambda: obs.q is not None, t, "joint_states from the bridge", self.alive)
        obs.wait_for(lambda: obs.detections is not None, t, "detections from the detector", self.alive)
        obs.wait_for(lambda: obs.ctrl is not None, t, "the controller's status", self.alive)
        if self.config.teleoperator:
            obs.wait_for(lambda: obs.teleop is not None, t, "the teleoperator's status", self.alive)
        self.log(f"[graph] up in {time.monotonic() - t0:.1f} s")

    def _start_lockstep(self) -> None:
        """Lockstep: once the detector's subscription to the camera is seen, run STARTUP_S (every node
        answers and says its status), then make sure the detector sees a frame
        (lockstep_client.await_detector): once, as the controller counts every frame (a miss is a
        FirstFrameMissedError; `start` launches the graph again). The first steps render frames too,
        the last at the held step: run before the detector listened, one missed there would leave the
        controller waiting for it at the first episode (the likely cause of three hangs with the wait
        after the steps)."""
        obs, cfg = self.obs, self.config

        def listening() -> bool:   # the graph's discovery: polled by wait_for, bounded by its timeout
            topic = f"{obs.node.get_namespace().rstrip('/')}/camera/image_raw"
            return any(i.node_name == DETECTOR for i in obs.node.get_subscriptions_info_by_topic(topic))

        obs.wait_for(listening, cfg.startup_timeout, "the detector's subscription to the camera", self.alive)
        t_held = obs.steps.run(cfg.steps(STARTUP_S), "the graph's first steps")

        def reset() -> None:
            res = obs.call(obs.reset_cli, ResetScene.Request(use_seed=True, seed=0), 30.0, "reset")
            if not res.success:
                raise GraphError(f"reset refused: {res.message}")

        def detected(timeout: float) -> bool:
            try:
                obs.wait_for(lambda: obs.detections_stamp >= t_held, timeout,
                             "the detector's answer to a frame", self.alive)
                return True
            except GraphError:
                return False

        await_detector(reset, detected, lambda text: self.log(f"[graph] {text}"), FirstFrameMissedError,
                       tries=1, wait_s=DETECTOR_FIRST_WAIT_S)

    def configure(self) -> None:
        """Set the controller's and the teleoperator's run-time parameters from the config."""
        for node, values in self.config.node_parameters().items():
            self.obs.set_parameters(node, values)

    def close(self) -> None:
        if self.runner is not None:
            runner, self.runner = self.runner, None
            runner.close(self.log)

    def set_model(self, model_path: str) -> None:
        """Use another latent model: the controller and the teleoperator load it (their model_path)."""
        if str(model_path) == str(self.config.model_path):
            return
        for node in self.config.model_nodes():
            self.obs.set_parameters(node, {"model_path": str(model_path)}, timeout=30.0)
        self.config.model_path = str(model_path)
        self.log(f"[graph] {' and '.join(self.config.model_nodes())} now use {model_path}")

    # ------------------------------------------------------------------ episodes
    def run_episode(self, task: str, seed: int, label: str = "", n_objects: int = 1) -> EpisodeRecord:
        """Reset to the seeded layout of `task`, latch the context, let the teleoperator drive."""
        if not self.config.teleoperator:
            raise GraphError("run_episode needs the teleoperator (GraphConfig.teleoperator is False)")
        wall0 = time.monotonic()
        spec = parse_task(task, self.catalogue)
        used_seed, start_pose, q_now = self.reset_scene(spec, int(seed), n_objects)
        result = EpisodeResult(task=task, layout_seed=used_seed, mode="graph", model=label,
                               object_start=start_pose.to_dict())
        no_latch = self.latch()
        if no_latch:
            self._score_unlatched(result, spec, start_pose, q_now, no_latch)
            result.extra["wall_s"] = round(time.monotonic() - wall0, 2)
            return EpisodeRecord(result, np.zeros((0, 3)), np.zeros(0), [], np.zeros((0, 11)))
        result.detected_class = self.obs.ctrl.latched_class
        monitor = EpisodeMonitor(spec, start_pose, self.kin, round(self.config.state_rate / 20.0),
                                 self.config.keep_frames)
        self.obs.watch(monitor)
        try:
            final_wp, q_final, end_pose, duration = self._drive(task, monitor)
        finally:
            self.obs.watch(None)
        self._score(result, spec, monitor, start_pose, final_wp, q_final, end_pose, duration)
        result.extra["wall_s"] = round(time.monotonic() - wall0, 2)
        tcp = result.ee_path if result.ee_path is not None else np.zeros((0, 3))
        return EpisodeRecord(result, tcp, np.asarray(monitor.path_t[: len(tcp)]), monitor.frames,
                             np.asarray(monitor.trace))

    def reset_scene(self, spec: TaskSpec, seed: int, n_objects: int) -> tuple[int, ObjectPose, np.ndarray]:
        """A fresh plannable layout through the bridge's ~/reset, settled and detected; (the layout's
        seed, the goal object's pose, the arm's joint positions)."""
        obs, cfg = self.obs, self.config
        objects, _goal, _wps, used_seed = plannable_layout(self.kin, spec, spec.object_class, seed,
                                                            np.asarray(READY_POSE), n_objects,
                                                            catalogue=self.catalogue)
        res = obs.call(obs.reset_cli, reset_request(objects, READY_POSE), 30.0, "reset")
        if not res.success:
            raise GraphError(f"reset refused: {res.message}")
        if obs.steps is not None:   # a fixed count of steps: the scene settles, frames are rendered
            self.reset_stamp = obs.steps.stamp
            obs.steps.run(cfg.steps(cfg.settle_time), "the new scene to settle")
        else:
            settled = obs.now() + cfg.settle_time
            obs.wait_for(lambda: obs.detections_stamp >= settled and obs.objects_stamp >= settled,
                         30.0, "detections of the new scene", self.alive)
        with obs.cond:
            start_pose = obs.objects.get(spec.object_class)
            q_now = obs.q.copy()
        if start_pose is None:
            raise GraphError(f"{spec.object_class} missing from scene/objects after reset")
        return used_seed, start_pose, q_now

    def latch(self, attempts: int = 3, timeout: float = 10.0) -> str:
        """Ask the controller to latch the new scene's detection (retried); "" when it did, else why not."""
        obs = self.obs
        if obs.steps is not None:
            return self._latch_lockstep(attempts)
        why = ""
        for attempt in range(attempts):
            t_redetect = obs.now()
            obs.call(obs.redetect_cli, Trigger.Request(), 10.0, "redetect")
            try:
                obs.wait_for(lambda t0=t_redetect: obs.ctrl_recv > t0 and bool(obs.ctrl.latched_class)
                             and obs.ctrl.code != ControllerStatus.WAITING_FOR_DETECTION, timeout,
                             "the controller to latch a detection", self.alive)
                return ""
            except GraphError:
                with obs.cond:
                    st, dets = obs.ctrl, obs.detections
                    age = obs.now() - obs.detections_stamp
                seen = sorted({d.class_id for d in dets.detections}) if dets is not None else []
                why = (f"controller: code {st.code if st else '?'} ({st.reason if st else 'no status'}); "
                       f"last detections {age:.1f} s old: {seen}")
                self.log(f"[graph] no latch after redetect (attempt {attempt + 1}/{attempts}): {why}")
        return why

    def _latch_lockstep(self, attempts: int) -> str:
        """Lockstep: ~/redetect while held, then run to one step past the next camera frame (the
        controller waits for that frame's detections); "" when it latched, else why not."""
        obs, why = self.obs, ""
        for attempt in range(attempts):
            obs.call(obs.redetect_cli, Trigger.Request(), 10.0, "redetect")
            obs.steps.run(self.config.frame_steps() + 1, "the controller to latch a detection")
            with obs.cond:
                st, dets = obs.ctrl, obs.detections
            if st is not None and st.latched_class and st.code != ControllerStatus.WAITING_FOR_DETECTION:
                return ""
            seen = sorted({d.class_id for d in dets.detections}) if dets is not None else []
            why = (f"controller: code {st.code if st else '?'} ({st.reason if st else 'no status'}); "
                   f"last detections: {seen}")
            self.log(f"[graph] no latch after redetect (attempt {attempt + 1}/{attempts}): {why}")
        return why

    def _score_unlatched(self, result: EpisodeResult, spec: TaskSpec, start_pose: ObjectPose,
                         q_now: np.ndarray, why: str) -> None:
        """Like a person facing a controller that waits for a detection: nothing moves. The episode
        fails, its error measured against the planner's final waypoint."""
        result.note = f"no detection latched: {why}"
        result.success = False
        final_wp = plan_waypoints(self.kin, spec, start_pose, q_now, catalogue=self.catalogue)[-1]
        result.final_state_error = final_state_error(q_now, final_wp)
        self.log(f"[graph] {spec.name}: {result.note}")

    def _drive(self, task: str, monitor: EpisodeMonitor):
        """The simulated user takes the stick until the time limit (or success + linger); returns the
        final waypoint, the arm's and the object's final state, and the episode's duration (sim s)."""
        obs, cfg = self.obs, self.config
        if obs.steps is not None:
            return self._drive_lockstep(task, monitor)
        t_request = obs.now()
        res = obs.call(obs.start_cli, StartEpisode.Request(task=task), 10.0, "start_episode")
        if not res.success:
            raise GraphError(f"teleoperator refused {task}: {res.message}")
        # The previous episode's last status (DONE, same task) can still arrive after the request: the
        # first status of this episode is WAITING or RUNNING, or a FAILED that says it could not start
        # (one such stale DONE ended an episode of a 10-layout evaluation before it began). A
        # publisher's messages arrive in order, so once one of these is seen the rest are this episode's.
        def fresh() -> bool:
            st = obs.teleop
            return obs.teleop_recv > t_request and st.task == task and (
                st.state in (TeleopStatus.WAITING, TeleopStatus.RUNNING)
                or (st.state == TeleopStatus.FAILED and st.reason.startswith(("gave up", "cannot start"))))

        obs.wait_for(fresh, 30.0, "the teleoperator to take the episode", self.alive)
        started = (TeleopStatus.RUNNING, TeleopStatus.DONE, TeleopStatus.FAILED)
        obs.wait_for(lambda: obs.teleop_recv > t_request and obs.teleop.task == task
                     and obs.teleop.state in started, 30.0, "the teleoperator to start", self.alive)
        if obs.teleop.state == TeleopStatus.FAILED:
            raise GraphError(f"teleoperator failed to start {task}: {obs.teleop.reason}")
        monitor.start_ns = obs.now_ns() - round(float(obs.teleop.elapsed) * 1e9)

        def finished() -> bool:
            if obs.teleop.state in (TeleopStatus.DONE, TeleopStatus.FAILED) and obs.teleop_recv > t_request:
                return True
            tts = monitor.tracker.time_to_success
            return cfg.stop_on_success and tts is not None and monitor.since(obs.now_ns()) >= tts + cfg.linger

        wall_limit = cfg.settings.time_limit / max(cfg.real_time_factor, 0.05) * 4 + 60
        obs.wait_for(finished, wall_limit, f"the end of the {task} episode", self.alive)
        if obs.teleop.state == TeleopStatus.RUNNING:  # stopped early on success
            obs.call(obs.stop_cli, Trigger.Request(), 10.0, "stop")
        final_wp = np.asarray(obs.teleop.final_waypoint, float)
        t_end, t_end_ns = obs.now(), obs.now_ns()
        # let the arm come to rest and the last scene state arrive
        obs.wait_for(lambda: obs.objects_stamp > t_end and obs.q_stamp > t_end, 10.0, "final state",
                     self.alive)
        with obs.cond:
            q_final = obs.q.copy()
            end_pose = obs.objects.get(monitor.spec.object_class)
        return final_wp, q_final, end_pose, monitor.since(t_end_ns)

    def _drive_lockstep(self, task: str, monitor: EpisodeMonitor):
        """`_drive` in lockstep: the episode starts while the simulation holds, runs its time limit (in
        chunks of a scene update when it may stop on success) and FINAL_S more; only counts of steps."""
        obs, cfg = self.obs, self.config
        t_request = obs.steps.stamp
        res = obs.call(obs.start_cli, StartEpisode.Request(task=task), 10.0, "start_episode")
        if not res.success:
            raise GraphError(f"teleoperator refused {task}: {res.message}")

        def mine() -> bool:   # a status of this episode (the last one's, same task, is older)
            return obs.teleop is not None and obs.teleop.task == task and _stamp(obs.teleop) > t_request

        limit = cfg.steps(cfg.settings.time_limit)
        for _ in range(limit):          # it starts once its inputs are in (a step or a few)
            obs.steps.run(1, f"the teleoperator to start {task}")
            if mine() and obs.teleop.state != TeleopStatus.WAITING:
                break
        if not mine() or obs.teleop.state == TeleopStatus.FAILED:
            raise GraphError(f"teleoperator failed to start {task}: "
                             f"{obs.teleop.reason if obs.teleop else 'no status'}")
        monitor.start_ns = stamp_ns(obs.teleop) - round(float(obs.teleop.elapsed) * 1e9)
        chunk = (steps_to_grid(obs.steps.stamp_ns, monitor.start_ns, obs.steps.unit, cfg.steps(0.1))
                 if cfg.stop_on_success else limit)
        done = (TeleopStatus.DONE, TeleopStatus.FAILED)
        while obs.teleop.state not in done:
            obs.steps.run(max(1, chunk), f"the {task} episode")
            tts = monitor.tracker.time_to_success
            elapsed = monitor.since(obs.steps.stamp_ns)
            if cfg.stop_on_success and tts is not None and elapsed >= tts + cfg.linger:
                obs.call(obs.stop_cli, Trigger.Request(), 10.0, "stop")
                break
            chunk = cfg.steps(0.1)      # past the limit: the teleoperator's own end is a step or two on
        final_wp = np.asarray(obs.teleop.final_waypoint, float)
        # its end from what any of its final statuses says (elapsed stops there), not from the one that
        # came in: which arrives before the loop looks depends on the load (a test saw 3.1 s for 3.0 s)
        ended = obs.teleop.state in done
        t_end = monitor.start_ns + round(float(obs.teleop.elapsed) * 1e9) if ended else obs.steps.stamp_ns
        # the final state FINAL_S after the end, wherever the loop noticed it (within a chunk)
        left_s = (t_end - obs.steps.stamp_ns) * 1e-9 + FINAL_S
        obs.steps.run(cfg.steps(left_s), "the final state")
        with obs.cond:
            q_final = obs.q.copy()
            end_pose = obs.objects.get(monitor.spec.object_class)
        return final_wp, q_final, end_pose, monitor.since(t_end)

    @staticmethod
    def _score(result: EpisodeResult, spec: TaskSpec, m: EpisodeMonitor, start_pose: ObjectPose,
               final_wp: np.ndarray, q_final: np.ndarray, end_pose: ObjectPose | None,
               duration: float) -> None:
        """The episode's metrics from its final state and what the monitor saw."""
        if final_wp.shape == (7,):
            result.final_state_error = final_state_error(q_final, final_wp)
        if end_pose is not None:
            path_xy = np.asarray(m.path)[:, :2] if m.path else np.zeros((0, 2))
            ok, disp, ang = judge_task(spec, start_pose, end_pose, path_xy)
            result.success, result.displacement_m, result.angle_err_deg = ok, disp, ang
            result.object_end = end_pose.to_dict()
            if ok and m.tracker.time_to_success is None:
                m.tracker.time_to_success = duration
        result.time_to_success = m.tracker.time_to_success if result.success else None
        result.duration_s = round(duration, 3)
        result.safety_interventions = m.tally.interventions
        result.limit_violations = m.limits.violations
        result.extra.update({"max_speed_ratio": round(m.limits.max_speed_ratio, 3),
                             "estop": m.tally.estop_seen, "commands_rejected": m.tally.rejected,
                             "position_violations": m.limits.position_violations,
                             "velocity_violations": m.limits.velocity_violations,
                             "interventions_by_code": dict(m.tally.by_code)})
        result.ee_path = np.asarray(m.path) if m.path else None


def evaluate_graph(config: GraphConfig, tasks: Sequence[str], seeds: Sequence[int], label: str = "",
                   log: Callable[[str], None] = print, n_objects: int = 1,
                   on_episode: Callable[[EpisodeRecord], None] | None = None) -> list[EpisodeRecord]:
    """Start the graph once and run every (task, seed) episode on it."""
    records = []
    with GraphEvaluator(config, log) as ev:
        for task in tasks:
            for seed in seeds:
                rec = ev.run_episode(task, seed, label, n_objects)
                r = rec.result
                log(f"[graph] {task:28s} seed {r.layout_seed:>8d}  success {r.success!s:5s}  "
                    f"final state error {r.final_state_error:.3f} rad  "
                    f"time {r.time_to_success if r.time_to_success is not None else float('nan'):5.1f} s  "
                    f"interventions {r.safety_interventions}  violations {r.limit_violations}  "
                    f"({r.extra['wall_s']:.1f} s wall)")
                records.append(rec)
                if on_episode is not None:
                    on_episode(rec)
    return records

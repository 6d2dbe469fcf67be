"""`--mode graph`: the full node graph in separate processes, driven like a person would drive it.

Processes (installed executables, as `ros2 run` would start them):
  panda_bridge (MuJoCo physics, safety layer, camera rendering, /clock at `real_time_factor`)
  detector_node (ONNX detector on the rendered images)
  controller_node (latent-action decoder; joy -> joint_velocity_cmd)
  sim_teleoperator (the paper's simulated user; publishes joy)
all with use_sim_time, so the graph runs faster than real time and stays consistent.

This process hosts a small orchestrator node: per episode it resets the scene to a fresh layout
through the bridge's `~/reset`, waits for detections of the new scene, asks the controller to latch
them (`~/redetect`), starts the teleoperator on the task, and measures: final state error, success
from the ground-truth `scene/objects`, time to success, the bridge's safety interventions
(`~/status`) and limit violations measured on `joint_states`, plus the TCP path and camera frames.
"""
from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vla_evaluation.kinematic import TeleopSettings
from vla_evaluation.metrics import EpisodeResult, LimitMonitor, SafetyTally, SuccessTracker, final_state_error

BRIDGE, DETECTOR, CONTROLLER, TELEOP = "panda_bridge", "detector_node", "controller_node", "sim_teleoperator"
EXECUTABLES = {
    BRIDGE: ("vla_panda_bridge", "panda_bridge"),
    DETECTOR: ("vla_detector", "detector_node"),
    CONTROLLER: ("vla_latent_controller", "controller_node"),
    TELEOP: ("vla_evaluation", "sim_teleoperator"),
}


class GraphError(RuntimeError):
    """The graph could not be started or an episode could not be run; the message says why."""


@dataclass
class GraphConfig:
    model_path: str
    detector_model: str
    real_time_factor: float = 2.0
    rate: float = 100.0  # controller and teleoperator (Hz of sim time)
    state_rate: float = 100.0
    camera_rate: float = 5.0
    camera_size: tuple[int, int] = (640, 480)
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
    extra_params: dict[str, dict] = field(default_factory=dict)

    def node_params(self) -> dict[str, dict]:
        s = self.settings
        stick = {"deadband": s.deadband, "axis_scale": s.axis_scale, "action_scale": s.action_scale,
                 "max_joint_speed": s.max_joint_speed}
        params = {
            BRIDGE: {"backend": "mujoco", "real_time_factor": float(self.real_time_factor),
                     "state_rate": float(self.state_rate), "camera_rate": float(self.camera_rate),
                     "camera_width": int(self.camera_size[0]), "camera_height": int(self.camera_size[1])},
            DETECTOR: {"model_path": str(self.detector_model)},
            CONTROLLER: {"model_path": str(self.model_path), "rate": float(self.rate),
                         "goal_selection": s.goal_selection, "joy_timeout": float(self.joy_timeout), **stick},
            TELEOP: {"model_path": str(self.model_path), "rate": float(self.rate), "horizon": s.horizon,
                     "n_candidates": int(s.n_candidates), "switch_time": s.switch_time,
                     "time_limit": s.time_limit, "controller_status_topic": f"{CONTROLLER}/status",
                     "max_stick_rate": float(s.max_stick_rate), **stick},
        }
        for node, extra in self.extra_params.items():
            params.setdefault(node, {}).update(extra)
        for node in params:
            if node != BRIDGE:
                params[node]["use_sim_time"] = True
        return params


def executable(package: str, name: str) -> str:
    """Path of an installed executable, resolved through the ament index like `ros2 run`."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        prefix = get_package_prefix(package)
    except PackageNotFoundError:
        raise GraphError(f"package {package!r} is not installed (run `make setup`)") from None
    path = os.path.join(prefix, "lib", package, name)
    if not os.access(path, os.X_OK):
        raise GraphError(f"executable {path} not found (run `make setup`)")
    return path


def _yaml_params(node: str, params: dict) -> str:
    import yaml

    return yaml.safe_dump({node: {"ros__parameters": params}}, sort_keys=True)


class NodeProcesses:
    """Starts the four nodes as child processes and tears them down (SIGINT, then SIGTERM/SIGKILL)."""

    def __init__(self, config: GraphConfig, env: dict[str, str], workdir: Path,
                 log: Callable[[str], None] = print) -> None:
        self.config = config
        self.env = env
        self.workdir = workdir
        self.log = log
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: dict = {}

    def start(self, nodes: Sequence[str] = (BRIDGE, DETECTOR, CONTROLLER, TELEOP)) -> None:
        params = self.config.node_params()
        self.workdir.mkdir(parents=True, exist_ok=True)
        for node in nodes:
            pkg, exe = EXECUTABLES[node]
            pfile = self.workdir / f"{node}.params.yaml"
            pfile.write_text(_yaml_params(node, params[node]))
            cmd = [executable(pkg, exe), "--ros-args", "-r", f"__node:={node}", "--params-file", str(pfile)]
            logf = open(self.workdir / f"{node}.log", "a")  # noqa: SIM115 - closed in stop()
            self._logs[node] = logf
            self.procs[node] = subprocess.Popen(
                cmd, env=self.env, stdout=logf, stderr=subprocess.STDOUT, start_new_session=True
            )

    def check_alive(self) -> None:
        for node, p in self.procs.items():
            if p.poll() is not None:
                raise GraphError(f"{node} exited with code {p.returncode}; last log lines:\n"
                                 f"{self.tail(node)}")

    def tail(self, node: str, lines: int = 15) -> str:
        f = self.workdir / f"{node}.log"
        try:
            return "\n".join(f.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def stop(self, nodes: Sequence[str] | None = None, timeout: float = 5.0) -> None:
        """SIGINT (the nodes command zero and exit), then SIGTERM, then SIGKILL; all nodes by default.

        In reverse start order, one after the other: the teleoperator and the controller go first,
        while the bridge still publishes /clock (a node on sim time may only notice a signal when a
        timer fires), and the robot side goes last."""
        order = [n for n in (TELEOP, CONTROLLER, DETECTOR, BRIDGE) if n in self.procs]
        order += [n for n in self.procs if n not in order]
        names = [n for n in order if nodes is None or n in nodes]
        for node in names:
            p = self.procs.pop(node)
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.log(f"[graph] {node} ignored SIGINT; terminating")
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                    p.wait(3.0)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    try:
                        os.killpg(p.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    p.wait()
            f = self._logs.pop(node, None)
            if f is not None:
                f.close()

    def returncodes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.procs.items()}


def isolated_env(domain_id: int | None) -> dict[str, str]:
    """The children's environment: this one (ROS bootstrap variables kept), a ROS domain of our own
    unless one is set, localhost-only discovery."""
    env = dict(os.environ)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    elif "ROS_DOMAIN_ID" not in env:
        env["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(201, 232))
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("MUJOCO_GL", "egl")
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


class _Observer:
    """The orchestrator's ROS side: subscriptions, service clients and the latest values seen."""

    def __init__(self, ctx, keep_frames: bool) -> None:
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import qos_profile_sensor_data as sensor
        from sensor_msgs.msg import Image, JointState
        from std_srvs.srv import Trigger

        from vla_interfaces.msg import (
            ControllerStatus,
            DetectionArray,
            SafetyStatus,
            SceneObjectArray,
            TeleopStatus,
        )
        from vla_interfaces.srv import ResetScene, StartEpisode

        self.node = Node("vla_evaluation", context=ctx,
                         parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
        self.lock = threading.Lock()
        self.cond = threading.Condition(self.lock)
        self.keep_frames = keep_frames
        self.q = None
        self.dq = None
        self.q_stamp = -math.inf
        self.objects: dict = {}
        self.objects_stamp = -math.inf
        self.detections = None
        self.detections_stamp = -math.inf
        self.ctrl = None
        self.ctrl_recv = -math.inf
        self.teleop = None
        self.teleop_recv = -math.inf
        self.safety = None
        self.frame = None
        self.frame_stamp = -math.inf
        self.on_joint_state: Callable | None = None
        self.on_objects: Callable | None = None
        self.on_safety: Callable | None = None
        self.on_frame: Callable | None = None
        n = self.node
        n.create_subscription(JointState, "joint_states", self._joints, sensor)
        n.create_subscription(SceneObjectArray, "scene/objects", self._objects, sensor)
        n.create_subscription(DetectionArray, "detections", self._dets, sensor)
        n.create_subscription(ControllerStatus, f"{CONTROLLER}/status", self._ctrl, sensor)
        n.create_subscription(TeleopStatus, f"{TELEOP}/status", self._teleop, sensor)
        n.create_subscription(SafetyStatus, f"{BRIDGE}/status", self._safety, sensor)
        if keep_frames:
            n.create_subscription(Image, "camera/image_raw", self._image, sensor)
        self.reset_cli = n.create_client(ResetScene, f"{BRIDGE}/reset")
        self.redetect_cli = n.create_client(Trigger, f"{CONTROLLER}/redetect")
        self.start_cli = n.create_client(StartEpisode, f"{TELEOP}/start_episode")
        self.stop_cli = n.create_client(Trigger, f"{TELEOP}/stop")
        self.ResetScene, self.StartEpisode, self.Trigger = ResetScene, StartEpisode, Trigger

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    @staticmethod
    def _stamp(msg) -> float:
        return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def _joints(self, msg) -> None:
        names = list(msg.name)
        try:
            idx = [names.index(f"panda_joint{i}") for i in range(1, 8)]
        except ValueError:
            return
        q = np.array([msg.position[i] for i in idx])
        dq = np.array([msg.velocity[i] for i in idx]) if len(msg.velocity) == len(names) else None
        with self.cond:
            self.q, self.dq, self.q_stamp = q, dq, self._stamp(msg)
            self.cond.notify_all()
        if self.on_joint_state is not None:
            self.on_joint_state(self.q_stamp, q, dq)

    def _objects(self, msg) -> None:
        from vla_common.objects import ObjectPose

        objs = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw) for o in msg.objects}
        with self.cond:
            self.objects, self.objects_stamp = objs, self._stamp(msg)
            self.cond.notify_all()
        if self.on_objects is not None:
            self.on_objects(self.objects_stamp, objs)

    def _dets(self, msg) -> None:
        with self.cond:
            self.detections, self.detections_stamp = msg, self._stamp(msg)
            self.cond.notify_all()

    def _ctrl(self, msg) -> None:
        with self.cond:
            self.ctrl, self.ctrl_recv = msg, self.now()
            self.cond.notify_all()

    def _teleop(self, msg) -> None:
        with self.cond:
            self.teleop, self.teleop_recv = msg, self.now()
            self.cond.notify_all()

    def _safety(self, msg) -> None:
        with self.cond:
            self.safety = msg
        if self.on_safety is not None:
            self.on_safety(msg)

    def _image(self, msg) -> None:
        if msg.encoding not in ("rgb8", "bgr8"):
            return
        a = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :msg.width * 3]
        a = a.reshape(msg.height, msg.width, 3)
        if msg.encoding == "bgr8":
            a = a[:, :, ::-1]
        with self.cond:
            self.frame, self.frame_stamp = a.copy(), self._stamp(msg)
        if self.on_frame is not None:
            self.on_frame(self.frame_stamp, self.frame)

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
        if not client.wait_for_service(timeout_sec=timeout):
            raise GraphError(f"service {client.srv_name} not available ({what})")
        done = threading.Event()
        fut = client.call_async(request)
        fut.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise GraphError(f"service {client.srv_name} did not answer within {timeout:.0f} s ({what})")
        return fut.result()


@dataclass
class EpisodeRecord:
    """What an episode leaves besides its metrics: the TCP path and camera frames (for the demo)."""

    result: EpisodeResult
    tcp_path: np.ndarray  # (T, 3) TCP positions
    tcp_times: np.ndarray  # (T,) s since the episode started
    frames: list[tuple[float, np.ndarray]] = field(default_factory=list)
    trace: np.ndarray | None = None  # (T, 11): t, q1..q7, stick, waypoint index, projected distance


class GraphEvaluator:
    """Runs evaluation episodes on the live graph (use as a context manager)."""

    def __init__(self, config: GraphConfig, log: Callable[[str], None] = print) -> None:
        self.config = config
        self.log = log
        self.procs: NodeProcesses | None = None
        self.ctx = None
        self.executor = None
        self.obs: _Observer | None = None
        self._spin_thread: threading.Thread | None = None
        self.kin = None
        self._saved_env: dict[str, str | None] = {}

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> GraphEvaluator:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        import tempfile

        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from vla_common.kinematics import PandaKinematics

        cfg = self.config
        env = isolated_env(cfg.domain_id)
        # this process joins the same domain before its rclpy context exists
        for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
            self._saved_env[key] = os.environ.get(key)
            os.environ[key] = env[key]
        workdir = Path(cfg.log_dir) if cfg.log_dir else Path(tempfile.mkdtemp(prefix="vla_graph_"))
        self.kin = PandaKinematics()
        self.procs = NodeProcesses(cfg, env, workdir, self.log)
        self.log(f"[graph] starting bridge, detector, controller, teleoperator (ROS_DOMAIN_ID "
                 f"{env['ROS_DOMAIN_ID']}, logs in {workdir})")
        self.procs.start()
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.obs = _Observer(self.ctx, cfg.keep_frames)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.obs.node)
        self._spin_thread = threading.Thread(target=self._spin, daemon=True)
        self._spin_thread.start()
        try:
            self._wait_ready()
        except BaseException:
            self.close()
            raise

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            while self.ctx is not None and self.ctx.ok():
                self.executor.spin_once(timeout_sec=0.1)
        except (ExternalShutdownException, RuntimeError):
            pass

    def _wait_ready(self) -> None:
        obs, t = self.obs, self.config.startup_timeout
        alive = self.procs.check_alive
        t0 = time.monotonic()
        for cli in (obs.reset_cli, obs.redetect_cli, obs.start_cli):
            while not cli.wait_for_service(timeout_sec=0.5):
                alive()
                if time.monotonic() - t0 > t:
                    raise GraphError(f"service {cli.srv_name} did not appear within {t:.0f} s")
        obs.wait_for(lambda: obs.q is not None, t, "joint_states from the bridge", alive)
        obs.wait_for(lambda: obs.detections is not None, t, "detections from the detector", alive)
        obs.wait_for(lambda: obs.ctrl is not None, t, "the controller's status", alive)
        obs.wait_for(lambda: obs.teleop is not None, t, "the teleoperator's status", alive)
        self.log(f"[graph] up in {time.monotonic() - t0:.1f} s")

    def close(self) -> None:
        import rclpy

        if self.procs is not None:
            self.procs.stop()
        if self.ctx is not None:
            ctx, self.ctx = self.ctx, None
            try:
                if self.executor is not None:
                    self.executor.shutdown(timeout_sec=1.0)
                if self.obs is not None:
                    self.obs.node.destroy_node()
                rclpy.shutdown(context=ctx)
            except Exception:  # noqa: BLE001 - best-effort teardown
                pass
        if self._spin_thread is not None:
            self._spin_thread.join(timeout=2.0)
        for key, val in self._saved_env.items():
            if val is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = val

    def set_model(self, model_path: str) -> None:
        """Use another latent model: restart the controller and the teleoperator with it (the bridge
        and the detector keep running)."""
        if str(model_path) == str(self.config.model_path):
            return
        self.config.model_path = str(model_path)
        obs = self.obs
        self.procs.stop([CONTROLLER, TELEOP])
        t0 = obs.now()
        self.log(f"[graph] controller + teleoperator restarted with {model_path}")
        self.procs.start([CONTROLLER, TELEOP])
        alive = self.procs.check_alive
        for cli in (obs.redetect_cli, obs.start_cli):
            deadline = time.monotonic() + self.config.startup_timeout
            while not cli.wait_for_service(timeout_sec=0.5):
                alive()
                if time.monotonic() > deadline:
                    raise GraphError(f"service {cli.srv_name} did not come back")
        obs.wait_for(
            lambda: obs.ctrl_recv > t0 and obs.teleop_recv > t0,
            self.config.startup_timeout,
            "the restarted controller and teleoperator",
            alive,
        )

    # ------------------------------------------------------------------ episodes
    def run_episode(self, task: str, seed: int, label: str = "", n_objects: int = 1) -> EpisodeRecord:
        """Reset to the seeded layout of `task`, latch the context, let the teleoperator drive."""
        from vla_common.robot import READY_POSE
        from vla_common.tasks import parse_task

        from vla_evaluation.kinematic import _plannable_layout
        from vla_evaluation.metrics import judge_task

        cfg, obs, alive = self.config, self.obs, self.procs.check_alive
        spec = parse_task(task)
        wall0 = time.monotonic()
        objects, _goal, _wps, used_seed = _plannable_layout(self.kin, task, spec.object_class, int(seed),
                                                            np.asarray(READY_POSE), n_objects)
        result = EpisodeResult(task=task, layout_seed=used_seed, mode="graph", model=label)
        # 1. fresh layout through the bridge
        req = obs.ResetScene.Request()
        req.use_seed = False
        req.objects = [self._scene_object(o) for o in objects]
        req.initial_positions = [float(v) for v in READY_POSE]
        res = obs.call(obs.reset_cli, req, 30.0, "reset")
        if not res.success:
            raise GraphError(f"reset refused: {res.message}")
        t_reset = obs.now()
        # 2. detections of the new scene (after objects settled)
        settle_until = t_reset + cfg.settle_time
        obs.wait_for(lambda: obs.detections_stamp >= settle_until and obs.objects_stamp >= settle_until,
                     30.0, "detections of the new scene", alive)
        # 3. the controller latches them
        no_latch = self._latch(alive)
        with obs.cond:
            start_pose = obs.objects.get(spec.object_class)
            q_now = obs.q.copy()
        if start_pose is None:
            raise GraphError(f"{spec.object_class} missing from scene/objects after reset")
        result.object_start = start_pose.to_dict()
        if no_latch:
            # Like a person facing a controller that waits for a detection: nothing moves. The
            # episode counts as failed, its error measured against the planner's final waypoint.
            from vla_evaluation.kinematic import plan_waypoints

            result.note = f"no detection latched: {no_latch}"
            result.success = False
            final_wp = plan_waypoints(self.kin, task, start_pose, q_now)[-1]
            result.final_state_error = final_state_error(q_now, final_wp)
            result.extra["wall_s"] = round(time.monotonic() - wall0, 2)
            self.log(f"[graph] {task}: {result.note}")
            return EpisodeRecord(result, np.zeros((0, 3)), np.zeros(0), [], np.zeros((0, 11)))
        result.detected_class = obs.ctrl.latched_class
        # 4. monitors
        tracker = SuccessTracker(spec, start_pose)
        limits = LimitMonitor()
        tally = SafetyTally()
        path: list[np.ndarray] = []
        path_t: list[float] = []
        trace: list[list[float]] = []  # t, q1..q7, stick, waypoint index, projected distance
        frames: list[tuple[float, np.ndarray]] = []
        t_start = [math.inf]
        every = max(1, int(round(cfg.state_rate / 20.0)))
        counter = [0]

        def on_js(stamp, q, dq):
            if stamp < t_start[0]:
                return
            limits.update(q, dq)
            counter[0] += 1
            if counter[0] % every == 0:
                path.append(self.kin.fk(q)[0])
                path_t.append(stamp - t_start[0])
                st = obs.teleop
                if st is not None:
                    trace.append([stamp - t_start[0], *q, st.axis, st.waypoint_index, st.distance])

        def on_objects(stamp, objs):
            if stamp >= t_start[0] and spec.object_class in objs:
                tracker.update(stamp - t_start[0], objs[spec.object_class])

        def on_safety(msg):
            tally.update(int(msg.code), int(msg.interventions), bool(msg.estop_active),
                         int(msg.commands_rejected))

        def on_frame(stamp, frame):
            if stamp >= t_start[0]:
                frames.append((stamp - t_start[0], frame))

        obs.on_joint_state, obs.on_objects, obs.on_safety = on_js, on_objects, on_safety
        obs.on_frame = on_frame if cfg.keep_frames else None
        try:
            # 5. the simulated user takes the stick
            t_request = obs.now()
            sreq = obs.StartEpisode.Request()
            sreq.task = task
            res = obs.call(obs.start_cli, sreq, 10.0, "start_episode")
            if not res.success:
                raise GraphError(f"teleoperator refused {task}: {res.message}")
            obs.wait_for(lambda: obs.teleop_recv > t_request and obs.teleop.task == task
                         and obs.teleop.state in (2, 3, 4), 30.0, "the teleoperator to start", alive)
            if obs.teleop.state == 4:
                raise GraphError(f"teleoperator failed to start {task}: {obs.teleop.reason}")
            t_start[0] = obs.now() - float(obs.teleop.elapsed)
            wall_limit = cfg.settings.time_limit / max(cfg.real_time_factor, 0.05) * 4 + 60

            def finished() -> bool:
                st = obs.teleop
                if st.state in (3, 4) and obs.teleop_recv > t_request:
                    return True
                if cfg.stop_on_success and tracker.time_to_success is not None:
                    return obs.now() - t_start[0] >= tracker.time_to_success + cfg.linger
                return False

            obs.wait_for(finished, wall_limit, f"the end of the {task} episode", alive)
            if obs.teleop.state == 2:  # stopped early on success
                obs.call(obs.stop_cli, obs.Trigger.Request(), 10.0, "stop")
            final_wp = np.asarray(obs.teleop.final_waypoint, float)
            t_end = obs.now()
            # let the arm come to rest and the last scene state arrive
            obs.wait_for(lambda: obs.objects_stamp > t_end and obs.q_stamp > t_end, 10.0,
                         "final state", alive)
            with obs.cond:
                q_final = obs.q.copy()
                end_pose = obs.objects.get(spec.object_class)
        finally:
            obs.on_joint_state = obs.on_objects = obs.on_safety = obs.on_frame = None
        if final_wp.shape == (7,):
            result.final_state_error = final_state_error(q_final, final_wp)
        if end_pose is not None:
            path_xy = np.asarray(path)[:, :2] if path else np.zeros((0, 2))
            ok, disp, ang = judge_task(spec, start_pose, end_pose, path_xy)
            result.success, result.displacement_m, result.angle_err_deg = ok, disp, ang
            result.object_end = end_pose.to_dict()
            if ok and tracker.time_to_success is None:
                tracker.time_to_success = t_end - t_start[0]
        result.time_to_success = tracker.time_to_success if result.success else None
        result.duration_s = round(t_end - t_start[0], 3)
        result.safety_interventions = tally.interventions
        result.limit_violations = limits.violations
        result.extra.update({"wall_s": round(time.monotonic() - wall0, 2),
                             "max_speed_ratio": round(limits.max_speed_ratio, 3),
                             "estop": tally.estop_seen, "commands_rejected": tally.rejected,
                             "position_violations": limits.position_violations,
                             "velocity_violations": limits.velocity_violations,
                             "interventions_by_code": dict(tally.by_code)})
        result.ee_path = np.asarray(path) if path else None
        tcp = result.ee_path if result.ee_path is not None else np.zeros((0, 3))
        return EpisodeRecord(result, tcp, np.asarray(path_t[: len(tcp)]), frames, np.asarray(trace))

    def _latch(self, alive, attempts: int = 3, timeout: float = 10.0) -> str:
        """Ask the controller to latch the new scene's detection (retried); "" when it did, else why not."""
        obs = self.obs
        for attempt in range(attempts):
            t_redetect = obs.now()
            obs.call(obs.redetect_cli, obs.Trigger.Request(), 10.0, "redetect")
            try:
                obs.wait_for(lambda t0=t_redetect: obs.ctrl_recv > t0 and bool(obs.ctrl.latched_class)
                             and obs.ctrl.code != 5, timeout, "the controller to latch a detection", alive)
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

    @staticmethod
    def _scene_object(pose):
        from vla_interfaces.msg import SceneObject

        o = SceneObject()
        o.class_id, o.x, o.y, o.yaw = pose.class_id, float(pose.x), float(pose.y), float(pose.yaw)
        return o


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

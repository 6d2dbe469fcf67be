"""Simulated kinesthetic demonstrations, recorded through the graph users record with.

The person who backdrives the arm in the paper is replaced by a scripted demonstrator: per episode
the scene is reset through the bridge's `~/reset` (a task layout and a jittered start pose drawn
from the episode's random generator), the task is planned with Pinocchio from the object's
ground-truth pose (`vla_sim.planner.plan_task`, itself varied per episode: approach offset, push
height, tilt, speeds), and executed by publishing `joint_velocity_cmd` from every `joint_states`
message (event-driven, no timer). The graph is `vla_bringup record.launch.yaml`, started through
vla_launch exactly as `vla launch` starts it: the bridge, the detector node (whose detections the
bags hold) and the recorder node, which records each episode as it would a real one, its first camera
frame and detection before the arm moves. Success is judged on the ground-truth `scene/objects`
(`vla_common.tasks.task_success`); failed episodes are marked `discarded`.

Only the demonstrator runs in this process (all nodes on simulated time); everything between it and
the graph goes through ROS topics and services. In lockstep (the default; `--free-running` for the
real-time graph) the bridge waits every joint state for the demonstrator's answer (its command, in a
vla_interfaces/StepAnswer), the demonstrator holds the simulation at its plan's end, and the steps
between the reset, the recording's start, its first frame, the plan and the recorded tail are fixed
counts (vla_evaluation.lockstep_client): the same seeds give the same demonstrations at any load.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos import qos_profile_sensor_data as sensor
from sensor_msgs.msg import CameraInfo, JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from vla_common.catalogue import Catalogue, TaskSpec, load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import JOINT_NAMES
from vla_common.ros.convert import ns_from_stamp, reset_request
from vla_common.ros.domain import graph_on_domain
from vla_common.tasks import SPREAD_MARGIN, check_spread_margin, task_layout, task_success
from vla_demo_recorder.dataset import DemoError, load_demo
from vla_sim.planner import PlanError, plan_task, random_start_pose

from vla_evaluation.graph_runner import GraphRunner
from vla_evaluation.lockstep_client import LockstepClient, await_detector
from vla_evaluation.sweep import SERIAL, Engine, engine_from, run_sweep
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_interfaces.msg import DetectionArray, RecorderStatus, SafetyStatus, SceneObjectArray, StepAnswer
from vla_interfaces.srv import GripperCommand, ResetScene, StartEpisode

BRIDGE = "panda_bridge"
RECORDER = "recorder"
LAUNCH_FILE = ("vla_bringup", "record.launch.yaml")
RECORD_TAIL_S = 0.2  # s of simulated time recorded past the end of the plan and its settling
RECORDER_STATUS_PERIOD_S = 0.05  # the recorder's ~/status (its clock) while generating
STARTUP_S = 0.6  # lockstep: sim s run once at startup (every node's status, the recorder's at 0.5 s)
RESET_SETTLE_S = 0.2  # sim s after a reset before the scene is read (the arm and objects at rest)
# Wall s a wait for another node (the detector's detections, the recorder's clock, the scene) may take:
# only against a hang; at load ~150 on 2 cores the reset scene's detection took over 30 s
WAIT_S = 120.0
# The plan's own clock runs at simulated time while the arm follows it (largest joint error under
# the first value, rad), slows down beyond and stops at the second, so that a demonstrator that falls
# behind (a loaded machine: late commands, the bridge's watchdog stopping the arm) neither closes the
# hand above the object nor drags the arm after a reference far ahead (measured at real time beside
# two busy processes: 3 of 4 episodes kept before, the hand closed 2 cm over a can that was stopped).
PLAN_LAG = (0.03, 0.08)
# What the demonstrator asks of the hand for a plan's events (the planner leaves time for them).
HAND_REQUESTS = {
    "open": GripperCommand.Request(command=GripperCommand.Request.OPEN, speed=0.08),
    "grasp": GripperCommand.Request(command=GripperCommand.Request.GRASP, position=0.0, speed=0.08,
                                    max_effort=30.0, epsilon_inner=0.005, epsilon_outer=0.08),
}


def plan_pace(lag: float) -> float:
    """How fast the plan's clock runs (0..1) for the arm's largest joint error from the reference
    (rad): 1 within PLAN_LAG[0], falling linearly to 0 at PLAN_LAG[1]; 0 for a non-finite error."""
    lo, hi = PLAN_LAG
    if not math.isfinite(lag):
        return 0.0
    return min(1.0, max(0.0, (hi - lag) / (hi - lo)))


WORKER_FAILED = "the episode's worker failed (a graph that did not start?); see the log above"


class GenerateError(RuntimeError):
    """The graph could not be started or an episode could not run; the message says why."""


@dataclass
class GenerateConfig:
    tasks: list[TaskSpec]  # parsed once, from the catalogue
    episodes: int = 10  # per task
    out: Path = Path("demos")
    seed: int = 0
    real_time_factor: float = 0.0  # simulation speed at most; 0 = as fast as possible
    lockstep: bool = True  # the bridge waits for the demonstrator every joint state (the same at any load)
    # joint_states (Hz of sim time): 5x the demonstrations' 10 Hz.
    state_rate: float = 50.0
    camera_rate: float = 5.0
    image_every_n: int = 1000  # keep the first frame of an episode (and every n-th after)
    settle: float = 0.6  # sim seconds of zero command after the plan, before judging
    detector_model: str | None = None  # None or "": the detector node's shipped model
    keep_failed: bool = True  # failed episodes stay on disk, marked discarded
    max_plan_tries: int = 5
    startup_timeout: float = 90.0
    domain_id: int | None = None
    log_dir: Path | None = None
    catalogue: str = ""  # the object catalogue YAML ("": the default); the scene and recorder read it
    # tasks with the hand: the k-th episode's object near the k-th spread point of its region
    # (vla_common.tasks.SPREAD_POINTS: corners and centre, as a teacher places it) instead of anywhere
    spread: bool = False
    spread_margin: float = SPREAD_MARGIN  # m: the spread points on the region grown by this (tasks.py)

    def launch_arguments(self) -> dict[str, object]:
        """record.launch.yaml's arguments."""
        return {"catalogue": str(Path(self.catalogue).absolute()) if self.catalogue else "",
                "use_sim_time": True, "real_time_factor": float(self.real_time_factor),
                "lockstep": bool(self.lockstep),
                "state_rate": float(self.state_rate), "camera_rate": float(self.camera_rate),
                "image_every_n": int(self.image_every_n), "output_dir": str(Path(self.out).absolute()),
                "detector_model": str(self.detector_model or "")}


@dataclass
class EpisodeRecord:
    index: int
    task: str
    seed: int
    bag: str = ""
    success: bool = False
    displacement: float = float("nan")
    angle_err_deg: float = float("nan")
    duration_s: float = 0.0
    wall_s: float = 0.0
    detection: dict | None = None
    plan_params: dict = field(default_factory=dict)
    replans: int = 0
    spread_point: int | None = None  # the spread point of the layout (GenerateConfig.spread)
    error: str = ""


def parse_tasks(items: list[str], tasks_file: Path | None, catalogue: Catalogue) -> list[TaskSpec]:
    """The catalogue's tasks named by --task options and a file (one per line, # comments); the
    catalogue's base tasks if none. Parsed here, once; they travel as TaskSpecs."""
    names = list(items)
    if tasks_file is not None:
        for line in Path(tasks_file).read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if line:
                names.append(line)
    return [catalogue.task(n) for n in names] if names else catalogue.task_set("base")


def _stamp(msg) -> float:
    return _stamp_of(msg.header.stamp)


def _stamp_of(t) -> float:
    return t.sec + t.nanosec * 1e-9


class Demonstrator:
    """The demonstrator's ROS side: joint state in, velocity command out; the scene's ground truth,
    the detections and the recorder's status as they arrive; clients of the bridge and the recorder."""

    def __init__(self, context, lockstep: bool = False) -> None:
        """`lockstep`: answer every joint state (the bridge's lockstep) with the command in a StepAnswer,
        keep every message (reliable), and hold the simulation at a plan's end."""
        self.node = Node("demonstrator", context=context,
                         parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)])
        n = self.node
        self.cond = threading.Condition()
        self.q: np.ndarray | None = None
        self.q_stamp = -math.inf
        self.objects: dict[str, ObjectPose] = {}
        self.objects_stamp = -math.inf
        self.detections_stamp = -math.inf
        # Lockstep, while recording: a state is answered only once the frames before it are detected, so
        # the detector never skips one (its queue keeps the newest) and the bag holds every frame's.
        self.frame_stamp = -math.inf       # the last camera frame's (its camera_info's) stamp
        self.await_frames = False
        self.pending: StepAnswer | None = None   # an answer held until the frames' detections are in
        self.recorder: RecorderStatus | None = None
        self.recorder_stamp = -math.inf  # the recorder's clock, from its ~/status
        self.plan = None
        self.plan_t0: float | None = None
        self.plan_wall = 0                 # stamp (ns) of the last joint state the plan's clock advanced on
        self.plan_clock = 0.0              # the plan's own time (s), see _advance_plan_clock
        self.pace = 1.0
        self.plan_failure = ""             # why the running plan was abandoned (a reflex)
        self.plan_end = math.inf
        self.plan_done = threading.Event()
        self.commands = 0
        self.hand_sent = 0                # the plan's hand events sent so far
        self.hand_replies: list[str] = []
        self.heights: list[tuple[float, float]] = []   # (sim s, the task object's z) while a plan runs
        self.track: str | None = None
        # The bridge waits for a zero command after a stop (e.g. its watchdog, when this process fell
        # behind): the demonstrator sends one, as the arming rule asks (vla_common.arming).
        self.send_zero = True
        self.cmd_pub = n.create_publisher(Float64MultiArray, "joint_velocity_cmd",
                                          QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        qos = 1000 if lockstep else sensor       # lockstep: every message (reliable), a lost one a hang
        self.answer_pub = n.create_publisher(StepAnswer, "lockstep/answer", 100) if lockstep else None
        self.steps = LockstepClient(n, self.cond, lambda: self.q_stamp, GenerateError) if lockstep else None
        self.reset_stamp = math.nan       # lockstep: the simulated time (s) of the last reset
        n.create_subscription(JointState, "joint_states", self._on_joints, qos)
        n.create_subscription(SceneObjectArray, "scene/objects", self._on_objects, qos)
        n.create_subscription(DetectionArray, "detections", self._on_detections, qos)
        if lockstep:
            n.create_subscription(CameraInfo, "camera/camera_info", self._on_frame, qos)
        n.create_subscription(RecorderStatus, f"{RECORDER}/status", self._on_recorder, qos)
        n.create_subscription(SafetyStatus, f"{BRIDGE}/status", self._on_safety, 10)
        self.reset_cli = n.create_client(ResetScene, f"{BRIDGE}/reset")
        self.start_cli = n.create_client(StartEpisode, f"{RECORDER}/start_episode")
        self.stop_cli = n.create_client(Trigger, f"{RECORDER}/stop_episode")
        self.discard_cli = n.create_client(Trigger, f"{RECORDER}/discard_episode")
        self.recorder_params_cli = n.create_client(SetParameters, f"{RECORDER}/set_parameters")
        self.gripper_cli = n.create_client(GripperCommand, f"{BRIDGE}/gripper")

    def _on_joints(self, msg) -> None:
        names = list(msg.name)
        try:
            q = np.array([msg.position[names.index(j)] for j in JOINT_NAMES])
        except (ValueError, IndexError):
            return
        t, t_ns = _stamp(msg), ns_from_stamp(msg.header.stamp)
        with self.cond:
            self.q, self.q_stamp = q, t
            self.cond.notify_all()
        plan = self.plan
        if plan is None:
            self._answer(msg, [])        # lockstep: no plan, no command (the bridge's watchdog holds)
            return
        if self.plan_t0 is None:
            self.plan_t0, self.plan_wall = t, t_ns
        elapsed = self.plan_clock = self._advance_plan_clock(plan, t_ns, q)
        dq = plan.command(elapsed, q, self.pace) if elapsed <= plan.duration else np.zeros(7)
        if self.send_zero:
            self.send_zero, dq = False, np.zeros(7)
        self._hand_events(plan, elapsed)
        self.commands += 1
        if elapsed >= self.plan_end:
            self.plan = None
            if self.steps is not None:   # the simulation holds right here, the plan done
                self.steps.hold_after(ns_from_stamp(msg.header.stamp), 0)
            self.plan_done.set()
        if self.answer_pub is None:
            self.cmd_pub.publish(Float64MultiArray(data=[float(v) for v in dq]))
        else:
            self._answer(msg, [float(v) for v in dq])

    def _answer(self, msg, command: list[float]) -> None:
        """Lockstep: this joint state's answer (after everything the step sent), held while recording
        until the detections of the frames published before it are in."""
        if self.answer_pub is None:
            return
        answer = StepAnswer(header=msg.header, node="demonstrator", command=command)
        with self.cond:
            if self.await_frames and self.frame_stamp > self.detections_stamp:
                self.pending, answer = answer, None
        if answer is not None:
            self.answer_pub.publish(answer)

    def await_detections(self, on: bool) -> None:
        """Lockstep: hold answers for the frames' detections (while recording) or not (a held answer
        goes out)."""
        with self.cond:
            self.await_frames = on
        if not on:
            self._release()

    def _release(self) -> None:
        with self.cond:
            answer, self.pending = self.pending, None
        if answer is not None:
            self.answer_pub.publish(answer)

    def _on_frame(self, msg) -> None:
        with self.cond:
            self.frame_stamp = max(self.frame_stamp, _stamp(msg))

    def _hand_events(self, plan, elapsed: float) -> None:
        """The plan's hand events due at its time `elapsed` (the bridge's gripper service)."""
        events = plan.hand_events
        while self.hand_sent < len(events) and events[self.hand_sent][0] <= elapsed:
            future = self.gripper_cli.call_async(HAND_REQUESTS[events[self.hand_sent][1]])
            future.add_done_callback(self._on_hand_reply)
            self.hand_sent += 1

    def _advance_plan_clock(self, plan, t_ns: int, q: np.ndarray) -> float:
        """The plan's time at this joint state (stamp t_ns): advanced by the simulated time since the last
        state at `pace` (1 while the arm follows the reference, down to 0 as it lags, PLAN_LAG; 0
        while the bridge waits for a zero command); at the simulated time's rate past the plan's end.
        The step from integer stamps: the same plan whatever simulated time the episode starts at."""
        dt = max(0, t_ns - self.plan_wall) * 1e-9
        self.plan_wall = t_ns
        if self.plan_clock >= plan.duration:
            self.pace = 1.0
        else:
            lag = float(np.max(np.abs(plan.reference(self.plan_clock)[0] - q)))
            self.pace = 0.0 if self.send_zero else plan_pace(lag)
        return self.plan_clock + dt * self.pace

    def _on_safety(self, msg) -> None:
        if msg.code == SafetyStatus.AWAITING_ZERO:
            self.send_zero = True
        elif msg.code == SafetyStatus.REFLEX and self.plan is not None:
            # the arm holds until a recovery (the next reset clears it): the plan cannot go on
            self.plan, self.plan_failure = None, f"robot reflex during the plan: {msg.text}"
            self.plan_done.set()

    def _on_hand_reply(self, future) -> None:
        res = future.result()
        self.hand_replies.append(("" if res.success else "refused: ") + res.message)

    def _on_objects(self, msg) -> None:
        objs = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw, o.pose.position.z) for o in msg.objects}
        with self.cond:
            self.objects, self.objects_stamp = objs, _stamp(msg)
            if self.track in objs and self.plan is not None:
                self.heights.append((self.objects_stamp, objs[self.track].z))
            self.cond.notify_all()

    def _on_detections(self, msg) -> None:
        with self.cond:
            self.detections_stamp = max(self.detections_stamp, _stamp(msg))
            ready = self.detections_stamp >= self.frame_stamp
            self.cond.notify_all()
        if ready:
            self._release()

    def _on_recorder(self, msg) -> None:
        with self.cond:
            self.recorder, self.recorder_stamp = msg, _stamp(msg)
            self.cond.notify_all()

    # -- helpers for the orchestrator (main thread; the executor spins elsewhere) ----------------
    def recorded_until(self, topics) -> float:
        """Lockstep: the oldest of the newest stamps (s) the recorder's ~/status says it recorded on
        `topics` in this episode (-inf before one of them has any)."""
        msg = self.recorder
        if msg is None:
            return -math.inf
        newest = dict(zip(msg.stamped_topics, msg.newest_stamps))
        stamps = [newest.get(self.node.resolve_topic_name(t)) for t in topics]
        return min((_stamp_of(s) if s is not None else -math.inf) for s in stamps)

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def wait(self, predicate, timeout: float, what: str) -> None:
        with self.cond:
            if not self.cond.wait_for(predicate, timeout):
                raise GenerateError(f"timed out after {timeout:.0f} s waiting for {what}")

    def call(self, client, request, timeout: float, what: str):
        if not client.wait_for_service(timeout_sec=timeout):
            raise GenerateError(f"service {client.srv_name} not available ({what})")
        future = client.call_async(request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise GenerateError(f"{what}: no reply from {client.srv_name} within {timeout:.0f} s")
        return future.result()

    def subscribers(self, topic: str) -> set[str]:
        """Names of the nodes subscribed to `topic`."""
        return {info.node_name for info in self.node.get_subscriptions_info_by_topic(topic)}

    def run_plan(self, plan, settle: float, timeout: float) -> None:
        self.plan_done.clear()
        self.plan_t0, self.plan_clock, self.pace = None, 0.0, 1.0
        self.plan_end = plan.duration + settle
        self.hand_sent, self.hand_replies, self.heights = 0, [], []
        self.track = plan.task.object_class
        self.send_zero = True
        self.plan_failure = ""
        self.plan = plan
        if self.steps is not None:
            self._run_plan_lockstep(plan, settle)
        elif not self.plan_done.wait(timeout):
            self.plan = None
            self.zero()
            raise GenerateError(f"plan of {plan.duration:.1f} s did not finish within {timeout:.0f} s wall")
        if self.plan_failure:
            self.zero()
            raise GenerateError(self.plan_failure)

    def _run_plan_lockstep(self, plan, settle: float) -> None:
        """Lockstep: run until the plan is done (it holds the simulation at its end), in counts of its
        duration: the plan's clock slows where the arm lags, so at most 3 times as long in all."""
        per_s = round(1.0 / self.steps.unit)
        chunk = round((plan.duration + settle) * per_s) + 1
        for _ in range(3):
            self.steps.run(chunk, f"the plan of {plan.duration:.1f} s")
            if self.plan_done.is_set():
                return
        self.plan = None
        raise GenerateError(f"plan of {plan.duration:.1f} s did not finish in {3 * chunk / per_s:.1f} s of "
                            "simulated time")

    def zero(self) -> None:
        self.cmd_pub.publish(Float64MultiArray(data=[0.0] * 7))


def _domain_busy(domain: int) -> bool:
    """Another graph (a bridge, a recorder, a demonstrator, joint_states) on `domain`: two graphs on
    one domain would mix their joint states."""
    return graph_on_domain(domain, {BRIDGE, RECORDER, "demonstrator"}, "/joint_states")


class _Graph:
    """record.launch.yaml plus this process's demonstrator node, on one ROS domain."""

    def __init__(self, cfg: GenerateConfig, progress: Callable[[str], None]) -> None:
        log_path = Path(cfg.log_dir) / "record.log" if cfg.log_dir is not None else None
        self.runner: GraphRunner[Demonstrator] = GraphRunner(
            LAUNCH_FILE, cfg.launch_arguments(), domain=cfg.domain_id, busy=_domain_busy,
            log_path=log_path, error=GenerateError)
        self.domain = self.runner.domain
        self.demo: Demonstrator | None = None
        self.progress = progress
        self.timeout = cfg.startup_timeout
        self.cfg = cfg

    def start(self) -> Demonstrator:
        self.progress(f"ROS domain {self.domain}; vla launch {' '.join(LAUNCH_FILE)}")
        self.demo = self.runner.start(lambda ctx: Demonstrator(ctx, self.cfg.lockstep))
        if self.demo.steps is not None:
            st = self.demo.steps
            st.alive, st.unit = self.alive, 1.0 / self.cfg.state_rate
            st.real_time_factor = self.cfg.real_time_factor
            self._start_lockstep()
        self._wait_ready()
        return self.demo

    def _start_lockstep(self) -> None:
        """Once the recorder subscribes (it has discovered the graph), a fixed STARTUP_S of steps: every
        node's status is out, nothing has moved."""
        deadline = time.monotonic() + self.timeout
        while not {"/joint_states", "/camera/image_raw"} <= self._recorded_topics():
            self.alive()
            if time.monotonic() > deadline:
                raise GenerateError(f"the recorder did not subscribe within {self.timeout:.0f} s; last "
                                    f"output:\n{self.runner.tail()}")
            time.sleep(0.1)   # polling the graph's discovery, bounded by the deadline
        demo = self.demo
        t_held = demo.steps.run(round(STARTUP_S * self.cfg.state_rate), "the graph's first steps")

        def reset() -> None:
            res = demo.call(demo.reset_cli, ResetScene.Request(use_seed=True, seed=0), WAIT_S, "reset")
            if not res.success:
                raise GenerateError(f"reset refused: {res.message}")

        def detected(timeout: float) -> bool:
            try:
                demo.wait(lambda: demo.detections_stamp >= t_held, timeout, "the first frame's detections")
                return True
            except GenerateError:
                self.alive()
                return False

        await_detector(reset, detected, self.progress, GenerateError)

    def alive(self) -> None:
        self.runner.alive()

    def _wait_ready(self) -> None:
        demo, deadline = self.demo, time.monotonic() + self.timeout
        while not (demo.q is not None and demo.objects and demo.recorder is not None
                   and {"/joint_states", "/camera/image_raw"} <= self._recorded_topics()):
            self.alive()
            if time.monotonic() > deadline:
                raise GenerateError(f"the graph was not ready within {self.timeout:.0f} s (joint_states, "
                                    f"scene/objects, the recorder's status and subscriptions); last "
                                    f"output:\n{self.runner.tail()}")
            time.sleep(0.1)
        if (n := demo.node.count_publishers("/joint_states")) != 1:
            raise GenerateError(f"{n} publishers of /joint_states on ROS domain {self.domain}: another graph "
                                "shares it; set ROS_DOMAIN_ID to a free domain")
        req = SetParameters.Request(parameters=[
            Parameter("status_period_s", value=RECORDER_STATUS_PERIOD_S).to_parameter_msg()])
        demo.call(demo.recorder_params_cli, req, 10, "the recorder's status period")

    def _recorded_topics(self) -> set[str]:
        return {t for t in ("/joint_states", "/camera/image_raw") if RECORDER in self.demo.subscribers(t)}

    def close(self) -> None:
        if self.demo is not None:
            self.demo.zero()
        self.runner.close(self.progress)


def plan_units(cfg: GenerateConfig) -> list[tuple[str, EpisodeRecord]]:
    """Every episode as a unit of a sweep, keyed by its index: its task and seed (drawn in order from
    cfg.seed, the same however the units are spread), its spread point."""
    master = np.random.default_rng(cfg.seed)
    units = []
    for spec in cfg.tasks:
        for k in range(cfg.episodes):
            rec = EpisodeRecord(index=len(units) + 1, task=spec.name, seed=int(master.integers(2**31)),
                                spread_point=k if cfg.spread and spec.uses_hand else None)
            units.append((f"{rec.index:04d} {spec.name} seed {rec.seed}", rec))
    return units


class GenerateWorker:
    """A sweep worker (vla_evaluation.sweep): one graph (record.launch.yaml and the demonstrator),
    started at its first episode, for the episodes it gets. An episode's error is its record's; a graph
    that died is closed and the next episode starts a new one."""

    def __init__(self, shared: tuple[GenerateConfig, bool]) -> None:
        cfg, own = shared   # own: beside other workers (Ray): a ROS domain and a log folder of its own
        if own:
            logs = None if cfg.log_dir is None else Path(cfg.log_dir) / f"worker-{os.getpid()}"
            cfg = replace(cfg, domain_id=None, log_dir=logs)
        self.cfg, self.graph = cfg, None
        self.kin, self.catalogue = PandaKinematics(), load_catalogue(cfg.catalogue)

    def run(self, rec: EpisodeRecord) -> EpisodeRecord:
        rec = replace(rec)
        if self.graph is None:  # a graph that does not start fails the unit (reported by the sweep)
            graph = _Graph(self.cfg, print)
            try:
                graph.start()
            except BaseException:
                graph.close()
                raise
            self.graph = graph
        demo, spec = self.graph.demo, next(t for t in self.cfg.tasks if t.name == rec.task)
        wall0 = time.monotonic()
        try:
            _run_episode(self.cfg, demo, self.kin, spec, self.catalogue, np.random.default_rng(rec.seed), rec,
                         self.graph.alive)
        except GenerateError as err:
            rec.error = str(err)
            self._after_error(rec)
        finally:
            demo.await_detections(False)
        rec.wall_s = time.monotonic() - wall0
        return rec

    def _after_error(self, rec: EpisodeRecord) -> None:
        """A failed episode's bag is discarded; a graph that has died is closed."""
        try:
            self.graph.alive()
            if rec.bag:   # recording (an idle recorder refuses the discard: nothing to do)
                self.graph.demo.call(self.graph.demo.discard_cli, Trigger.Request(), 60, "discard")
        except GenerateError as err:
            rec.error += f"; the graph: {err}"
            self.close()

    def close(self) -> None:
        if self.graph is not None:
            graph, self.graph = self.graph, None
            graph.close()


def run_generation(cfg: GenerateConfig, progress=print, engine: Engine = SERIAL) -> list[EpisodeRecord]:
    """Generate cfg.episodes episodes of every task, each a unit of a sweep on `engine` (serially in
    this process by default); one record per episode, in the plan's order."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    units = plan_units(cfg)
    done: dict[str, EpisodeRecord] = {}

    def on_result(key: str, rec: EpisodeRecord) -> None:
        done[key] = rec
        progress(f"[{rec.index:3d}] {rec.task:<28} {'ok  ' if rec.success else 'FAIL'} "
                 f"disp {rec.displacement * 100:5.1f} cm angle {rec.angle_err_deg:5.1f} deg "
                 f"({rec.duration_s:.1f} s sim, {rec.wall_s:.1f} s wall) {rec.error}")

    failed: list[str] = []
    try:
        failed = run_sweep(units, GenerateWorker, engine=engine, on_result=on_result,
                           shared=(cfg, not engine.serial), name="generate", log=progress)
    finally:   # the episodes done so far (Ctrl-C), a failed unit's marked
        records = [done[k] if k in done else replace(rec, error=WORKER_FAILED)
                   for k, rec in units if k in done or k in failed]
        _write_report(cfg, records)
    return records


def _write_report(cfg: GenerateConfig, records: list[EpisodeRecord]) -> None:
    report = {"config": {k: str(v) for k, v in asdict(cfg).items()}, "episodes": [asdict(r) for r in records]}
    (cfg.out / "generate_report.json").write_text(json.dumps(report, indent=1, default=str))


def last_frame_stamp(held: float, reset: float, unit: float, camera_rate: float) -> float:
    """Lockstep: the stamp (s) of the last camera frame at or before the held step `held`. The bridge
    renders one at the reset's step and every round(1 / (camera_rate * unit)) steps after it."""
    every = max(1, round(1.0 / (camera_rate * unit)))
    steps = round((held - reset) / unit)
    return reset + (steps // every) * every * unit


def _reset_scene(demo: Demonstrator, spec, layout, q0, alive) -> ObjectPose:
    """Reset through the bridge's ~/reset and wait for the settled, detected scene; the object's pose.
    Lockstep: the reset while the simulation holds, then a fixed RESET_SETTLE_S of steps."""
    res = demo.call(demo.reset_cli, reset_request(layout, q0), WAIT_S, "reset")
    if not res.success:
        raise GenerateError(f"reset refused: {res.message}")
    t_reset = demo.now()
    if demo.steps is not None:
        t_reset = demo.reset_stamp = demo.steps.stamp
        demo.steps.run(round(RESET_SETTLE_S / demo.steps.unit) + 1, "the reset scene to settle")
    _wait(demo, lambda: (
        demo.q_stamp > t_reset + 0.2
        and demo.objects_stamp > t_reset + 0.2
        # a camera frame of the new scene too (detected): frames queued before the reset come first
        and demo.detections_stamp > t_reset
        and float(np.max(np.abs(demo.q - q0))) < 0.02
    ), WAIT_S, "the reset scene", alive,
        lambda: (f"reset at {t_reset:.3f} s; last joint state {demo.q_stamp:.3f} s, scene/objects "
                 f"{demo.objects_stamp:.3f} s, detections {demo.detections_stamp:.3f} s, frame "
                 f"{demo.frame_stamp:.3f} s; joints {float(np.max(np.abs(demo.q - q0))):.3f} rad from q0"))
    start = demo.objects.get(spec.object_class)
    if start is None:
        raise GenerateError(f"{spec.object_class} missing from scene/objects after reset")
    return start


def _wait(demo: Demonstrator, predicate, timeout: float, what: str, alive,
          state: Callable[[], str] | None = None) -> None:
    """demo.wait in slices, checking between them that the graph still runs; a timeout's error says
    `state()` (what was seen) when given."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            demo.wait(predicate, min(1.0, max(0.0, deadline - time.monotonic())), what)
            return
        except GenerateError:
            alive()
            if time.monotonic() >= deadline:
                seen = f" ({state()})" if state is not None else ""
                raise GenerateError(f"timed out after {timeout:.0f} s waiting for {what}{seen}") from None


def _plan_episode(cfg, demo: Demonstrator, kin, spec, catalogue, rng, rec: EpisodeRecord, alive):
    """A layout and start pose (the episode's variation), reset, and a plan from the measured scene; a
    layout the planner cannot do is re-drawn (counted in the report, never recorded)."""
    for attempt in range(cfg.max_plan_tries):
        layout = task_layout(spec, rng, catalogue=catalogue, spread=rec.spread_point,
                             spread_margin=cfg.spread_margin)
        q0 = random_start_pose(rng)
        start = _reset_scene(demo, spec, layout, q0, alive)
        try:
            return start, plan_task(kin, spec, start, demo.q.copy(), rng, catalogue)
        except PlanError as err:
            rec.replans = attempt + 1
            if attempt == cfg.max_plan_tries - 1:
                raise GenerateError(f"no plan in {cfg.max_plan_tries} layouts: {err}") from err
    raise AssertionError("not reached")


def _record_plan(cfg, demo: Demonstrator, spec, plan, rec: EpisodeRecord, alive) -> float:
    """Start the recorder, wait for the first frame's detection, run the plan; the end (sim s)."""
    note = json.dumps({"generated": True, "seed": rec.seed, "plan": rec.plan_params})
    # The recorder's start time must come after the reset: its clock (like its queues) can lag the
    # bridge when the simulation runs faster than real time. The loader drops joint states stamped
    # before the start, so stale pre-reset states never enter the episode.
    # Lockstep: the recorder is a participant; it has handled every step up to the held one (its clock
    # there), and leaves out what is stamped before it (a detection of an earlier frame).
    if demo.steps is None:
        t_reset = demo.q_stamp
        _wait(demo, lambda: demo.recorder_stamp >= t_reset, WAIT_S, "the recorder's clock to pass the reset",
              alive)
    res = demo.call(demo.start_cli, StartEpisode.Request(task=spec.name, note=note), WAIT_S, "start")
    if not res.success:
        raise GenerateError(f"start_episode refused: {res.message}")
    rec.bag = res.bag_path
    if demo.steps is not None:
        demo.await_detections(True)
    # the first camera frame and its detection are in the bag before the arm moves (lockstep: one camera
    # period of steps, then the detector's answer while the simulation holds)
    if demo.steps is None:
        t_recording = demo.now()
        _wait(demo, lambda: demo.detections_stamp >= t_recording, WAIT_S, "the first frame's detection",
              alive)
    else:   # a frame stamped after the start (the recorder leaves out one stamped at it)
        t_recording = demo.steps.stamp
        demo.steps.run(round(1.0 / (cfg.camera_rate * demo.steps.unit)) + 1, "a camera frame to record")
        _wait(demo, lambda: demo.detections_stamp > t_recording, WAIT_S, "the first frame's detection", alive)
    wall_limit = (plan.duration + cfg.settle) / max(cfg.real_time_factor, 0.05) * 4 + 60
    demo.run_plan(plan, cfg.settle, wall_limit)
    return demo.now() if demo.steps is None else demo.steps.stamp


def _run_episode(cfg, demo: Demonstrator, kin, spec, catalogue, rng, rec: EpisodeRecord, alive) -> None:
    """One episode: plan, record, judge; failures are marked discarded (or deleted)."""
    start, plan = _plan_episode(cfg, demo, kin, spec, catalogue, rng, rec, alive)
    rec.plan_params = {k: round(float(v), 4) for k, v in plan.params.items()}
    t_end = _record_plan(cfg, demo, spec, plan, rec, alive)
    rec.duration_s = plan.duration
    if demo.steps is not None:   # the recorded tail, a fixed count of steps the recorder has answered
        held = demo.steps.run(round(RECORD_TAIL_S / demo.steps.unit) + 1, "the recorded tail")
        # and the last frame's camera info and detections, that frame known from the counts (not from
        # what has arrived: the held step's frame may still be rendering, and its camera info was seen
        # to reach the bag after the stop at load, test_generate_lockstep); the recorder has them before
        # the stop's request, which follows them
        last = last_frame_stamp(held, demo.reset_stamp, demo.steps.unit, cfg.camera_rate)
        _wait(demo, lambda: min(demo.frame_stamp, demo.detections_stamp) >= last - demo.steps.unit / 2,
              WAIT_S, f"the last frame's ({last:.3f} s) detection", alive)
        # and in the bag: the detector's message reaches the recorder, another process, on a path of its
        # own, so the stop's request could overtake it at load (a bag a detection short, CI)
        framed = ("camera/camera_info", "detections")
        _wait(demo, lambda: demo.recorded_until(framed) >= last - demo.steps.unit / 2, WAIT_S,
              f"the recorder to have the last frame's ({last:.3f} s) detection", alive)
    _wait(demo, lambda: demo.objects_stamp >= t_end, WAIT_S, "the final object poses", alive)
    if demo.steps is None:  # stop once the recorder's clock has passed the plan's end (else the tail is lost)
        _wait(demo, lambda: demo.recorder_stamp >= t_end + RECORD_TAIL_S, WAIT_S, "the recorder to catch up",
              alive)
    end = demo.objects.get(spec.object_class, start)
    lift = None
    if spec.kind == "lift" and demo.heights:
        times, zs = zip(*demo.heights)
        lift = (np.array(times), np.array(zs) - start.z)
    rec.success, rec.displacement, rec.angle_err_deg = task_success(spec, start, end, lift=lift,
                                                                    catalogue=catalogue)
    refused = [r for r in demo.hand_replies if r.startswith("refused")]
    if refused:
        rec.success, rec.error = False, f"the hand {refused[0]}"
    res = demo.call(demo.stop_cli if rec.success else demo.discard_cli, Trigger.Request(), 60, "stop")
    if not res.success:
        raise GenerateError(f"stopping the episode failed: {res.message}")
    # a kept bag must also be one the training loader accepts (on a loaded machine the recorder
    # can still lose states); one that is not counts as failed, so `--delete-failed` runs redo it
    if rec.success:
        problem, rec.detection = loaded_detection(rec.bag)
        if problem:
            rec.success = False
            rec.error = f"recording refused by the loader: {problem}"
    if not rec.success and not cfg.keep_failed:
        shutil.rmtree(rec.bag, ignore_errors=True)


def loaded_detection(bag: str | Path) -> tuple[str, dict | None]:
    """(why training cannot use the bag or "", the demo's detection as a dict or None).

    A bag without a detection near its start counts as refused: training (the detector encoder)
    would skip it, and a kept bag must be one it uses (the loader times the context by its stamp)."""
    try:
        demo = load_demo(bag)
    except DemoError as err:
        return str(err), None
    if demo.detection is None:
        return "no detection near the start of the episode (training's context)", None
    return "", demo.detection.as_dict()


def recording_problem(bag: str | Path) -> str:
    """Why the training loader refuses a recorded bag (lost states, a jump, no context), "" if it does not."""
    return loaded_detection(bag)[0]


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def add_arguments(p: argparse.ArgumentParser) -> None:
    """`vla_evaluation generate` arguments."""
    p.add_argument("--task", action="append", default=[],
                   help="task, e.g. bread:push_east (repeatable); default: the base tasks")
    p.add_argument("--tasks-file", type=Path, help="file with one task per line")
    p.add_argument("--episodes", type=int, default=10, help="episodes per task")
    p.add_argument("--out", type=Path, default=Path("demos"), help="output folder of the bags")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--image-every-n", type=int, default=1000,
                   help="record every n-th camera frame (the first one always)")
    p.add_argument("--camera-rate", type=float, default=5.0, help="camera frames per second (sim time)")
    p.add_argument("--real-time-factor", type=float, default=None,
                   help="simulation speed relative to wall time at most (default 0: as fast as possible; "
                        "with --free-running 1)")
    p.add_argument("--free-running", action="store_true",
                   help="no lockstep: the simulation paced by the wall clock (as before issue 33; the "
                        "demonstrations then depend on the machine's load)")
    p.add_argument("--detector-model", default=None,
                   help="ONNX model of the detector node (default: the shipped one)")
    p.add_argument("--delete-failed", action="store_true",
                   help="delete episodes that failed the task instead of keeping them marked discarded")
    p.add_argument("--log-dir", type=Path, default=None, help="write the graph's output (record.log) here")
    p.add_argument("--catalogue", default="",
                   help="object catalogue YAML with the tasks and objects (default: the paper's five)")
    p.add_argument("--spread", action="store_true",
                   help="tasks with the hand: episode k's object near the k-th of the region's corners and "
                        "centre (few-shot demonstrations a fresh layout lies between)")
    p.add_argument("--spread-margin", type=float, default=SPREAD_MARGIN, metavar="M",
                   help="with --spread: the corners on the region grown by M metres on every side, so "
                        "that fresh layouts lie inside the demonstrated hull (default: %(default)s)")
    add_engine_arguments(p)   # each episode a unit: a graph per worker, in lockstep the same bags either way


def run(args: argparse.Namespace) -> int:
    """CLI entry: `vla_evaluation generate ...`. Ctrl-C / SIGTERM stop cleanly (the graph included)."""
    signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        tasks = parse_tasks(args.task, args.tasks_file, load_catalogue(args.catalogue))
        if args.spread_margin != SPREAD_MARGIN and not args.spread:
            raise ValueError("--spread-margin places the spread points: it needs --spread")
        try:
            check_spread_margin(args.spread_margin)
        except ValueError as e:
            raise ValueError(f"--spread-margin: {e}") from None
    except (ValueError, OSError) as err:
        print(f"error: {err}")
        return 2
    rtf = args.real_time_factor if args.real_time_factor is not None else (1.0 if args.free_running else 0.0)
    cfg = GenerateConfig(tasks=tasks, episodes=args.episodes, out=args.out, seed=args.seed,
                         real_time_factor=rtf, lockstep=not args.free_running, camera_rate=args.camera_rate,
                         image_every_n=args.image_every_n, keep_failed=not args.delete_failed,
                         detector_model=args.detector_model, log_dir=args.log_dir, catalogue=args.catalogue,
                         spread=args.spread, spread_margin=args.spread_margin)
    try:
        engine = engine_from(args)
        records = run_generation(cfg, engine=engine)
    except GenerateError as err:
        print(f"error: {err}")
        return 1
    except KeyboardInterrupt:
        print("interrupted; the report holds the episodes done so far")
        return 130
    ok = sum(r.success for r in records)
    print(f"{ok}/{len(records)} episodes succeeded ({100 * ok / max(len(records), 1):.1f} %); "
          f"bags in {cfg.out}, report {cfg.out / 'generate_report.json'}")
    by_task: dict[str, list[bool]] = {}
    for r in records:
        by_task.setdefault(r.task, []).append(r.success)
    for task, res in by_task.items():
        print(f"  {task:<28} {sum(res)}/{len(res)}")
    if any(r.error == WORKER_FAILED for r in records):
        return 1
    return 0 if records and ok == len(records) else 3

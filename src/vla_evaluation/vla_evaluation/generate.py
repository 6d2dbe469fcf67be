"""Simulated kinesthetic demonstrations, recorded through the real ROS graph.

The person who backdrives the arm in the paper is replaced by a scripted demonstrator: per episode
the scene is reset through the bridge's `~/reset` (a task layout and a jittered start pose drawn
from the episode's random generator), the task is planned with Pinocchio from the object's
ground-truth pose (`vla_sim.planner.plan_task`, itself varied per episode: approach
offset, push height, tilt, speeds), and executed by publishing `joint_velocity_cmd` from every
`joint_states` message (event-driven, no timer). The recorder node records the episode exactly as
it would a real one; the first camera frame is taken before the arm moves and, when a detector
model exists, detected once and published on `detections`. Success is judged on the ground-truth
`scene/objects` (`vla_common.tasks.task_success`); failed episodes are marked `discarded`.

Processes: panda_bridge (MuJoCo, /clock) runs as the installed executable; the recorder node and the
demonstrator node share this process on a MultiThreadedExecutor, all with use_sim_time. Messages
between them go through ROS topics.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

BRIDGE = "panda_bridge"
RECORDER = "recorder"
RECORD_TAIL_S = 0.2  # s of simulated time recorded past the end of the plan and its settling


class GenerateError(RuntimeError):
    """The graph could not be started or an episode could not run; the message says why."""


@dataclass
class GenerateConfig:
    tasks: list[str]
    episodes: int = 10  # per task
    out: Path = Path("demos")
    seed: int = 0
    real_time_factor: float = 1.0  # simulation speed; 0 = as fast as possible
    # joint_states (Hz of sim time). 50 Hz is 5x the demonstrations' 10 Hz; at 200 Hz the generator
    # (recorder + demonstrator in Python) fell behind a fast simulation and lost up to 3 s of states.
    state_rate: float = 50.0
    camera_rate: float = 5.0
    camera_size: tuple[int, int] = (640, 480)
    image_every_n: int = 1000  # keep the first frame of an episode (and every n-th after)
    settle: float = 0.6  # sim seconds of zero command after the plan, before judging
    detector_model: str | None = None  # None: src/vla_detector/models/detector.onnx if it exists
    keep_failed: bool = True  # failed episodes stay on disk, marked discarded
    max_plan_tries: int = 5
    startup_timeout: float = 90.0
    domain_id: int | None = None
    log_dir: Path | None = None


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
    error: str = ""


def default_detector_model() -> Path | None:
    """The detector shipped in the source tree, if there is one."""
    path = Path(__file__).resolve().parents[2] / "vla_detector" / "models" / "detector.onnx"
    if path.is_file():
        return path
    try:
        from vla_detector.inference import default_model_path
    except ImportError:
        return None
    p = default_model_path()
    return p if p.is_file() else None


def parse_tasks(items: list[str], tasks_file: Path | None) -> list[str]:
    """Task names from --task options and a file (one per line, # comments); base tasks if none."""
    from vla_common.tasks import BASE_TASKS, parse_task

    names = list(items)
    if tasks_file is not None:
        for line in Path(tasks_file).read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if line:
                names.append(line)
    return [parse_task(n).name for n in (names or BASE_TASKS)]


class Demonstrator:
    """The ROS side of the scripted demonstrator: joint state in, velocity command out, scene
    ground truth, first-frame detection, and clients of the bridge and the recorder."""

    def __init__(self, context, detector=None) -> None:
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.qos import qos_profile_sensor_data as sensor
        from sensor_msgs.msg import Image, JointState
        from std_msgs.msg import Float64MultiArray
        from std_srvs.srv import Trigger

        from vla_interfaces.msg import DetectionArray, SceneObjectArray
        from vla_interfaces.srv import ResetScene, StartEpisode

        self.node = Node(
            "demonstrator",
            context=context,
            parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)],
        )
        n = self.node
        self.cond = threading.Condition()
        self.detector = detector
        self.q: np.ndarray | None = None
        self.q_stamp = -math.inf
        self.objects: dict = {}
        self.objects_stamp = -math.inf
        self.frame_stamp = -math.inf
        self.want_frame = False
        self.frame_after = math.inf
        self.last_frame_stamp = -math.inf
        self.object_class = ""
        self.first_frame = None
        self.detection: dict | None = None
        self.plan = None
        self.plan_t0: float | None = None
        self.plan_end = math.inf
        self.plan_done = threading.Event()
        self.commands = 0
        self._Float64MultiArray = Float64MultiArray
        self._DetectionArray = DetectionArray
        self.cmd_pub = n.create_publisher(
            Float64MultiArray,
            "joint_velocity_cmd",
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        )
        self.det_pub = n.create_publisher(DetectionArray, "detections", 10)
        n.create_subscription(JointState, "joint_states", self._on_joints, sensor)
        n.create_subscription(SceneObjectArray, "scene/objects", self._on_objects, sensor)
        # the bridge's camera is reliable: a best-effort reader loses most fragmented 900 kB frames
        n.create_subscription(Image, "camera/image_raw", self._on_image,
                              QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE))
        self.reset_cli = n.create_client(ResetScene, f"/{BRIDGE}/reset")
        self.start_cli = n.create_client(StartEpisode, f"/{RECORDER}/start_episode")
        self.stop_cli = n.create_client(Trigger, f"/{RECORDER}/stop_episode")
        self.discard_cli = n.create_client(Trigger, f"/{RECORDER}/discard_episode")
        self.ResetScene, self.StartEpisode, self.Trigger = ResetScene, StartEpisode, Trigger

    @staticmethod
    def _stamp(msg) -> float:
        return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def _on_joints(self, msg) -> None:
        names = list(msg.name)
        try:
            idx = [names.index(f"panda_joint{i}") for i in range(1, 8)]
        except ValueError:
            return
        q = np.array([msg.position[i] for i in idx])
        t = self._stamp(msg)
        with self.cond:
            self.q, self.q_stamp = q, t
            self.cond.notify_all()
        plan = self.plan
        if plan is None:
            return
        if self.plan_t0 is None:
            self.plan_t0 = t
        elapsed = t - self.plan_t0
        dq = plan.command(elapsed, q) if elapsed <= plan.duration else np.zeros(7)
        self.cmd_pub.publish(self._Float64MultiArray(data=[float(v) for v in dq]))
        self.commands += 1
        if elapsed >= self.plan_end:
            self.plan = None
            self.plan_done.set()

    def _on_objects(self, msg) -> None:
        from vla_common.objects import ObjectPose

        objs = {o.class_id: ObjectPose(o.class_id, o.x, o.y, o.yaw) for o in msg.objects}
        with self.cond:
            self.objects, self.objects_stamp = objs, self._stamp(msg)
            self.cond.notify_all()

    def _on_image(self, msg) -> None:
        stamp = self._stamp(msg)
        with self.cond:
            self.last_frame_stamp = stamp
            self.cond.notify_all()
        if not self.want_frame or stamp < self.frame_after:
            return
        from vla_demo_recorder.dataset import image_to_rgb

        self.want_frame = False
        rgb = image_to_rgb(msg, "sensor_msgs/msg/Image")
        if self.detector is not None:
            dets = self.detector.detect(rgb)
            out = self._DetectionArray(header=msg.header, image_width=msg.width, image_height=msg.height)
            from vla_interfaces.msg import Detection

            out.detections = [
                Detection(
                    class_id=d.class_id,
                    class_index=d.class_index,
                    score=d.score,
                    center_x=d.cx,
                    center_y=d.cy,
                    size_x=d.w,
                    size_y=d.h,
                )
                for d in dets
            ]
            self.det_pub.publish(out)
            mine = [d for d in dets if d.class_id == self.object_class]  # what the loader will use
            best = max(mine or dets, key=lambda d: d.score, default=None)
            self.detection = best.as_dict() if best is not None else None
        with self.cond:
            self.first_frame, self.frame_stamp = rgb, stamp
            self.cond.notify_all()

    # -- helpers for the orchestrator (main thread; the executor spins elsewhere) ----------------
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

    def run_plan(self, plan, settle: float, timeout: float) -> None:
        self.plan_done.clear()
        self.plan_t0 = None
        self.plan_end = plan.duration + settle
        self.plan = plan
        if not self.plan_done.wait(timeout):
            self.plan = None
            self.cmd_pub.publish(self._Float64MultiArray(data=[0.0] * 7))
            raise GenerateError(f"plan of {plan.duration:.1f} s did not finish within {timeout:.0f} s wall")

    def zero(self) -> None:
        self.cmd_pub.publish(self._Float64MultiArray(data=[0.0] * 7))


def _domain_busy(domain: int, listen_s: float = 1.5) -> bool:
    """True when nodes of another graph (a bridge, a recorder, joint_states) live on `domain`."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node("vla_domain_probe", context=ctx)
        deadline = time.monotonic() + listen_s
        while time.monotonic() < deadline:
            if {BRIDGE, RECORDER, "demonstrator"} & set(node.get_node_names()) or \
                    node.count_publishers("/joint_states"):
                return True
            time.sleep(0.1)
        node.destroy_node()
        return False
    finally:
        rclpy.shutdown(context=ctx)


def pick_domain(preferred: int | None, tries: int = 8) -> int:
    """A ROS domain with no other graph on it: `preferred` (error if busy) or a random free one.
    Other jobs on a shared machine pick random domains too; two graphs on one domain would mix
    their joint states."""
    if preferred is not None:
        if _domain_busy(preferred):
            raise GenerateError(f"ROS domain {preferred} already has a bridge/recorder/joint_states; "
                                "choose a free ROS_DOMAIN_ID")
        return preferred
    for domain in random.SystemRandom().sample(range(30, 200), tries):
        if not _domain_busy(domain):
            return domain
    raise GenerateError(f"no free ROS domain found in {tries} tries")


def _bridge_process(cfg: GenerateConfig, env: dict) -> subprocess.Popen:
    root = Path(__file__).resolve().parents[3]
    exe = root / "install" / "vla_panda_bridge" / "lib" / "vla_panda_bridge" / BRIDGE
    if not exe.exists():
        raise GenerateError(f"{exe} is not installed (run `make setup`)")
    params = {
        "backend": "mujoco",
        "real_time_factor": float(cfg.real_time_factor),
        "state_rate": float(cfg.state_rate),
        "camera_rate": float(cfg.camera_rate),
        "camera_width": int(cfg.camera_size[0]),
        "camera_height": int(cfg.camera_size[1]),
    }
    cmd = [str(exe), "--ros-args", "-r", f"__node:={BRIDGE}"]
    for k, v in params.items():
        cmd += ["-p", f"{k}:={v}"]
    log = None
    if cfg.log_dir is not None:
        cfg.log_dir.mkdir(parents=True, exist_ok=True)
        log = open(cfg.log_dir / f"{BRIDGE}.log", "w")  # noqa: SIM115 - closed with the process
    return subprocess.Popen(
        cmd, env=env, stdout=log or subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True
    )


def run_generation(cfg: GenerateConfig, progress=print) -> list[EpisodeRecord]:
    """Generate cfg.episodes episodes of every task; returns one record per episode."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from vla_common.kinematics import PandaKinematics
    from vla_common.tasks import parse_task
    from vla_demo_recorder.recorder_node import RecorderNode

    domain = pick_domain(cfg.domain_id if cfg.domain_id is not None else
                         (int(os.environ["ROS_DOMAIN_ID"]) if os.environ.get("ROS_DOMAIN_ID") else None))
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    progress(f"ROS domain {domain}")

    detector = None
    model = cfg.detector_model if cfg.detector_model is not None else default_detector_model()
    if model:
        from vla_detector.inference import Detector

        detector = Detector(str(model))
        progress(f"detector: {model} ({', '.join(detector.classes)})")

    cfg.out.mkdir(parents=True, exist_ok=True)
    bridge = _bridge_process(cfg, env)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    executor = MultiThreadedExecutor(num_threads=4, context=ctx)
    recorder = RecorderNode(
        track_joint_state_stamps=True,
        context=ctx,
        parameter_overrides=[
            Parameter("use_sim_time", Parameter.Type.BOOL, True),
            Parameter("output_dir", value=str(cfg.out.absolute())),
            Parameter("image_every_n", value=int(cfg.image_every_n)),
            Parameter("topic_poll_period_s", value=0.2),
            Parameter("start_button", value=-1),
            Parameter("stop_button", value=-1),
            Parameter("discard_button", value=-1),
        ],
    )
    demo = Demonstrator(ctx, detector)
    executor.add_node(recorder)
    executor.add_node(demo.node)
    stop_spinning = threading.Event()

    def spin() -> None:
        while ctx.ok() and not stop_spinning.is_set():
            executor.spin_once(timeout_sec=0.1)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    records: list[EpisodeRecord] = []
    try:
        demo.wait(
            lambda: demo.q is not None and demo.objects,
            cfg.startup_timeout,
            f"{BRIDGE} joint_states and scene/objects (see its log)",
        )
        if bridge.poll() is not None:
            raise GenerateError(f"{BRIDGE} exited with code {bridge.returncode}")
        if (n := demo.node.count_publishers("/joint_states")) != 1:
            raise GenerateError(f"{n} publishers of /joint_states on ROS domain {domain}: another graph "
                                "shares it; set ROS_DOMAIN_ID to a free domain")
        kin = PandaKinematics()
        deadline = time.monotonic() + 30
        while not {"/joint_states", "/camera/image_raw"} <= set(recorder.subscribed_topics()):
            if time.monotonic() > deadline:
                raise GenerateError(
                    f"recorder did not subscribe to the bridge topics: {recorder.subscribed_topics()}"
                )
            time.sleep(0.1)
        master = np.random.default_rng(cfg.seed)
        index = 0
        for task_name in cfg.tasks:
            spec = parse_task(task_name)
            for _ in range(cfg.episodes):
                index += 1
                ep_seed = int(master.integers(2**31))
                rec = EpisodeRecord(index=index, task=spec.name, seed=ep_seed)
                wall0 = time.monotonic()
                try:
                    _run_episode(cfg, demo, kin, spec, np.random.default_rng(ep_seed), rec,
                                 lambda: recorder.get_clock().now().nanoseconds * 1e-9,
                                 lambda: recorder.latest_stamp_ns.get("/joint_states", 0) * 1e-9)
                except GenerateError as err:
                    rec.error = str(err)
                    if recorder.recorder.recording:
                        demo.call(demo.discard_cli, demo.Trigger.Request(), 60, "discard")
                    if bridge.poll() is not None:
                        raise GenerateError(f"{BRIDGE} exited with code {bridge.returncode}") from err
                rec.wall_s = time.monotonic() - wall0
                records.append(rec)
                progress(
                    f"[{index:3d}] {spec.name:<28} {'ok  ' if rec.success else 'FAIL'} "
                    f"disp {rec.displacement * 100:5.1f} cm angle {rec.angle_err_deg:5.1f} deg "
                    f"({rec.duration_s:.1f} s sim, {rec.wall_s:.1f} s wall) {rec.error}"
                )
    finally:
        demo.zero()
        (cfg.out / "generate_report.json").write_text(
            json.dumps(
                {
                    "config": {k: str(v) for k, v in asdict(cfg).items()},
                    "episodes": [asdict(r) for r in records],
                },
                indent=1,
                default=str,
            )
        )
        stop_spinning.set()
        spinner.join(10)  # no callback may run on a node being destroyed
        executor.shutdown(timeout_sec=10)
        recorder.destroy_node()
        demo.node.destroy_node()
        rclpy.shutdown(context=ctx)
        if bridge.poll() is None:
            os.killpg(bridge.pid, signal.SIGINT)
            try:
                bridge.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(bridge.pid, signal.SIGKILL)
                bridge.wait()
    return records


def _reset_scene(demo: Demonstrator, spec, layout, q0):
    """Reset through the bridge's ~/reset and wait for the settled scene; returns the object pose."""
    from vla_interfaces.msg import SceneObject

    req = demo.ResetScene.Request()
    req.objects = [
        SceneObject(class_id=o.class_id, x=float(o.x), y=float(o.y), yaw=float(o.yaw)) for o in layout
    ]
    req.initial_positions = [float(v) for v in q0]
    res = demo.call(demo.reset_cli, req, 30, "reset")
    if not res.success:
        raise GenerateError(f"reset refused: {res.message}")
    t_reset = demo.now()
    demo.wait(
        lambda: (
            demo.q_stamp > t_reset + 0.2
            and demo.objects_stamp > t_reset + 0.2
            # a camera frame of the new scene too: frames queued before the reset then come first
            and demo.last_frame_stamp > t_reset
            and float(np.max(np.abs(demo.q - q0))) < 0.02
        ),
        30,
        "the reset scene",
    )
    start = demo.objects.get(spec.object_class)
    if start is None:
        raise GenerateError(f"{spec.object_class} missing from scene/objects after reset")
    return start


def _wait_for_clock(now: Callable[[], float], t: float, timeout: float, what: str) -> None:
    """Poll (10 ms) until the clock `now` (s) reaches t; GenerateError after `timeout` wall seconds."""
    deadline = time.monotonic() + timeout
    while now() < t:
        if time.monotonic() > deadline:
            raise GenerateError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.01)


def _run_episode(cfg, demo: Demonstrator, kin, spec, rng, rec: EpisodeRecord,
                 recorder_now: Callable[[], float], recorded_until: Callable[[], float]) -> None:
    """One episode; `recorder_now`: the recorder's clock (s), `recorded_until`: the stamp (s) of the
    newest joint state it has recorded."""
    from vla_common.tasks import task_layout, task_success
    from vla_sim.planner import PlanError, plan_task, random_start_pose

    # 1. a layout and start pose (the episode's variation), reset, plan from the measured scene;
    #    a layout the planner cannot do is re-drawn (counted in the report, never recorded)
    for attempt in range(cfg.max_plan_tries):
        layout = task_layout(spec, rng)
        q0 = random_start_pose(rng)
        start = _reset_scene(demo, spec, layout, q0)
        try:
            plan = plan_task(kin, spec, start, demo.q.copy(), rng)
            break
        except PlanError as err:
            rec.replans = attempt + 1
            if attempt == cfg.max_plan_tries - 1:
                raise GenerateError(f"no plan in {cfg.max_plan_tries} layouts: {err}") from err
    rec.plan_params = {k: round(float(v), 4) for k, v in plan.params.items()}

    # 2. record: first frame (+ detection) before the arm moves, then the demonstration
    note = json.dumps({"generated": True, "seed": rec.seed, "plan": rec.plan_params})
    demo.object_class = spec.object_class
    # The recorder's start time must come after the reset: its clock (like its queues) can lag the
    # bridge when the simulation runs faster than real time. The loader drops joint states stamped
    # before the start, so stale pre-reset states never enter the episode.
    _wait_for_clock(recorder_now, demo.q_stamp, 30, "the recorder's clock to pass the reset")
    res = demo.call(demo.start_cli, demo.StartEpisode.Request(task=spec.name, note=note), 30, "start")
    if not res.success:
        raise GenerateError(f"start_episode refused: {res.message}")
    rec.bag = res.bag_path
    # the recorder holds every frame from its start on; detect the first one received after the
    # reply (a frame stamped between the recorder's start and the reply would be missed otherwise)
    t_recording = demo.now()
    demo.frame_after = t_recording
    demo.want_frame = True
    demo.wait(lambda: demo.frame_stamp >= t_recording, 30, "the first camera frame")
    rec.detection = demo.detection
    wall_limit = (plan.duration + cfg.settle) / max(cfg.real_time_factor, 0.05) * 4 + 60
    demo.run_plan(plan, cfg.settle, wall_limit)
    rec.duration_s = plan.duration
    t_end = demo.now()
    demo.wait(lambda: demo.objects_stamp >= t_end, 30, "the final object poses")
    # stop only once the recorder has recorded the end of the plan (else the episode's tail is lost)
    _wait_for_clock(recorded_until, t_end + RECORD_TAIL_S, 30, "the recorder to catch up")
    end = demo.objects.get(spec.object_class, start)
    rec.success, rec.displacement, rec.angle_err_deg = task_success(spec, start, end)

    # 3. keep successes; failures are marked discarded (or deleted)
    res = demo.call(demo.stop_cli if rec.success else demo.discard_cli, demo.Trigger.Request(), 60, "stop")
    if not res.success:
        raise GenerateError(f"stopping the episode failed: {res.message}")
    # 4. a kept bag must also be one the training loader accepts (on a loaded machine the recorder
    #    can still lose states); one that is not counts as failed, so `--delete-failed` runs redo it
    if rec.success and (problem := recording_problem(rec.bag)):
        rec.success = False
        rec.error = f"recording refused by the loader: {problem}"
    if not rec.success and not cfg.keep_failed:
        shutil.rmtree(rec.bag, ignore_errors=True)


def recording_problem(bag: str | Path) -> str:
    """Why the training loader refuses a recorded bag (lost states, a jump, no context), "" if it does not."""
    from vla_demo_recorder.dataset import DemoError, load_demo

    try:
        load_demo(bag)
    except DemoError as err:
        return str(err)
    return ""


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
    p.add_argument(
        "--image-every-n",
        type=int,
        default=1000,
        help="record every n-th camera frame (the first one always)",
    )
    p.add_argument("--camera-rate", type=float, default=5.0, help="camera frames per second (sim time)")
    p.add_argument(
        "--real-time-factor",
        type=float,
        default=1.0,
        help="simulation speed relative to wall time (0: as fast as possible)",
    )
    p.add_argument(
        "--detector-model",
        default=None,
        help="ONNX detector for the first-frame detections (default: the shipped model if any; '' for none)",
    )
    p.add_argument(
        "--delete-failed",
        action="store_true",
        help="delete episodes that failed the task instead of keeping them marked discarded",
    )
    p.add_argument("--log-dir", type=Path, default=None, help="write the bridge's log here")


def run(args: argparse.Namespace) -> int:
    """CLI entry: `vla_evaluation generate ...`. Ctrl-C / SIGTERM stop cleanly (bridge included)."""
    signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        tasks = parse_tasks(args.task, args.tasks_file)
    except (ValueError, OSError) as err:
        print(f"error: {err}")
        return 2
    cfg = GenerateConfig(
        tasks=tasks,
        episodes=args.episodes,
        out=args.out,
        seed=args.seed,
        real_time_factor=args.real_time_factor,
        camera_rate=args.camera_rate,
        image_every_n=args.image_every_n,
        keep_failed=not args.delete_failed,
        detector_model=args.detector_model,
        log_dir=args.log_dir,
    )
    try:
        records = run_generation(cfg)
    except GenerateError as err:
        print(f"error: {err}")
        return 1
    except KeyboardInterrupt:
        print("interrupted; the report holds the episodes done so far")
        return 130
    ok = sum(r.success for r in records)
    print(
        f"{ok}/{len(records)} episodes succeeded ({100 * ok / max(len(records), 1):.1f} %); "
        f"bags in {cfg.out}, report {cfg.out / 'generate_report.json'}"
    )
    by_task: dict[str, list[bool]] = {}
    for r in records:
        by_task.setdefault(r.task, []).append(r.success)
    for task, res in by_task.items():
        print(f"  {task:<28} {sum(res)}/{len(res)}")
    return 0 if records and ok == len(records) else 3

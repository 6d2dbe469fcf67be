"""The study's trials through the launched graph: the participant publishes its stick as sensor_msgs/Joy.

`GraphBackend` starts the shipped `demo.launch.yaml` with the one graph runner (`graph.GraphEvaluator`,
as `vla_evaluation evaluate --mode graph` and `demo` do) plus the recorder, and per trial:
- sets the controller's `mode` (latent or end_effector) and, for latent actions, its model;
- resets the scene through the bridge's `~/reset` (the trial's seeded layout, as the evaluation);
- starts a bag (`recorder/start_episode`, the trial's key in the note) and, while it opens, for latent
  actions asks the controller to latch the new scene's detection (`~/redetect`);
- lets the participant drive: at the protocol's rate (simulated time) it sees the hand (forward
  kinematics of `joint_states`, what TF shows), the object (the simulation's ground truth
  `scene/objects`, what a person sees on the table) and the controller's status, and publishes `joy`:
  the stick on axis 0, the end-effector mode button as button 0 (the controller's `ee_mode_button`).
  The controller turns it into a command (the decoder, or the end-effector baseline), and the bridge's
  safety layer into motion: every command takes the path a person's would. A simulated participant
  runs in lockstep (vla_common.lockstep): it answers every joint state with a Joy stamped like it (its
  decision at the protocol's rate, the stick held between), the controller waits for that Joy and the
  bridge for the controller, and the steps between the reset, the latch, the trial's start and its end
  are fixed counts, so a trial's row is a function of its seeds at any load (at real time factor 0: as
  fast as the CPU allows);
- ends at the participant's "done" or the time limit, releases the stick, lets the arm come to rest
  (0.5 s), closes the bag and, while the recorder closes it, scores the trial with `trial.trial_row`,
  every backend's scorer. Each row carries `wall_phases` (wall s of each step above) and
  `trial_rtf` (simulated over wall s while the participant drove).
The launch leaves out the shipped sim_teleoperator (the oracle; `GraphConfig.teleoperator`): the
participant is the only publisher on `joy`, and no idle node follows joint_states or loads each model.

A real participant (an id without `sim:`) drives instead (:mod:`.person`): the launch adds the operator
station (its address is printed for the person's screen; a joystick's `joy_node` may publish `joy`
beside it), the study publishes nothing on `joy` and counts what the person sends, the experimenter
confirms the start of each trial after the reset and ends it at the participant's "done" (or the time
limit ends it). The rest (reset, bag, latch, scoring) is the same for both.
"""
from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sensor_msgs.msg import Joy
from std_srvs.srv import Trigger
from vla_common.kinematics import PandaKinematics
from vla_common.ros.convert import ns_from_stamp
from vla_common.tasks import parse_task
from vla_evaluation.graph import (
    CONTROLLER,
    EpisodeMonitor,
    GraphConfig,
    GraphError,
    GraphEvaluator,
    GraphObserver,
)
from vla_evaluation.kinematic import TeleopSettings, plan_waypoints
from vla_evaluation.metrics import LimitMonitor, final_state_error, judge_task
from vla_evaluation.resources import detector_model_path, latent_model_dir

from vla_interfaces.msg import ControllerStatus, GripperStatus, RecorderStatus, SafetyStatus
from vla_interfaces.srv import StartEpisode
from vla_study.hand_participant import BUSY, EMPTY, HOLDING, OPEN
from vla_study.participant import HumanOperator, HumanParams, Observation
from vla_study.person import Experimenter, InputTally, PersonDriver, run_person_trial
from vla_study.protocol import Protocol, model_for
from vla_study.trial import Measured, Participant, Scene, Trial, TrialBackend, controller_parameters

RECORDER = "recorder"
# the stick and buttons as the controller is set up for them (grasp: the shipped controller.yaml's)
AXIS, EE_MODE_BUTTON, GRASP_BUTTON, NUM_AXES, NUM_BUTTONS = 0, 0, 2, 2, 4
OPEN_WIDTH = 0.07   # m between the fingers that a person sees as open (sim_grasp.hand_seen's)
SETTLE_S = 0.5  # sim s after the trial for the arm to rest and the object to settle
# Wall s the recorder's clock may take to pass a trial's reset or end: only against a hang (the recorder
# is no lockstep participant; at load 100 it fell 30 s behind a held simulation)
RECORDER_WAIT_S = 120.0
# The camera (sim Hz): a trial needs a frame only to latch the context after the reset (the participant
# sees the scene's ground truth). A 640x480 frame costs ~17 ms of CPU to render and ~8 ms to detect
# (measured in-process), so 5 Hz (the evaluation's) spent ~0.12 CPU s per simulated s of the graph's
# ~0.65 on frames nobody reads; 2 Hz spends ~0.05, and a frame comes within 0.5 sim s of a request.
CAMERA_RATE = 2.0
# Wall s the recorder may take to catch up with the simulation (its clock), or to answer: a bound only
# against a hung recorder (30 s was passed at load 80-120 on 2 cores, failing the trial)
RECORDER_WAIT_S = 120.0


def hand_view(msg: GripperStatus | None) -> str:
    """The hand as a person sees it (hand_participant): open, holding, empty (closed on nothing) or busy
    (the fingers moving); "" when no status came."""
    if msg is None:
        return ""
    if msg.state in (GripperStatus.MOVING, GripperStatus.GRASPING):
        return BUSY
    if msg.state == GripperStatus.HOLDING or (msg.holding and msg.state != GripperStatus.GRASP_FAILED):
        return HOLDING
    return OPEN if msg.state != GripperStatus.GRASP_FAILED and msg.width >= OPEN_WIDTH else EMPTY


class TrialDriver:
    """One trial's participant on the observer's timer (or, in lockstep, on every joint state, deciding
    every `every` states and holding the stick between): observation in, Joy out. `mode`: the
    controller's mode; a participant's switch of it (hybrid control) holds the simulation at that step
    (`switch_to`) for the backend to set it while held, so that it takes effect at a fixed step."""

    def __init__(self, op: HumanOperator, object_class: str, t_start: float, time_limit: float, kin,
                 mode: str, every: int = 0) -> None:
        self.op, self.cls, self.t_start, self.time_limit = op, object_class, t_start, time_limit
        self._start_ns = round(t_start * 1e9)   # a trial's times from ns: the same floats at any start
        self.kin, self.mode, self.switch_to = kin, mode, ""
        self.sticks: list[float] = []
        self.t_done: float | None = None
        self.t_end: float | None = None
        self.finished = threading.Event()
        self.every, self._states, self._axis = every, 0, 0.0   # lockstep: states per decision

    def answer(self, obs: StudyObserver, msg) -> None:
        """Lockstep: this joint state's Joy, stamped like it (a decision every `every` states)."""
        stamp = msg.header.stamp
        if self.finished.is_set():
            obs.publish_stick(0.0, stamp=stamp)
            return
        self._states += 1
        if (self._states - 1) % self.every:
            obs.publish_stick(self._axis, stamp=stamp)          # the stick held between decisions
            return
        self.tick(obs, stamp)

    def tick(self, obs: StudyObserver, stamp=None) -> None:
        if self.finished.is_set():
            return
        t = ((obs.now_ns() if stamp is None else ns_from_stamp(stamp)) - self._start_ns) * 1e-9
        with obs.cond:
            q, objs, ctrl, safety, hand = obs.q, obs.objects, obs.ctrl, obs.safety, obs.hand
        obj = objs.get(self.cls)
        if t >= self.time_limit or q is None or obj is None:
            if t >= self.time_limit:
                self._end(obs, t, stamp)
            else:
                obs.publish_stick(0.0, stamp=stamp)
            return
        code = int(ctrl.code) if ctrl is not None else 0
        if safety is not None and safety.code == SafetyStatus.AWAITING_ZERO:
            # the bridge stopped the arm and moves it again after a zero: what the controller's
            # AWAITING_NEUTRAL says, the station shows both as "return the stick to neutral"
            code = ControllerStatus.AWAITING_NEUTRAL
        ee = self.mode == "end_effector"
        seen = Observation(t, self.kin.fk(q)[0], np.array([obj.x, obj.y]), code,
                           (ctrl.ee_axis if ctrl is not None and ee else "x"), obj_z=float(obj.z),
                           hand_state=hand_view(hand), mode=self.mode)
        act = self.op.act(seen)
        if act.done:
            self.t_done = t
            self._end(obs, t, stamp)
            return
        if act.switch_mode and stamp is not None:   # lockstep: hold here; the backend switches it
            self.switch_to = act.switch_mode
            obs.steps.hold_after(ns_from_stamp(stamp), 0)
        obs.publish_stick(act.axis, press=act.press, grasp=act.grasp, stamp=stamp)
        self._axis = act.axis
        self.sticks.append(act.axis)

    def _end(self, obs: StudyObserver, t: float, stamp=None) -> None:
        if stamp is not None:     # lockstep: the arm rests SETTLE_S from this very step, then it holds
            obs.steps.hold_after(ns_from_stamp(stamp), obs.settle_steps)
        obs.publish_stick(0.0, stamp=stamp)  # the participant lets go
        self.t_end = t
        with obs.cond:
            self.finished.set()
            obs.cond.notify_all()


class StudyObserver(GraphObserver):
    """The evaluation's observer plus the participant's stick (`joy`) and the recorder's services."""

    def __init__(self, ctx, keep_frames: bool, rate: float, persons: bool = False,
                 use_sim_time: bool = True, lockstep: bool = False) -> None:
        super().__init__(ctx, keep_frames, use_sim_time, lockstep=lockstep)
        n = self.node
        self.joy_pub = n.create_publisher(Joy, "joy", 100 if lockstep else 10)
        self.settle_steps = 0   # lockstep: the steps of SETTLE_S (set by the backend)
        if persons:   # what a person sends (the station, a joystick), counted by their trial's driver
            n.create_subscription(Joy, "joy", self._joy, 50)
        self.rec_start_cli = n.create_client(StartEpisode, f"{RECORDER}/start_episode")
        self.rec_stop_cli = n.create_client(Trigger, f"{RECORDER}/stop_episode")
        self.hand: GripperStatus | None = None   # what the fingers show (tasks with the hand)
        n.create_subscription(GripperStatus, "gripper/status", self._hand, 100 if lockstep else 10)
        self.recorder: RecorderStatus | None = None
        self.recorder_stamp = -np.inf
        n.create_subscription(RecorderStatus, f"{RECORDER}/status", self._recorder, 10)
        self.driver: TrialDriver | None = None
        if not lockstep:   # in lockstep the participant answers every joint state instead (on_state)
            n.create_timer(1.0 / float(rate), self._tick)  # simulated time (use_sim_time)

    def _recorder(self, msg: RecorderStatus) -> None:
        with self.cond:
            self.recorder = msg
            self.recorder_stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            self.cond.notify_all()

    def _hand(self, msg: GripperStatus) -> None:
        with self.cond:
            self.hand = msg

    def _tick(self) -> None:
        d = self.driver
        if d is not None:
            d.tick(self)

    def on_state(self, msg) -> None:
        """Lockstep: every joint state gets the participant's Joy (the stick at rest between trials)."""
        if self.steps is None:
            return
        d = self.driver
        if isinstance(d, TrialDriver):
            d.answer(self, msg)
        else:
            self.publish_stick(0.0, stamp=msg.header.stamp)

    def _joy(self, msg: Joy) -> None:
        d = self.driver
        if isinstance(d, PersonDriver):
            d.op.on_joy(msg.axes, msg.buttons)

    def publish_stick(self, axis: float, press: bool = False, stamp=None, grasp: bool = False) -> None:
        """The stick (and the mode and grasp buttons), stamped `stamp` (lockstep: the joint state it
        answers)."""
        msg = Joy()
        msg.header.stamp = stamp if stamp is not None else self.node.get_clock().now().to_msg()
        msg.header.frame_id = ""  # a Joy has no geometry
        msg.axes, msg.buttons = joy_fields(axis, press, grasp)
        self.joy_pub.publish(msg)


def joy_fields(axis: float, press: bool = False, grasp: bool = False) -> tuple[list[float], list[int]]:
    """The participant's Joy axes and buttons: the stick, the end-effector mode and the grasp buttons
    where the study's graph sets the controller up for them (study_graph_config)."""
    axes = [0.0] * NUM_AXES
    axes[AXIS] = float(axis)
    buttons = [0] * NUM_BUTTONS
    buttons[EE_MODE_BUTTON] = 1 if press else 0
    buttons[GRASP_BUTTON] = 1 if grasp else 0
    return axes, buttons


def study_graph_config(p: Protocol, out: Path, real_time_factor: float = 2.0,
                       operator_port: int | None = None, lockstep: bool = False) -> GraphConfig:
    """`lockstep`: simulated participants (a person drives in real time)."""
    return GraphConfig(
        model_path=str(latent_model_dir("default")), detector_model=str(detector_model_path()),
        # the controller commands at its shipped 100 Hz (the bridge's 0.1 s watchdog then survives a
        # stalled period); the participant's stick comes at the protocol's rate
        real_time_factor=real_time_factor, rate=100.0, camera_rate=CAMERA_RATE, lockstep=lockstep,
        settings=TeleopSettings(rate=float(p.rate), time_limit=float(p.time_limit)),
        log_dir=Path(out) / "logs", record_dir=Path(out) / "bags", teleoperator=False,
        operator_port=operator_port,
        # the stick at the protocol's rate: 0.5 sim s without joy zeroes the command (twice the
        # evaluation's 0.25 s: the participant runs in the study's process on a busy machine)
        joy_timeout=0.5,
        extra_params={CONTROLLER: {"axis": AXIS, "ee_mode_button": EE_MODE_BUTTON, "enable_button": -1,
                                   "grasp_button": GRASP_BUTTON,
                                   "ee_axes": list(p.end_effector_axes),
                                   "ee_debounce": float(p.end_effector_debounce)}})


class PhaseClock:
    """Wall seconds per named phase of a trial, in order (what the study's per-trial time is made of)."""

    def __init__(self) -> None:
        self.phases: dict[str, float] = {}
        self._t = time.monotonic()

    def mark(self, name: str) -> None:
        now = time.monotonic()
        self.phases[name] = round(now - self._t, 3)
        self._t = now


def monitor_path(monitor: EpisodeMonitor, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    """The TCP path (T, 3) and its times that the monitor sampled from joint_states until `t_end`."""
    keep = np.asarray(monitor.path_t) <= t_end + 1e-9
    path = np.asarray(monitor.path)[keep[: len(monitor.path)]] if monitor.path else np.zeros((0, 3))
    return path.reshape(-1, 3), np.asarray(monitor.path_t)[keep]


def limit_fields(lim: LimitMonitor) -> dict:
    """The row's limit violations, measured on joint_states (as the evaluation's)."""
    return dict(limit_violations=int(lim.violations), position_violations=int(lim.position_violations),
                velocity_violations=int(lim.velocity_violations),
                max_speed_ratio=round(float(lim.max_speed_ratio), 3))


@dataclass
class GraphScene(Scene):
    clock: PhaseClock = field(default_factory=PhaseClock)
    q_start: np.ndarray | None = None
    bag_path: str = ""


class GraphBackend(TrialBackend):
    """Runs each trial on the launched graph (start it once; `close()` stops it)."""

    def __init__(self, protocol: Protocol, out: Path, log=print, real_time_factor: float = 2.0,
                 experimenter: Experimenter | None = None, operator_port: int = 8080) -> None:
        """`experimenter`: for real participants (None: simulated ones only); the operator station then
        starts on 127.0.0.1:`operator_port` (0: any free port)."""
        self.protocol, self.log, self.experimenter = protocol, log, experimenter
        Path(out, "logs").mkdir(parents=True, exist_ok=True)
        Path(out, "bags").mkdir(parents=True, exist_ok=True)
        self.out = Path(out)
        persons = experimenter is not None
        # simulated participants in lockstep, as fast as the CPU allows; a person in real time
        lockstep = not persons
        cfg = study_graph_config(protocol, out, 0.0 if lockstep else real_time_factor,
                                 operator_port if persons else None, lockstep=lockstep)
        self.ev = GraphEvaluator(cfg, log, observer=lambda ctx, keep, **kw: StudyObserver(
            ctx, keep, protocol.rate, persons, **kw))
        self.kin = PandaKinematics()
        self.mode: str | None = None
        self.ev.start()
        if lockstep:
            self.ev.obs.settle_steps = cfg.steps(SETTLE_S)
        self.catalogue = self.ev.catalogue
        self.station = ""
        if persons:
            self.station = self._station_address()
            log(f"[study] the participant drives from the operator station at {self.station or '(not found)'}"
                " (or a joystick's joy_node)")

    def _station_address(self, poll_s: float = 0.1) -> str:
        """The operator station's address, from the line it prints once it serves the page; the graph's
        other nodes answer before it (CI once read the log too early: '(not found)'), so wait for it
        within the graph's start-up time, and stop at once if a process of the launch ends."""
        log_path = self.ev.runner.session.log_path
        deadline = time.monotonic() + self.ev.config.startup_timeout
        while True:
            found = re.search(r"operator station is at (\S+)", log_path.read_text())
            if found or time.monotonic() > deadline:
                return found.group(1) if found else ""
            self.ev.alive()
            time.sleep(poll_s)

    def close(self) -> None:
        self.ev.close()

    def _set_strategy(self, trial: Trial) -> str:
        params = controller_parameters(trial.strategy)
        mode = params["mode"]
        # every trial, the same mode and assistance too: the end-effector baseline starts at its first
        # axis, so a trial does not depend on the trials its graph ran before (a sweep's worker runs any)
        self.ev.obs.set_parameters(CONTROLLER, params)
        self.mode = mode
        if mode == "latent":
            self.ev.set_model(str(latent_model_dir(model_for(self.protocol, trial))))
        return mode

    def prepare(self, trial: Trial) -> GraphScene:
        """The strategy, the scene reset by ~/reset (the trial's seeded layout, settled, detected), the
        trial's bag opened while the controller latches the new detection (the bag records the latch)."""
        ev = self.ev
        clock = PhaseClock()
        mode = self._set_strategy(trial)
        spec = parse_task(trial.task, self.catalogue)
        clock.mark("strategy")
        _seed, start, q_now = ev.reset_scene(spec, int(trial.layout_seed), 1)
        clock.mark("reset")
        bag = self._start_bag(trial)
        clock.mark("bag_start")
        scene = GraphScene(mode, spec, start, clock=clock, q_start=q_now)
        if mode == "latent" and (why := ev.latch()):
            scene.note = f"no context: {why}"  # the controller waits, nothing moves
        clock.mark("latch")
        scene.bag_path = self._bag_opened(bag, trial)
        clock.mark("bag_opened")
        if not trial.participant.startswith("sim:"):   # a person: the experimenter says when they are ready
            self.experimenter.confirm(f"Trial {trial.key}: {trial.task} with {trial.strategy}"
                                      f" ({trial.phase}). The scene is reset; is the participant ready?")
        return scene

    def participant(self, trial: Trial, scene: Scene, params: HumanParams | None, seed: int) -> Participant:
        """A person's tally of the `joy` they send (`params` None), else the simulated operator."""
        if params is None:
            return InputTally(AXIS, EE_MODE_BUTTON)
        return super().participant(trial, scene, params, seed)

    def drive(self, trial: Trial, scene: GraphScene, op: Participant) -> Measured:
        """The participant drives until done or the limit; the arm rests; the bag closes while the trial
        is measured."""
        ev, obs, p = self.ev, self.ev.obs, self.protocol
        monitor = self._monitor(scene)
        obs.watch(monitor)
        monitor.t_start = obs.now() if obs.steps is None else obs.steps.stamp   # lockstep: the held step
        if isinstance(op, InputTally):
            driver = PersonDriver(op, monitor.t_start, float(p.time_limit))
        else:
            every = ev.config.steps(1.0 / p.rate) if obs.steps is not None else 0
            driver = TrialDriver(op, scene.spec.object_class, monitor.t_start, float(p.time_limit), self.kin,
                                 scene.mode, every=every)
        if obs.steps is not None:
            self._lockstep_trial(trial, driver)       # it holds SETTLE_S after the end
        else:
            self._until_the_end(trial, driver, p.time_limit / max(ev.config.real_time_factor, 0.05) * 4 + 60)
        scene.clock.mark("trial")
        t_end = driver.t_start + driver.t_end
        if obs.steps is None:
            obs.wait_for(lambda: obs.objects_stamp >= t_end + SETTLE_S and obs.q_stamp >= t_end + SETTLE_S,
                         60.0, "the arm to rest after the trial", ev.alive)
        obs.watch(None)
        with obs.cond:
            q_final, end = obs.q.copy(), obs.objects.get(scene.spec.object_class)
        scene.clock.mark("settle")
        # the recorder closes it as we score (in lockstep its clock passed the end while the arm rested)
        bag_closed = self._stop_bag(t_end + (SETTLE_S if obs.steps is None else 0.0), scene.bag_path)
        scene.clock.mark("bag_stop")
        if end is None:
            raise GraphError(f"{scene.spec.object_class} missing from scene/objects after trial {trial.key}")
        path, times = monitor_path(monitor, driver.t_end)
        ok, disp, ang = judge_task(scene.spec, scene.start, end, path[:, :2])
        final_wp = plan_waypoints(self.kin, scene.spec, scene.start, scene.q_start,
                                  catalogue=self.catalogue)[-1]
        extra = bag_closed()
        extra.update(limit_fields(monitor.limits))  # measured on joint_states, as the evaluation's
        if scene.spec.kind == "pick_place":   # judge_task: the distance to the place, the height above rest
            extra.update(placement_error_m=round(disp, 4), above_rest_m=round(ang, 4))
        scene.clock.mark("score")  # with the bag's closing
        # where the trial's wall time went, and the simulation's pace while the participant drove
        rtf = driver.t_end / max(scene.clock.phases["trial"], 1e-3)
        extra.update(wall_phases=scene.clock.phases, trial_rtf=round(rtf, 2),
                     camera_rate=ev.config.camera_rate, lockstep=bool(ev.config.lockstep))
        return Measured(path, times, np.asarray(driver.sticks), ok=ok, disp=disp,
                        t_success=monitor.tracker.time_to_success, t_done=driver.t_done, t_end=driver.t_end,
                        fse=final_state_error(q_final, final_wp), interventions=monitor.tally.interventions,
                        extra=extra)

    def _monitor(self, scene: GraphScene) -> EpisodeMonitor:
        """The trial's measurements on joint_states, scene/objects and the statuses (a path sample
        every 1/20 s of the state rate)."""
        every = max(1, round(self.ev.config.state_rate / 20.0))
        return EpisodeMonitor(scene.spec, scene.start, self.kin, every, False)

    def _lockstep_trial(self, trial: Trial, driver: TrialDriver) -> None:
        """Lockstep: run to the time limit and the rest after it; the participant answers every joint
        state and, at its end, holds the simulation SETTLE_S later (so a trial that ends early does not
        run on to the limit)."""
        obs, cfg = self.ev.obs, self.ev.config
        end = obs.steps.step + cfg.steps(self.protocol.time_limit) + obs.settle_steps + 2
        obs.driver = driver
        try:
            while True:
                obs.steps.run(max(0, end - obs.steps.step), f"trial {trial.key}")
                if driver.finished.is_set() or not driver.switch_to:
                    break
                self._switch_mode(driver)   # held at the step the participant asked it in
        finally:
            obs.driver = None
        if not driver.finished.is_set():
            raise GraphError(f"trial {trial.key}: the participant did not end by the time limit")

    def _switch_mode(self, driver: TrialDriver) -> None:
        """Hybrid control's switch (the station's), made while the simulation holds."""
        self.ev.obs.set_parameters(CONTROLLER, {"mode": driver.switch_to})
        driver.mode, self.mode, driver.switch_to = driver.switch_to, driver.switch_to, ""

    def _until_the_end(self, trial: Trial, driver, wall_limit: float) -> None:
        """Let the driver run on the observer's timer until the trial ends (a person's: at the
        experimenter's word or the limit)."""
        obs = self.ev.obs
        obs.driver = driver
        try:
            if isinstance(driver, PersonDriver):
                run_person_trial(driver, self.experimenter, f"Driving (at most {self.protocol.time_limit:g} "
                                 "s): when the participant says done", wall_limit)
            obs.wait_for(driver.finished.is_set, wall_limit, f"the end of trial {trial.key}", self.ev.alive)
        finally:
            obs.driver = None

    def _start_bag(self, trial) -> Callable[[], StartEpisode.Response]:
        """Ask the recorder for the trial's bag once its clock has passed the reset; returns the wait."""
        obs = self.ev.obs
        # the recorder's clock can lag the bridge's: start after the reset (in lockstep the scene settled
        # since, so the recorder's clock is past the reset itself)
        t_reset = obs.q_stamp if obs.steps is None else self.ev.reset_stamp
        obs.wait_for(lambda: obs.recorder_stamp >= t_reset, RECORDER_WAIT_S,
                     "the recorder's clock to pass the reset", self.ev.alive)
        return obs.request(obs.rec_start_cli, StartEpisode.Request(task=trial.task, note=json.dumps(
            {"study_trial": trial.key})), RECORDER_WAIT_S, "start the trial's bag")

    def _bag_opened(self, started: Callable[[], StartEpisode.Response], trial) -> str:
        res = started()
        if not res.success:
            raise GraphError(f"the recorder refused trial {trial.key}: {res.message}")
        return res.bag_path

    def _stop_bag(self, t_end: float, bag: str) -> Callable[[], dict]:
        """Close the bag once the recorder's clock has passed the trial's end (else its tail is lost);
        returns the wait for it, which gives the row's `bag`."""
        obs = self.ev.obs
        obs.wait_for(lambda: obs.recorder_stamp >= t_end, RECORDER_WAIT_S, "the recorder to catch up",
                     self.ev.alive)
        stopped = obs.request(obs.rec_stop_cli, Trigger.Request(), 60.0, "close the trial's bag")

        def closed() -> dict:
            res = stopped()
            if not res.success:
                raise GraphError(f"closing the bag {bag} failed: {res.message}")
            try:
                rel = str(Path(bag).resolve().relative_to(self.out.resolve()))
            except ValueError:
                rel = bag
            return {"bag": rel}
        return closed

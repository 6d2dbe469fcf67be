"""The study on a real robot (protocol `robot: real`): attach to the lab's graph, the experimenter places.

`RobotBackend` launches nothing that moves. It joins the graph the lab already started on this
shell's ROS_DOMAIN_ID (the robot's launch: `vla launch vla_bringup teleop.launch.yaml backend:=libfranka
... use_operator_station:=true`, see docs/real-robot.md and docs/study-participants.md) and needs its
bridge (`panda_bridge`: `~/estop`, `joint_states`) and controller (`controller_node`: parameters,
`~/redetect`, `~/status`). It starts only a recorder of its own (a bag per trial into `<out>/bags`)
when none answers on `recorder/start_episode`. Per trial:

1. the controller's strategy and model (its `mode`, `model_path`), as on the simulated robot;
2. the experimenter is asked to place the object at the trial's start point (the trial's seeded
   placement, the one the simulated study resets to: in words and in metres in the robot's base frame)
   and to confirm when it is placed and the participant is ready. The arm is stopped meanwhile: the
   bridge's e-stop is latched from the runner's start and between trials. No `~/reset` is ever called;
3. the bag opens, the controller latches the scene's detection (latent actions), the e-stop is released:
   the arm moves only once the participant's stick has been at neutral (the bridge's rule after any
   stop) and only as the participant drives it; the trial ends at the participant's "done" (the
   experimenter's Enter) or the protocol's time limit, and the e-stop is latched again at once;
4. once the arm is at rest, the bag closes and the experimenter scores the trial: success y/n and,
   optionally, the object's displacement as measured on the table (nothing else can measure the
   object without a simulation). The runner measures the rest itself from `joint_states` (forward
   kinematics, what TF shows): time, TCP path length, smoothness (SPARC, LDLJ), the participant's
   inputs and mode switches, limit violations and the bridge's interventions.

Nothing here moves the arm: the runner publishes no command and no stick for a person; it only
latches and releases the bridge's e-stop. Ctrl-C (or any error) latches the e-stop before the runner
lets go of the graph, and the e-stop stays latched when the study ends (release it with
`ros2 service call /panda_bridge/estop std_srvs/srv/SetBool "{data: false}"` or the station's page).
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from std_srvs.srv import SetBool
from vla_common.kinematics import PandaKinematics
from vla_common.robot import ROBOTS
from vla_common.tasks import parse_task
from vla_evaluation.graph import BRIDGE, CONTROLLER, GraphConfig, GraphError, GraphEvaluator
from vla_evaluation.graph_runner import NodeSpinner
from vla_evaluation.kinematic import plan_waypoints
from vla_evaluation.metrics import LimitMonitor, final_state_error
from vla_launch.launcher import ProcessSpec
from vla_launch.run import find_executable
from vla_launch.session import LaunchError, LaunchSession

from vla_study.graph_backend import (
    AXIS,
    EE_MODE_BUTTON,
    SETTLE_S,
    GraphBackend,
    GraphScene,
    PhaseClock,
    StudyObserver,
    limit_fields,
    monitor_path,
    study_graph_config,
)
from vla_study.outcome import thrown
from vla_study.participant import HumanParams
from vla_study.person import Experimenter, InputTally, PersonDriver, placement_text, start_point
from vla_study.protocol import Protocol
from vla_study.trial import Measured, Participant, Scene, Trial

REST_SPEED = 0.05  # rad/s: every joint slower than this is an arm at rest (the e-stop brakes it there)
RECORDER_TOPICS = ["joint_states", "joy", "detections", "camera/image_raw", "controller_node/status",
                   "panda_bridge/status"]
WHERE = "docs/study-participants.md, 'On a real robot'"


class RobotObserver(StudyObserver):
    """The study's observer on a robot's graph: an FR3's joint names (fr3_joint1..7) read as the
    Panda's, as the controller's joint_map does; its kinematics are the Panda's. While `hold` is set
    (between trials: the experimenter's hands may be at the table) an e-stop released by anyone else
    (the station's page, a service call) is latched again at once."""

    RELATCH_S = 0.5  # wall s between two re-latch requests

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.robot_model = "panda"   # "fr3" once an FR3's joint_states arrive
        self.hold = False
        self.hold_since = math.inf   # the node's clock when the hold began
        self.estop_cli = None
        self.relatched = 0
        self._relatch_t = -math.inf

    def set_hold(self, on: bool) -> None:
        self.hold_since = self.now() if on else math.inf
        self.hold = bool(on)

    def _joints(self, msg) -> None:
        if msg.name and msg.name[0].startswith("fr3_joint"):
            self.robot_model = "fr3"
            msg.name = [n.replace("fr3_joint", "panda_joint", 1) for n in msg.name]
        super()._joints(msg)

    def _safety(self, msg) -> None:
        super()._safety(msg)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        # a status stamped before the hold began (the trial's, still in flight) is no release
        if self.hold and not msg.estop_active and stamp > self.hold_since and self.estop_cli is not None:
            now = time.monotonic()
            if now - self._relatch_t >= self.RELATCH_S:
                self._relatch_t = now
                self.relatched += 1
                self.estop_cli.call_async(SetBool.Request(data=True))   # no wait: this is the executor
                self.node.get_logger().warn("the e-stop was released between trials: latched again "
                                            "(the study releases it at the experimenter's confirmation)")


def recorder_command(out_dir: Path, use_sim_time: bool) -> list[str]:
    """The study's recorder as the simulated study's launch starts it (demo.launch.yaml): bags only at
    the runner's word (the stick's buttons are the participant's), the first camera frame of each."""
    params = {"output_dir": str(Path(out_dir).absolute()), "topics": "[" + ",".join(RECORDER_TOPICS) + "]",
              "image_every_n": "10000", "start_button": "-1", "stop_button": "-1", "discard_button": "-1",
              "use_sim_time": "true" if use_sim_time else "false"}
    cmd = [find_executable("vla_demo_recorder", "recorder"), "--ros-args"]
    for k, v in params.items():
        cmd += ["-p", f"{k}:={v}"]
    return cmd


class AttachedGraph(GraphEvaluator):
    """GraphEvaluator's interface (obs, alive, latch, set_model, close) on a graph someone else started:
    this process joins the shell's ROS domain (its discovery settings as they are: the lab's) instead of
    launching one, and starts a recorder only if none answers."""

    def __init__(self, config: GraphConfig, log, observer, record_dir: Path, use_sim_time: bool) -> None:
        super().__init__(config, log, observer)
        self.record_dir, self.use_sim_time = Path(record_dir), use_sim_time
        self.domain = int(os.environ.get("ROS_DOMAIN_ID") or 0)
        self.side = NodeSpinner(self.domain)
        self.recorder: LaunchSession | None = None

    def start(self) -> None:
        def make(ctx):
            obs = self.observer(ctx, False)
            obs.estop_cli = obs.node.create_client(SetBool, f"{BRIDGE}/estop")
            return obs

        try:
            self.obs = self.side.start(make)
            self._wait_ready()
            self.configure()
        except BaseException:
            self.close()
            raise

    def _wait_ready(self) -> None:
        obs, t = self.obs, self.config.startup_timeout
        missing = f"start the robot's graph first, on this ROS_DOMAIN_ID ({WHERE})"
        for cli in (obs.estop_cli, obs.param_clis[CONTROLLER], obs.redetect_cli):
            if not cli.wait_for_service(timeout_sec=t):
                raise GraphError(f"no {cli.srv_name} on ROS_DOMAIN_ID {self.domain} within {t:.0f} s: "
                                 f"{missing}")
        obs.wait_for(lambda: obs.q is not None, t, "joint_states of the arm (panda_joint1..7 or "
                     f"fr3_joint1..7; {missing})", self.alive)
        obs.wait_for(lambda: obs.ctrl is not None, t, "the controller's status", self.alive)
        if not obs.rec_start_cli.wait_for_service(timeout_sec=3.0):
            self.record_dir.mkdir(parents=True, exist_ok=True)
            log_path = Path(self.config.log_dir) / "recorder.log" if self.config.log_dir else None
            self.recorder = LaunchSession.of_processes(
                [ProcessSpec("recorder", recorder_command(self.record_dir, self.use_sim_time))],
                log_path=log_path)
            try:
                self.recorder.start()
            except LaunchError as e:
                raise GraphError(f"the study's recorder did not start: {e}") from None
            self.log(f"[study] no recorder on the graph: started one into {self.record_dir} (output in "
                     f"{self.recorder.log_path})")
            if not obs.rec_start_cli.wait_for_service(timeout_sec=t):
                raise GraphError(f"the study's recorder did not answer within {t:.0f} s "
                                 f"(see {self.recorder.log_path})")
        obs.wait_for(lambda: obs.recorder is not None, t, "the recorder's status", self.alive)

    def configure(self) -> None:
        """Only the study's own controller settings (the stick's axis and mode button, the end-effector
        cycle): the lab's and the participant's (deadband, speed, enable button) stay as they are."""
        self.obs.set_parameters(CONTROLLER, self.config.extra_params.get(CONTROLLER, {}))

    def alive(self) -> None:
        if self.recorder is not None:
            try:
                self.recorder.check()
            except LaunchError as e:
                raise GraphError(f"the study's recorder ended: {e}") from None

    def close(self) -> None:
        self.side.close()
        if self.recorder is not None:
            recorder, self.recorder = self.recorder, None
            try:
                recorder.stop()
            except LaunchError as e:
                self.log(f"[study] {e}")


@dataclass
class RobotScene(GraphScene):
    placement_seed: int = 0


class RobotBackend(GraphBackend):
    """Each trial on the lab's graph with a person and the experimenter (see the module docstring)."""

    def __init__(self, protocol: Protocol, out: Path, log=print, experimenter: Experimenter | None = None,
                 use_sim_time: bool = False, startup_timeout: float = 60.0,
                 state_rate: float = 200.0) -> None:
        """`use_sim_time`: the graph is a simulated one (a rehearsal, or a test on the MuJoCo bridge),
        whose nodes follow /clock. `state_rate`: the bridge's joint_states rate (the path's sampling)."""
        if experimenter is None:
            raise ValueError("the real robot needs an experimenter (TerminalExperimenter at the terminal)")
        self.protocol, self.log, self.experimenter = protocol, log, experimenter
        self.out = Path(out)
        Path(out, "logs").mkdir(parents=True, exist_ok=True)
        Path(out, "bags").mkdir(parents=True, exist_ok=True)
        cfg = study_graph_config(protocol, out, 1.0, None)
        cfg.model_path, cfg.state_rate, cfg.startup_timeout = "", float(state_rate), float(startup_timeout)
        cfg.extra_params[CONTROLLER].pop("enable_button", None)   # a lab's deadman button stays
        self.ev = AttachedGraph(cfg, log, lambda ctx, keep: RobotObserver(ctx, keep, protocol.rate, True,
                                                                          use_sim_time),
                                Path(out) / "bags", use_sim_time)
        self.kin = PandaKinematics()
        self.mode: str | None = None
        self.station = ""
        self.ev.start()
        self.catalogue = self.ev.catalogue
        try:
            self._estop(True)
        except BaseException:
            self.ev.close()
            raise
        log(f"[study] attached to the robot's graph on ROS_DOMAIN_ID {self.ev.domain}; the arm is stopped "
            "(e-stop latched) until the experimenter confirms a trial's start; the participant drives from "
            "the lab's operator station or joystick")

    def _estop(self, on: bool) -> None:
        """Latch (then hold: a release by anyone else is latched again) or release the bridge's e-stop.
        The hold starts once the bridge has answered: statuses it sent before are not releases."""
        obs = self.ev.obs
        if not on:
            obs.set_hold(False)   # first: the hold must not latch what the study releases
        res = obs.call(obs.estop_cli, SetBool.Request(data=bool(on)), 10.0,
                       "latch the e-stop" if on else "release the e-stop")
        if not res.success:
            raise GraphError(f"the bridge refused to {'latch' if on else 'release'} its e-stop: "
                             f"{res.message}")
        if on:
            obs.set_hold(True)

    def close(self) -> None:
        """Latch the e-stop (it stays latched), then let go of the graph; the lab's graph keeps running."""
        try:
            if self.ev.obs is not None and self.ev.side.ctx is not None:
                self._estop(True)
                self.log("[study] the e-stop stays latched: release it at the station or with "
                         f"ros2 service call /{BRIDGE}/estop std_srvs/srv/SetBool \"{{data: false}}\"")
        except GraphError as e:
            self.log(f"[study] could not latch the e-stop at the end: {e}")
        finally:
            self.ev.close()

    def prepare(self, trial: Trial) -> RobotScene:
        """The strategy; the object placed by the experimenter at the trial's start point with the arm
        stopped; the bag opened while the controller latches the scene's detection."""
        ev, obs = self.ev, self.ev.obs
        clock = PhaseClock()
        mode = self._set_strategy(trial)
        spec = parse_task(trial.task, self.catalogue)
        goal, used_seed = start_point(trial, self.catalogue, self.kin)
        with obs.cond:
            q_before = obs.q.copy()
        clock.mark("strategy")
        self._estop(True)   # already latched; again, in case anyone released it between trials
        self.experimenter.confirm(placement_text(trial, goal, q_before))   # the object is placed by hand
        clock.mark("place")
        bag = self._start_bag(trial)
        clock.mark("bag_start")
        scene = RobotScene(mode, spec, goal, clock=clock, placement_seed=int(used_seed))
        if mode == "latent" and (why := ev.latch()):
            scene.note = f"no context: {why}"  # the controller waits, nothing moves (as in simulation)
        clock.mark("latch")
        scene.bag_path = self._bag_opened(bag, trial)
        clock.mark("bag_opened")
        with obs.cond:
            scene.q_start = obs.q.copy()
        return scene

    def participant(self, trial: Trial, scene: Scene, params: HumanParams | None, seed: int) -> Participant:
        """A person's tally; a simulated participant is refused (earlier, by protocol.robot_refusal; here
        again, so that nothing of one ever reaches the robot)."""
        if params is not None:
            raise GraphError(f"{trial.participant} is a simulated participant: refused on the real robot")
        return InputTally(AXIS, EE_MODE_BUTTON)

    def drive(self, trial: Trial, scene: RobotScene, op: Participant) -> Measured:
        """The e-stop released for the trial and latched again at its end; the arm at rest, the bag
        closed, the experimenter scores the trial; the rest is measured on joint_states."""
        ev, obs, p = self.ev, self.ev.obs, self.protocol
        monitor = self._monitor(scene)
        monitor.limits = LimitMonitor(spec=ROBOTS[obs.robot_model])   # the arm's own limit table
        driver = PersonDriver(op, obs.now(), float(p.time_limit))
        self._estop(False)  # the arm moves once the stick has been at neutral, as the participant drives
        obs.watch(monitor)
        monitor.t_start = driver.t_start = obs.now()
        try:
            self._until_the_end(trial, driver, p.time_limit * 4 + 60)
        finally:
            obs.watch(None)  # the e-stop's braking is the study's, not a safety intervention of the trial
            self._estop(True)
        scene.clock.mark("trial")
        t_end = driver.t_start + driver.t_end
        obs.wait_for(lambda: obs.q_stamp >= t_end + SETTLE_S and (
            obs.dq is None or float(np.max(np.abs(obs.dq))) < REST_SPEED), 30.0, "the arm to rest", ev.alive)
        with obs.cond:
            q_final = obs.q.copy()
        scene.clock.mark("settle")
        extra = self._stop_bag(obs.q_stamp, scene.bag_path)()
        scene.clock.mark("bag_stop")
        how = "the participant said done" if driver.t_done is not None else "the time limit"
        score = self.experimenter.score(
            f"Trial {trial.key} ended after {driver.t_end:.1f} s ({how}); the arm is stopped. Score it.")
        scene.clock.mark("score")
        path, times = monitor_path(monitor, driver.t_end)
        fse = self._final_state_error(scene, q_final)
        extra.update(limit_fields(monitor.limits))
        extra.update(robot="real", robot_model=obs.robot_model, scored_by="experimenter",
                     object_start_source="placed by the experimenter",
                     object_displacement_m=score.displacement_m,
                     thrown=None if score.displacement_m is None else thrown(score.displacement_m),
                     final_state_error=None if fse is None else round(float(fse), 4),
                     arm_start_q=[round(float(v), 4) for v in scene.q_start],
                     placement_seed=scene.placement_seed, wall_phases=scene.clock.phases)
        return Measured(path, times, np.asarray(driver.sticks), ok=score.success, disp=0.0, t_success=None,
                        t_done=driver.t_done, t_end=driver.t_end, fse=0.0 if fse is None else fse,
                        interventions=monitor.tally.interventions, extra=extra)

    def _final_state_error(self, scene: RobotScene, q_final: np.ndarray) -> float | None:
        """Against the planner's last waypoint for the object where it was told to go (None: no plan)."""
        try:
            return final_state_error(q_final, plan_waypoints(self.kin, scene.spec, scene.start, scene.q_start,
                                                             catalogue=self.catalogue)[-1])
        except ValueError:
            return None

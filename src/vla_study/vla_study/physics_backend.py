"""The study's trials in one process (`backend: physics`): the graph's computations without ROS.

MuJoCo's PandaSim, the bridge's SafetyFilter (one update per physics step, as vla_evaluation.physics),
the controller's stick mapping (the decoder) and end-effector baseline, the same participant and the
same scorer (trial.trial_row) as the graph: several times faster, no bags. For the sensitivity sweep
and the oracle comparison, not for the study's record.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from vla_common.catalogue import load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import parse_task
from vla_detector.inference import Detector
from vla_evaluation.kinematic import Layout, TeleopSettings, layout_command, make_layouts
from vla_evaluation.metrics import SuccessTracker, final_state_error, judge_task
from vla_evaluation.physics import _goal_pose, _servo
from vla_evaluation.resources import detector_model_path, latent_model_dir
from vla_latent_controller.ee_baseline import EndEffectorBaseline
from vla_latent_controller.model import LatentModel
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter
from vla_sim.sim import PandaSim

from vla_study.participant import Observation
from vla_study.protocol import Protocol, model_for
from vla_study.trial import Measured, Participant, Scene, Trial, TrialBackend, strategy_mode

JUDGE_S = 0.1  # s between two checks of the object's pose (the bridge's scene/objects rate)
SETTLE_S = 0.5  # s after the trial for the arm to rest and the object to settle


@dataclass
class PhysicsScene(Scene):
    layout: Layout | None = None
    command: object = None  # the decoder's stick -> joint velocity map (latent), else None


class PhysicsBackend(TrialBackend):
    """Runs one trial on a PandaSim with the bridge's safety filter (vla_evaluation.physics's loop)."""

    def __init__(self, protocol: Protocol) -> None:
        self.protocol = protocol
        self.catalogue = load_catalogue("")
        self.kin = PandaKinematics()
        self.sim = PandaSim(render=True, catalogue=self.catalogue)
        self.detector = Detector(detector_model_path())
        self._models: dict[str, LatentModel] = {}

    def model(self, name: str) -> LatentModel:
        if name not in self._models:
            self._models[name] = LatentModel.load(latent_model_dir(name))
        return self._models[name]

    def reset_scene(self, trial: Trial) -> Layout:
        """The trial's seeded layout, settled and detected (what the bridge's ~/reset gives the graph)."""
        return make_layouts([trial.task], [trial.layout_seed], sim=self.sim, detector=self.detector,
                            kin=self.kin, catalogue=self.catalogue)[0]

    def prepare(self, trial: Trial) -> PhysicsScene:
        p = self.protocol
        layout = self.reset_scene(trial)
        mode = strategy_mode(trial.strategy)
        start = _goal_pose(self.sim, layout.goal.class_id)
        scene = PhysicsScene(mode, parse_task(trial.task, self.catalogue), start, layout=layout)
        if mode == "latent":
            try:
                model = self.model(model_for(p, trial))
                scene.command, _ = layout_command(model, layout, TeleopSettings(rate=p.rate,
                                                                                time_limit=p.time_limit))
            except ValueError as e:  # no context latched: the controller waits, nothing moves
                scene.note = f"no context: {e}"
        return scene

    def drive(self, trial: Trial, scene: PhysicsScene, op: Participant) -> Measured:
        sim, p = self.sim, self.protocol
        cls = scene.layout.goal.class_id
        ee = (EndEffectorBaseline(self.kin, debounce=p.end_effector_debounce, axes=p.end_effector_axes)
              if scene.mode == "end_effector" else None)
        safety = SafetyFilter(SafetyConfig(dt=sim.physics_dt))
        safety.reset(sim.q)
        tracker = SuccessTracker(scene.spec, scene.start)
        per = max(1, int(round(1.0 / (p.rate * sim.physics_dt))))
        dt = per * sim.physics_dt
        judge_every = max(1, int(round(JUDGE_S / dt)))
        t0 = sim.time
        path, times, sticks = [], [], []
        t_done = None
        for i in range(int(round(p.time_limit / dt))):
            t = sim.time - t0
            obj = _goal_pose(sim, cls)
            seen = Observation(t, sim.tcp_pose()[0], np.array([obj.x, obj.y]), 0, ee.axis if ee else "x")
            act = op.act(seen)
            if act.done:
                t_done = t
                break
            safety.submit(self._command(ee, scene, act, t), sim.time)
            _servo(sim, safety, per)
            path.append(sim.tcp_pose()[0])
            times.append(sim.time - t0)
            sticks.append(act.axis)
            if i % judge_every == judge_every - 1:
                tracker.update(sim.time - t0, _goal_pose(sim, cls))
        t_end = sim.time - t0
        _servo(sim, safety, int(round(SETTLE_S / sim.physics_dt)))  # the arm rests, the object settles
        path_a = np.asarray(path) if path else np.zeros((0, 3))
        ok, disp, _ang = judge_task(scene.spec, scene.start, _goal_pose(sim, cls), path_a[:, :2])
        return Measured(path_a, np.asarray(times), np.asarray(sticks), ok=ok, disp=disp,
                        t_success=tracker.time_to_success, t_done=t_done, t_end=t_end,
                        fse=final_state_error(sim.q, scene.layout.waypoints[-1]),
                        interventions=safety.interventions)

    def _command(self, ee: EndEffectorBaseline | None, scene: PhysicsScene, act, t: float) -> np.ndarray:
        """The joint velocity the controller would send for the participant's action."""
        if ee is not None:
            if act.press:
                ee.press(t)
            return ee.command(self.sim.q, act.axis)
        if scene.command is not None:
            return scene.command(np.array([act.axis]), self.sim.q)[0]
        return np.zeros(7)

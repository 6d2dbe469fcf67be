"""The controller's own core on the in-process physics: an operator's stick and button through
`TeleopCore` (the assistance included), the bridge's `SafetyFilter` and `GripperCore`, MuJoCo.

`physics.py` mirrors the controller with `StickToCommand`; here the core itself runs, so whatever the
controller node does with a stick (the assistance's inference, its goal poses, the hand's stages) is
what the arm gets. Detections are the layout's first frame, or the detector on a fresh render every
`detect_every` seconds (an object the arm hides is then missing, as through the graph). No ROS, no
transport: for developing on many layouts; the deterministic graph (issue 33) is the reference.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from vla_common.camera_model import SIM_WEBCAM
from vla_common.kinematics import PandaKinematics
from vla_common.robot import HAND, JOINT_NAMES
from vla_latent_controller.teleop import Status, TeleopCore, TeleopParams
from vla_panda_bridge.backend_mujoco import SimHandDriver
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

from vla_evaluation.kinematic import Layout
from vla_evaluation.metrics import EpisodeResult, LimitMonitor, SuccessTracker, judge_task
from vla_panda_bridge import gripper

CONTROL_RATE = 100.0   # Hz: the controller node's default rate
JUDGE_EVERY_S = 0.1
PATH_EVERY_S = 0.05
FINGERS = HAND.finger_joints


@dataclass
class Seen:
    """What an operator sees at a control step."""

    t: float
    tcp: np.ndarray
    objects: list                   # the scene's ObjectPoses (true)
    status: Status                  # the controller's (what the operator station shows)
    hand: gripper.GripperStatusData | None


# An operator: what it sees -> (stick in [-1, 1], press the grasp button now)
Operator = Callable[[Seen], tuple[float, bool]]


def hold(stick: float = 1.0) -> Operator:
    """A person who holds the stick at one value."""
    return lambda seen: (stick, False)


@dataclass
class CoreRun:
    """How the episode went: the result, and per control step (t, stick, share, confidence, stage)."""

    result: EpisodeResult
    trace: list[tuple[float, float, float, float, str]] = field(default_factory=list)
    presses: int = 0


def _detections(sim, layout: Layout, detector, render_every: int, i: int, current):
    if detector is None or render_every <= 0 or i % render_every:
        return current
    return list(detector.detect(sim.render()))


def run_core_episode(model, layout: Layout, params: TeleopParams, sim, operator: Operator, seconds: float,
                     detector=None, detect_every: float = 0.2, stop_on_success: bool = True,
                     linger: float = 1.0, kin=None, label: str = "") -> CoreRun:
    """One episode of `layout` with the controller core driving `sim` for at most `seconds`."""
    kin = kin or PandaKinematics()
    size = layout.image_size or sim.camera_size
    camera = SIM_WEBCAM.pinhole(*size)
    core = TeleopCore(params, model, kin, camera=lambda: camera)
    core.arming.offer(True)            # the operator starts at neutral
    sim.reset(objects=layout.objects, q0=layout.q0)
    cls = layout.goal.class_id
    start = next(o for o in sim.object_poses() if o.class_id == cls)
    safety = SafetyFilter(SafetyConfig(dt=sim.physics_dt))
    safety.reset(sim.q)
    hand = gripper.GripperCore(SimHandDriver(sim, HAND.max_width))
    run = CoreRun(EpisodeResult(task=layout.task, layout_seed=layout.seed, mode="core-physics",
                                encoder=getattr(model, "encoder", ""), model=label,
                                object_start=start.to_dict()))
    tracker, limits = SuccessTracker(layout.task, start), LimitMonitor()
    per_control = max(1, int(round(1.0 / (CONTROL_RATE * sim.physics_dt))))
    dt = per_control * sim.physics_dt
    judge_every, path_every = (max(1, int(round(s / dt))) for s in (JUDGE_EVERY_S, PATH_EVERY_S))
    render_every = int(round(detect_every / dt)) if detector is not None else 0
    dets, path, t0, wall0 = list(layout.detections), [], sim.time, time.perf_counter()
    for i in range(int(round(seconds / dt))):
        t = sim.time - t0
        dets = _detections(sim, layout, detector, render_every, i, dets)
        cmd, press = _operate(core, sim, hand, operator, dets, size, t, run)
        if press:
            run.presses += 1
            hand.request(gripper.TOGGLE, sim.time)
        safety.submit(cmd, sim.time)
        for _ in range(per_control):
            dq, _code, _text = safety.filter(None, sim.q, sim.time)
            sim.set_velocity_command(dq)
            sim.step(1)
            hand.update(sim.time)
        limits.update(sim.q, sim.dq)
        if i % path_every == 0:
            path.append(sim.tcp_pose()[0])
        if i % judge_every == judge_every - 1:
            tracker.update(t, next(o for o in sim.object_poses() if o.class_id == cls))
            done = tracker.time_to_success
            if stop_on_success and done is not None and t >= done + linger:
                break
    _finish(run, sim, safety, limits, tracker, cls, start, path, t0, wall0)
    return run


def _operate(core: TeleopCore, sim, hand, operator: Operator, dets, size, t: float, run: CoreRun):
    """Feed the core this step's inputs (joint states with the fingers, the detections, the
    operator's stick) and step it; returns (the command, whether the operator pressed the button)."""
    now = sim.time
    fingers = sim.hand.finger_positions
    core.on_joint_states((*JOINT_NAMES, *FINGERS), (*sim.q, *fingers), now)
    core.on_detections(dets, size, now)
    seen = Seen(t, sim.tcp_pose()[0], sim.object_poses(), core.status, hand.status)
    stick, press = operator(seen)
    core.on_joy([float(stick)], [0], now)
    cmd, st = core.step(now)
    a = st.assist
    run.trace.append((t, float(stick), float(a.share), float(a.confidence), a.stage))
    return cmd.copy(), press


def _finish(run: CoreRun, sim, safety, limits, tracker, cls, start, path, t0, wall0) -> None:
    t_end = sim.time - t0
    safety.submit(np.zeros(7), sim.time)
    for _ in range(int(round(0.5 / sim.physics_dt))):   # the arm and the object come to rest
        dq, _code, _text = safety.filter(None, sim.q, sim.time)
        sim.set_velocity_command(dq)
        sim.step(1)
    end = next(o for o in sim.object_poses() if o.class_id == cls)
    path_arr = np.asarray(path) if path else np.zeros((0, 3))
    r = run.result
    ok, disp, ang = judge_task(r.task, start, end, path_arr[:, :2])
    r.success, r.displacement_m, r.angle_err_deg = ok, disp, ang
    r.object_end = end.to_dict()
    if ok and tracker.time_to_success is None:
        tracker.time_to_success = t_end
    r.time_to_success = tracker.time_to_success if ok else None
    r.duration_s = round(t_end, 3)
    r.safety_interventions = safety.interventions
    r.limit_violations = limits.violations
    r.final_state_error = math.nan
    r.extra.update({"wall_s": round(time.perf_counter() - wall0, 2), "presses": run.presses,
                    "max_speed_ratio": round(limits.max_speed_ratio, 3), "reflex": sim.reflex() or ""})
    r.ee_path = path_arr if len(path_arr) else None

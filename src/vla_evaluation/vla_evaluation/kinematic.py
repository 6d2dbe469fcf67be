"""`--mode kinematic`: the paper's evaluation loop, q <- q + phi(z*, s) dt, in plain Python.

Layouts are rendered once (MuJoCo camera, the same as the bridge's) and detected once, like the
controller's first-frame latch, then shared by every model evaluated on them: a sweep over many
trained models costs one decoder batch per control step. The arm is a pure integrator here (no
physics, no objects moving), so success is not judged; the metric is the final state error.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from vla_common.catalogue import Catalogue, TaskSpec
from vla_common.detection import Detection
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import DQ_MAX, Q_MAX, Q_MIN, READY_POSE
from vla_common.tasks import parse_task, task_layout
from vla_latent_controller.context import ContextError, select_detection
from vla_latent_controller.teleop import TeleopParams
from vla_sim.planner import PlanError, plan_task

from vla_evaluation.metrics import EpisodeResult, final_state_error
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

# Validation layouts are drawn from seeds at and above this offset; demonstration generators use
# small seeds, so evaluation layouts are never training layouts.
VALIDATION_SEED_OFFSET = 100_000
_CONTROLLER = TeleopParams()  # the controller's defaults, declared there
LAYOUT_RETRY_STRIDE = 1_000_003  # derived seeds when a layout cannot be planned


@dataclass
class TeleopSettings:
    """How the simulated user and the controller behave (the controller's parameters must match)."""

    rate: float = 20.0  # control steps per second of simulated time
    horizon: float = DEFAULT_HORIZON
    n_candidates: int = DEFAULT_CANDIDATES
    switch_time: float = DEFAULT_SWITCH_TIME
    time_limit: float = DEFAULT_TIME_LIMIT
    # The controller's stick mapping and goal choice (its defaults, from TeleopParams)
    deadband: float = _CONTROLLER.deadband
    axis_scale: float = _CONTROLLER.axis_scale
    action_scale: float = _CONTROLLER.action_scale
    max_joint_speed: float = _CONTROLLER.max_joint_speed
    path_fraction: float = _CONTROLLER.path_fraction
    goal_selection: str = _CONTROLLER.goal_selection
    dq_max: tuple | None = tuple(float(v) for v in DQ_MAX)  # the controller node's per-joint limit
    path_every: int = 2  # keep every n-th TCP position for plots
    max_stick_rate: float = 0.0  # stick units per second; 0: unlimited (the paper)
    hold: float = 0.0  # the graph's teleoperator holds the stick at this value (0: steers)
    # the graph's teleoperator, tasks with the hand: end-effector mode where the latent stops short
    fine_align: bool = True


@dataclass
class Layout:
    """One evaluation scene: the goal object, the arm's start and the teleoperator's waypoints, plus
    what the camera saw at the start (image and detections) for the context encoders."""

    task: str
    seed: int
    objects: list[ObjectPose]
    goal: ObjectPose
    q0: np.ndarray
    waypoints: list[np.ndarray]
    image: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    detections: list[Detection] = field(default_factory=list)


def sample_layout_objects(task_name: str | TaskSpec, seed: int, n_objects: int = 1,
                          catalogue: Catalogue | None = None) -> list[ObjectPose]:
    """A seeded random layout for the task (its object first, placed so the task is reachable),
    with n_objects - 1 distractors of the catalogue kept out of the pushing corridor."""
    return task_layout(task_name, np.random.default_rng(seed), n_objects=n_objects, catalogue=catalogue)


def plan_waypoints(kin, task_name: str | TaskSpec, goal: ObjectPose, q0: np.ndarray,
                   plan_seed: int = 0, catalogue: Catalogue | None = None) -> list[np.ndarray]:
    """The teleoperator's joint-space waypoints from the planner (pre-push, post-push; a circle's loop)."""
    rng = np.random.default_rng(plan_seed)
    plan = plan_task(kin, parse_task(task_name, catalogue), goal, np.asarray(q0, float), rng, catalogue)
    return teleop_waypoints(plan)


def make_layouts(tasks: Sequence[str], seeds: Sequence[int], sim=None, detector=None, kin=None,
                 render: bool = True, q0: np.ndarray | None = None, n_objects: int = 1,
                 progress: Callable[[str], None] | None = None,
                 catalogue: Catalogue | None = None) -> list[Layout]:
    """Reset the simulator to each (task, seed) layout, render the first frame and detect on it."""
    kin = kin or PandaKinematics()
    if render and sim is None:
        from vla_sim.sim import PandaSim  # MuJoCo, an optional heavy dependency: only when rendering

        sim = PandaSim(render=True, catalogue=catalogue)
    q_start = np.asarray(READY_POSE if q0 is None else q0, float)
    out = []
    for task in tasks:
        spec = parse_task(task, catalogue)
        cls = spec.object_class
        for seed in seeds:
            objects, goal, wps, used = plannable_layout(kin, spec, cls, int(seed), q_start, n_objects,
                                                        catalogue=catalogue)
            image, size, dets = None, None, []
            if sim is not None:
                sim.reset(objects=objects, q0=q_start)
                sim.step(50)  # let objects settle on the table before the first frame
                objects = sim.object_poses()
                goal = next(o for o in objects if o.class_id == cls)
                if render:
                    image = sim.render()
                    size = (image.shape[1], image.shape[0])
                    if detector is not None:
                        dets = list(detector.detect(image))
            out.append(Layout(spec.name, used, list(objects), goal, q_start.copy(), wps, image, size, dets))
            if progress:
                progress(f"layout {task} seed {used}")
    return out


def plannable_layout(kin, task: str | TaskSpec, cls: str, seed: int, q_start: np.ndarray, n_objects: int,
                      attempts: int = 50, catalogue: Catalogue | None = None):
    """The seed's layout, or the next derived seed's when the planner cannot plan it (IK limits)."""
    last = None
    for k in range(attempts):
        used = seed + k * LAYOUT_RETRY_STRIDE
        objects = sample_layout_objects(task, used, n_objects, catalogue)
        goal = next(o for o in objects if o.class_id == cls)
        try:
            return objects, goal, plan_waypoints(kin, task, goal, q_start, catalogue=catalogue), used
        except PlanError as e:
            last = e
    name = getattr(task, "name", task)
    raise ValueError(f"{name}: no plannable layout from seed {seed} in {attempts} attempts ({last})")


def layout_context(model, layout: Layout,
                   goal_selection: str = "highest_score") -> tuple[np.ndarray, str | None, str]:
    """(context, class for the latent gain, detected class) as the controller would latch them.

    The detector encoder uses the detection chosen by `goal_selection`; localization gets the oracle
    class (the paper's setup) and the image; end-to-end sees only the image. ContextError if the
    inputs are missing (no detection: the controller would wait, the arm does not move).
    """
    oracle = layout.goal.class_id
    det = select_detection(layout.detections, goal_selection, classes=model.classes)
    detected = det.class_id if det is not None else ""
    if model.encoder == "detector":
        if det is None:
            raise ContextError("no detection in the first frame")
        return model.context(det=det, image_size=layout.image_size), det.class_id, detected
    if layout.image is None:
        raise ContextError("no camera image for a CNN encoder")
    if model.encoder == "localization":
        return model.context(image=layout.image, class_id=oracle), oracle, detected
    return model.context(image=layout.image), None, detected


def layout_command(model, layout: Layout, settings: TeleopSettings) -> tuple[StickToCommand, str]:
    """The controller's stick-to-joint-velocity mapping for the layout's latched context, and the
    detected class. ContextError / ValueError when there is no context (the controller would wait)."""
    context, gain_class, detected = layout_context(model, layout, settings.goal_selection)
    command = StickToCommand(model, context, gain_class, settings.deadband, settings.axis_scale,
                             settings.action_scale, settings.max_joint_speed, settings.dq_max,
                             settings.path_fraction)
    return command, detected


def run_episode(model, layout: Layout, settings: TeleopSettings, kin=None, label: str = "") -> EpisodeResult:
    """One kinematic episode with the simulated teleoperator; never raises for a bad model/context."""
    result = EpisodeResult(task=layout.task, layout_seed=layout.seed, mode="kinematic",
                           encoder=getattr(model, "encoder", ""), model=label,
                           object_start=layout.goal.to_dict())
    q = layout.q0.copy()
    final = layout.waypoints[-1]
    result.extra["start_error"] = round(final_state_error(q, final), 5)
    t0 = time.perf_counter()
    try:
        command, result.detected_class = layout_command(model, layout, settings)
    except (ContextError, ValueError) as e:
        result.note = f"no context: {e}"
        result.final_state_error = final_state_error(q, final)
        result.duration_s = 0.0
        return result
    schedule = WaypointSchedule(layout.waypoints, settings.switch_time, settings.time_limit)
    tele = SimTeleoperator(command, schedule, settings.horizon, settings.n_candidates,
                           settings.max_stick_rate)
    dt = 1.0 / settings.rate
    n_steps = int(round(settings.time_limit * settings.rate))
    path = []
    reached = []  # distance to each waypoint when its time is up (a circle's loop, not just its end)
    active = 0
    for i in range(n_steps):
        step = tele.act(i * dt, q)
        if step.done:
            break
        if step.waypoint_index != active:
            reached.append(final_state_error(q, layout.waypoints[active]))
            active = step.waypoint_index
        cmd = command(np.array([step.axis]), q)[0]
        q = np.clip(q + cmd * dt, Q_MIN, Q_MAX)
        if kin is not None and i % settings.path_every == 0:
            path.append(kin.fk(q)[0])
    result.final_state_error = final_state_error(q, final)
    reached.append(result.final_state_error)
    result.extra["waypoint_error"] = round(float(np.mean(reached)), 5)
    result.duration_s = settings.time_limit
    result.extra["wall_s"] = round(time.perf_counter() - t0, 4)
    if path:
        result.ee_path = np.asarray(path)
    return result


def evaluate_kinematic(model, layouts: Sequence[Layout], settings: TeleopSettings | None = None,
                       kin=None, label: str = "") -> list[EpisodeResult]:
    settings = settings or TeleopSettings()
    return [run_episode(model, lay, settings, kin, label) for lay in layouts]

"""`--mode physics`: the graph's computations in one process, without ROS.

The arm and objects are MuJoCo (`PandaSim`, 1 kHz), every command goes through the bridge's
`SafetyFilter` (one update per physics step, as in the bridge node), the stick is mapped by the
controller's `StickToCommand` and chosen by the `SimTeleoperator`, and the task is judged by the same
`SuccessTracker` / `judge_task` as graph mode. What is left out is the transport: no message queues,
no separate processes, no detector running on every frame (the first frame's detection is latched,
as the controller does). About 5x faster than graph mode on 2 cores, so a model change can be checked
over many layouts; graph mode remains the reference.
"""
from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from vla_latent_controller.context import ContextError
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter

from vla_evaluation.kinematic import Layout, TeleopSettings, layout_command
from vla_evaluation.metrics import EpisodeResult, LimitMonitor, SuccessTracker, final_state_error, judge_task
from vla_evaluation.sim_teleoperator import SimTeleoperator, WaypointSchedule

JUDGE_EVERY_S = 0.1  # how often the goal object's pose is checked (the bridge's scene/objects rate)
PATH_EVERY_S = 0.05  # TCP samples kept for the path plots and the circle's sweep


def _servo(sim, safety, steps: int) -> None:
    """`steps` physics steps, each with one safety-filter update on the measured state (the bridge's
    servo loop; the filter holds the last submitted command, or brakes once it is stale)."""
    for _ in range(steps):
        dq, _code, _text = safety.filter(None, sim.q, sim.time)
        sim.set_velocity_command(dq)
        sim.step(1)


def _goal_pose(sim, class_id: str):
    return next((o for o in sim.object_poses() if o.class_id == class_id), None)


def run_episode(model, layout: Layout, settings: TeleopSettings, sim, safety_config=None,
                label: str = "", stop_on_success: bool = False, linger: float = 1.0) -> EpisodeResult:
    """One episode on `sim` (a PandaSim) from the layout's objects and start pose."""
    result = EpisodeResult(task=layout.task, layout_seed=layout.seed, mode="physics",
                           encoder=getattr(model, "encoder", ""), model=label)
    cls = layout.goal.class_id
    sim.reset(objects=layout.objects, q0=layout.q0)
    start = _goal_pose(sim, cls)
    result.object_start = start.to_dict()
    final = layout.waypoints[-1]
    result.extra["start_error"] = round(final_state_error(sim.q, final), 5)
    wall0 = time.perf_counter()
    try:
        command, result.detected_class = layout_command(model, layout, settings)
    except (ContextError, ValueError) as e:  # the controller would wait: nothing moves
        result.note = f"no context: {e}"
        result.success = False
        result.final_state_error = final_state_error(sim.q, final)
        return result
    schedule = WaypointSchedule(layout.waypoints, settings.switch_time, settings.time_limit)
    tele = SimTeleoperator(command, schedule, settings.horizon, settings.n_candidates,
                           settings.max_stick_rate, settings.hold)
    cfg = safety_config or SafetyConfig(dt=sim.physics_dt)
    if abs(cfg.dt - sim.physics_dt) > 1e-12:
        raise ValueError(f"safety filter period {cfg.dt} s must be the physics step {sim.physics_dt} s")
    safety = SafetyFilter(cfg)
    safety.reset(sim.q)
    tracker, limits = SuccessTracker(layout.task, start), LimitMonitor()
    per_control = max(1, int(round(1.0 / (settings.rate * sim.physics_dt))))
    control_dt = per_control * sim.physics_dt
    judge_every = max(1, int(round(JUDGE_EVERY_S / control_dt)))
    path_every = max(1, int(round(PATH_EVERY_S / control_dt)))
    path: list[np.ndarray] = []
    t0 = sim.time
    for i in range(int(round(settings.time_limit / control_dt))):
        q = sim.q
        step = tele.act(sim.time - t0, q)
        if step.done:
            break
        safety.submit(command(np.array([step.axis]), q)[0], sim.time)
        _servo(sim, safety, per_control)
        limits.update(sim.q, sim.dq)
        if i % path_every == 0:
            path.append(sim.tcp_pose()[0])
        if i % judge_every == judge_every - 1:
            tracker.update(sim.time - t0, _goal_pose(sim, cls))
            if stop_on_success and tracker.time_to_success is not None \
                    and sim.time - t0 >= tracker.time_to_success + linger:
                break
    t_end = sim.time - t0
    # the bridge brakes to zero when commands stop; let the arm and the object come to rest
    _servo(sim, safety, int(round(0.5 / sim.physics_dt)))
    end = _goal_pose(sim, cls)
    path_arr = np.asarray(path) if path else np.zeros((0, 3))
    result.final_state_error = final_state_error(sim.q, final)
    ok, disp, ang = judge_task(layout.task, start, end, path_arr[:, :2])
    result.success, result.displacement_m, result.angle_err_deg = ok, disp, ang
    result.object_end = end.to_dict()
    if ok and tracker.time_to_success is None:
        tracker.time_to_success = t_end
    result.time_to_success = tracker.time_to_success if ok else None
    result.duration_s = round(t_end, 3)
    result.safety_interventions = safety.interventions
    result.limit_violations = limits.violations
    result.extra.update({"wall_s": round(time.perf_counter() - wall0, 2),
                         "max_speed_ratio": round(limits.max_speed_ratio, 3),
                         "position_violations": limits.position_violations,
                         "velocity_violations": limits.velocity_violations})
    result.ee_path = path_arr if len(path_arr) else None
    return result


def evaluate_physics(model, layouts: Sequence[Layout], settings: TeleopSettings | None = None, sim=None,
                     label: str = "", stop_on_success: bool = False, log=None) -> list[EpisodeResult]:
    """Every layout in turn on one simulator (the one the layouts were rendered with, or a new one)."""
    settings = settings or TeleopSettings()
    if sim is None:
        from vla_sim.sim import PandaSim  # MuJoCo, an optional heavy dependency: only without a sim given

        sim = PandaSim(render=False)
    out = []
    for lay in layouts:
        r = run_episode(model, lay, settings, sim, label=label, stop_on_success=stop_on_success)
        if log:
            log(f"[physics] {r.task} seed {r.layout_seed}: success {r.success}, "
                f"displacement {r.displacement_m:.3f} m, FSE {r.final_state_error:.3f}")
        out.append(r)
    return out

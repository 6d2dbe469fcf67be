"""The paper's simulated teleoperator (plain Python, no ROS).

In place of a person on a 1-DoF joystick, the paper greedily picks, every step, the latent action
whose projected next state is closest to a joint-space waypoint:

    z* = argmin_{z in Z} || w - (q + phi(z, s) * dt) ||_2

over a discretised Z = [-1, 1]. Pushing tasks use two waypoints (pre-push, then post-push after
k = 15 s); a circle uses a sequence; the episode ends at 30 s.

Here the candidates are *stick deflections*, and `command_fn` maps them to the joint velocities the
controller would send for them (deadband, scaling, decoder, speed clamp): the teleoperator then drives
the system exactly as a person moving the stick would. `horizon` is the paper's dt, the look-ahead
of the projected state; it sets how gently the arm settles on a waypoint (a control period would make
the choice bang-bang).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from vla_latent_controller.teleop import TeleopParams, stick_to_unit

# (axes (N,), q (7,)) -> (N, 7) joint velocities (rad/s) the controller would command for each axis.
AxisCommandFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

DEFAULT_CANDIDATES = 41
DEFAULT_SWITCH_TIME = 15.0
DEFAULT_TIME_LIMIT = 30.0
DEFAULT_HORIZON = 1.0


def axis_candidates(n: int = DEFAULT_CANDIDATES) -> np.ndarray:
    """n stick values evenly spaced over [-1, 1], ordered by |value| so that ties pick the gentlest.

    n must be odd (so that 0, "hands off", is a candidate) and at least 3.
    """
    if int(n) != n or n < 3 or n % 2 == 0:
        raise ValueError(f"n_candidates must be an odd integer >= 3 (so 0 is a candidate), got {n!r}")
    grid = np.linspace(-1.0, 1.0, int(n))
    grid[int(n) // 2] = 0.0
    order = np.lexsort((grid, np.abs(grid)))  # |a| ascending, then negative before positive
    return grid[order]


def best_candidate(commands: np.ndarray, q: np.ndarray, waypoint: np.ndarray,
                   horizon: float = DEFAULT_HORIZON) -> tuple[np.ndarray, np.ndarray]:
    """Index of the candidate command whose projected state is nearest the waypoint.

    commands: (..., N, 7) joint velocities per candidate; q, waypoint: (..., 7).
    Returns (index (...,), projected distance (...,)). Non-finite commands are never chosen
    (distance +inf); argmin takes the first of equals, so candidate order breaks ties.
    """
    commands = np.asarray(commands, dtype=float)
    q = np.asarray(q, dtype=float)
    waypoint = np.asarray(waypoint, dtype=float)
    predicted = q[..., None, :] + commands * float(horizon)
    dist = np.linalg.norm(waypoint[..., None, :] - predicted, axis=-1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    idx = np.argmin(dist, axis=-1)
    return idx, np.take_along_axis(dist, idx[..., None], axis=-1)[..., 0]


@dataclass
class WaypointSchedule:
    """Which waypoint the teleoperator aims at, by time since the episode started.

    Two waypoints (push): the first until `switch_time`, then the second (the paper's k = 15 s).
    More (circle): the first until `switch_time`, the rest evenly over [switch_time, time_limit),
    unless explicit `switch_times` (len(waypoints) - 1 increasing times) are given.
    """

    waypoints: Sequence[np.ndarray]
    switch_time: float = DEFAULT_SWITCH_TIME
    time_limit: float = DEFAULT_TIME_LIMIT
    switch_times: Sequence[float] | None = None

    def __post_init__(self) -> None:
        wps = [np.asarray(w, dtype=float).reshape(-1) for w in self.waypoints]
        if not wps:
            raise ValueError("a waypoint schedule needs at least one waypoint")
        for i, w in enumerate(wps):
            if w.shape != (7,) or not np.all(np.isfinite(w)):
                raise ValueError(f"waypoint {i} must be 7 finite joint positions, got {w!r}")
        if not (self.time_limit > 0 and np.isfinite(self.time_limit)):
            raise ValueError(f"time_limit must be a positive number of seconds, got {self.time_limit!r}")
        if not (0 <= self.switch_time <= self.time_limit):
            raise ValueError(f"switch_time must be within [0, time_limit], got {self.switch_time!r}")
        self.waypoints = wps
        if self.switch_times is None:
            n = len(wps)
            if n == 1:
                times: list[float] = []
            else:
                starts = np.linspace(self.switch_time, self.time_limit, n - 1, endpoint=False)
                times = [float(t) for t in starts]
        else:
            times = [float(t) for t in self.switch_times]
            if len(times) != len(wps) - 1 or any(b < a for a, b in zip(times, times[1:])):
                raise ValueError("switch_times must be len(waypoints) - 1 non-decreasing times")
        self.switch_times = times

    @property
    def final(self) -> np.ndarray:
        return self.waypoints[-1]

    def index_at(self, t: float) -> int:
        return int(np.searchsorted(np.asarray(self.switch_times), t, side="right"))

    def waypoint_at(self, t: float) -> np.ndarray:
        return self.waypoints[self.index_at(t)]

    def done(self, t: float) -> bool:
        return t >= self.time_limit


def teleop_waypoints(plan) -> list[np.ndarray]:
    """The waypoints the paper's teleoperator aims at, from a planner's TaskPlan.

    Push: the pre-push and post-push keyframes only (the planner also has a hover point before and a
    lift after): the keyframes at push height, first and last. Circle: every keyframe (the approach,
    then the loop).
    """
    wps = [np.asarray(w, dtype=float) for w in plan.waypoints]
    if getattr(plan.task, "kind", "push") != "push" or len(wps) <= 2:
        return wps
    tcp_z = np.array([float(np.asarray(p)[2]) for p in plan.tcp_waypoints])
    low = np.flatnonzero(tcp_z <= tcp_z.min() + 0.01)
    if len(low) >= 2:
        return [wps[low[0]], wps[low[-1]]]
    return [wps[1], wps[2]] if len(wps) >= 3 else wps


@dataclass
class TeleopStep:
    """One decision: the stick value to hold, and why."""

    axis: float
    waypoint_index: int
    distance: float  # projected distance to the active waypoint after this step (rad)
    done: bool
    reason: str = ""


class SimTeleoperator:
    """Greedy one-step simulated user over a fixed grid of stick values."""

    def __init__(self, command_fn: AxisCommandFn, schedule: WaypointSchedule,
                 horizon: float = DEFAULT_HORIZON, n_candidates: int = DEFAULT_CANDIDATES,
                 max_stick_rate: float = 0.0, hold: float = 0.0) -> None:
        if not (horizon > 0 and np.isfinite(horizon)):
            raise ValueError(f"horizon must be a positive number of seconds, got {horizon!r}")
        if not (max_stick_rate >= 0 and np.isfinite(max_stick_rate)):
            raise ValueError(f"max_stick_rate must be >= 0 (0: unlimited), got {max_stick_rate!r}")
        self.command_fn = command_fn
        self.schedule = schedule
        self.horizon = float(horizon)
        self.axes = axis_candidates(n_candidates)
        # A hand moves the stick at a finite speed (stick units per second); 0 = the paper's
        # unconstrained choice. With a limit, only values reachable since the last step compete.
        self.max_stick_rate = float(max_stick_rate)
        self._last: tuple[float, float] | None = None  # (t, axis) of the previous step
        # A person who just holds the stick (issue 20 item 5): a fixed value instead of steering.
        if not (-1.0 <= hold <= 1.0):
            raise ValueError(f"hold must be a stick value in [-1, 1] (0: steer), got {hold!r}")
        self.hold = float(hold)

    def act(self, t: float, q: np.ndarray) -> TeleopStep:
        """The stick value at time t (s since the episode started) for joint positions q.

        Never raises on bad input: returns 0 (hands off) with a reason instead.
        """
        if self.schedule.done(t):
            return TeleopStep(0.0, len(self.schedule.waypoints) - 1, float("nan"), True, "time limit")
        idx = self.schedule.index_at(t)
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            return TeleopStep(0.0, idx, float("nan"), False, "bad joint state")
        if self.hold:
            return TeleopStep(self.hold, idx, float("nan"), False, "holding the stick")
        axes = self._reachable(t)
        try:
            commands = np.asarray(self.command_fn(axes, q), dtype=float)
        except Exception as exc:  # a model error must not kill the control loop
            return TeleopStep(0.0, idx, float("nan"), False, f"command model failed: {exc}")
        if commands.shape != (len(axes), 7):
            return TeleopStep(0.0, idx, float("nan"), False, f"command model gave shape {commands.shape}")
        best, dist = best_candidate(commands, q, self.schedule.waypoints[idx], self.horizon)
        if not np.isfinite(dist):
            return TeleopStep(0.0, idx, float("nan"), False, "no finite command")
        axis = float(axes[int(best)])
        self._last = (float(t), axis)
        return TeleopStep(axis, idx, float(dist), False)

    def _reachable(self, t: float) -> np.ndarray:
        """The candidate grid, or with a stick rate limit its values reachable from the last one plus
        the two ends of the reachable interval (still ordered gentlest first)."""
        if self.max_stick_rate <= 0 or self._last is None:
            return self.axes
        t0, a0 = self._last
        reach = self.max_stick_rate * max(0.0, float(t) - t0)
        lo, hi = max(-1.0, a0 - reach), min(1.0, a0 + reach)
        inside = self.axes[(self.axes >= lo) & (self.axes <= hi)]
        cand = np.unique(np.concatenate([inside, [lo, hi, a0]]))
        return cand[np.lexsort((cand, np.abs(cand)))]

    def reset(self) -> None:
        """Forget the previous stick value (a new episode starts from the stick at rest)."""
        self._last = None


class StickToCommand:
    """What the controller commands for a stick value, vectorised over candidate stick values.

    Mirrors the controller's latent path (`teleop.TeleopCore`): stick clipped to [-1, 1]; within the
    deadband exactly zero, outside it rescaled so +-1 is still reached, times axis_scale (clipped);
    z = gain(latched class) * u; command = action_scale * the NumPy decoder's velocity(z, s,
    path_fraction) with the episode's context latched; the whole vector scaled down to the
    max_joint_speed norm (the paper's 1.5 rad/s) and to per-joint dq_max when given. A test checks it
    against the controller core.
    """

    def __init__(self, model, context: np.ndarray, class_id: str | None = None, deadband: float = 0.1,
                 axis_scale: float = 1.0, action_scale: float = 1.0, max_joint_speed: float = 1.5,
                 dq_max: Sequence[float] | None = None,
                 path_fraction: float = TeleopParams.path_fraction) -> None:
        if not 0.0 <= deadband < 1.0:
            raise ValueError(f"deadband must be in [0, 1), got {deadband}")
        self.model = model
        self.decoder = model.decoder
        self.decoder.set_context(context)
        self.gain = float(model.gain(class_id))
        self.deadband = float(deadband)
        self.axis_scale = float(axis_scale)
        self.action_scale = float(action_scale)
        self.max_joint_speed = float(max_joint_speed)
        self.dq_max = None if dq_max is None else np.asarray(dq_max, dtype=float)
        self.path_fraction = model.path_fraction(float(path_fraction))   # 0: the model's, as the controller

    def stick(self, axes: np.ndarray) -> np.ndarray:
        """Stick values after deadband, rescaling and axis_scale, in [-1, 1] (the controller's own
        mapping function)."""
        return np.atleast_1d(stick_to_unit(np.asarray(axes, dtype=float), self.deadband, self.axis_scale))

    def __call__(self, axes: np.ndarray, q: np.ndarray) -> np.ndarray:
        u = self.stick(axes)
        cmd = self.action_scale * self.decoder.velocity_batch(q, u * self.gain, self.path_fraction)
        cmd[u == 0.0] = 0.0  # the controller's deadband gives exactly zero
        scale = np.ones(len(cmd))
        if self.max_joint_speed > 0:
            norms = np.linalg.norm(cmd, axis=1)
            over = norms > self.max_joint_speed
            scale = np.where(over, self.max_joint_speed / np.maximum(norms, 1e-300), 1.0)
        if self.dq_max is not None:
            worst = np.max(np.abs(cmd) / self.dq_max, axis=1)
            scale = np.where(worst * scale > 1.0, 1.0 / np.maximum(worst, 1e-300), scale)
        return cmd * scale[:, None]

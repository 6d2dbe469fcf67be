"""Scripted demonstrations: plan a task from the object's ground-truth pose with Pinocchio IK and
execute it as a joint-velocity tracking command (the stand-in for a person backdriving the arm).

Push: hover above the object's far side (opposite the push direction), outside the circle round
its footprint, descend, push along the direction by the task distance plus a margin, hold there;
the poses depend on the object's (x, y), not its yaw, which the learned model does not see. No lift
at the end: the teleoperator's last waypoint is the post-push pose, and a lift taught the 1-D latent
to rise during the push (measured: pushes stopped ~12 cm into a 24 cm stroke, 10-35 % success). The gripper
points down, tilted a little so the finger tips lead (the hand is wider than the fingers).
Circle: a loop of waypoints around the object above its top. Every episode varies (approach
offset and gap, push height, tilt, hover height, extra distance, speeds) through the given random
generator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from vla_common.catalogue import Catalogue, ObjectSpec, default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import DQ_MAX, Q_MAX, Q_MIN, READY_POSE
from vla_common.task_goals import (  # the goal poses' geometry and the ranges drawn around them
    APPROACH_GAP,
    APPROACH_RUN,
    APPROACH_SPEED,
    CARRY_LIFT,
    CARRY_SPEED,
    CIRCLE_GAP,
    CIRCLE_HEIGHT,
    CIRCLE_SPEED,
    DESCEND_SHARE,
    DOWN,
    EXTRA_DISTANCE,
    GRASP_HOVER,
    GRASP_TRANSIT_SPEED,
    HOVER_EXTRA,
    MIN_HOVER,
    PLACE_CLEARANCE,
    PUSH_HEIGHT,
    PUSH_SPEED,
    RETREAT_RUN,
    TILT_RANGE_DEG,
    TRANSIT_SPEED,
    grasp_height,
    mid,
    preferred_flip,
    push_rotation,
    push_start,
)
from vla_common.tasks import TaskSpec, parse_task

# Tracking gain of TaskPlan.command (1/s) and the share of DQ_MAX a command may use.
TRACKING_GAIN = 4.0
COMMAND_SPEED_SHARE = 0.9
# Reference trajectory limits: peak joint speed (rad/s) and peak acceleration (rad/s^2).
REF_MAX_SPEED = 0.8
REF_MAX_ACCEL = 2.5
_DENSE_STEP = 0.005  # m between IK samples along Cartesian segments
MIN_CLEARANCE = 0.02  # m between the arm (links 3-7) and the object before the push starts
_EXTRA_TILT_DEG = (0.0, 8.0, 16.0)  # tried in turn when the arm would come too close to the object


class PlanError(ValueError):
    """The task cannot be planned from this object pose / start configuration."""


def _min_jerk(tau: np.ndarray | float):
    """Position and derivative of the minimum-jerk profile s(tau) on [0, 1]."""
    t = np.clip(tau, 0.0, 1.0)
    s = t ** 3 * (10 - 15 * t + 6 * t * t)
    ds = 30 * t * t * (1 - t) ** 2
    return s, ds


@dataclass
class _Segment:
    t0: float
    duration: float
    s: np.ndarray  # (M,) path parameter of the samples, 0..1
    q: np.ndarray  # (M, 7) joint samples


@dataclass
class TaskPlan:
    """A time-parameterised joint trajectory for one task episode.

    waypoints: joint-space keyframes (push: hover, pre-push, post-push, then a hold; circle: hover then
    the loop), times: when each keyframe is reached (s from the start), tcp_waypoints: their TCP
    positions. command(t, q) tracks the trajectory: feed-forward velocity + TRACKING_GAIN * error,
    uniformly scaled into the Panda's velocity limits; zero-velocity hold after `duration`."""

    task: TaskSpec
    q_start: np.ndarray
    waypoints: list[np.ndarray]
    times: np.ndarray
    tcp_waypoints: list[np.ndarray]
    segments: list[_Segment]
    params: dict = field(default_factory=dict)
    gain: float = TRACKING_GAIN
    # what the hand does when (tasks with the hand): (time s, "open" | "grasp"), in time order
    hand_events: list[tuple[float, str]] = field(default_factory=list)

    def hand_command_at(self, t: float) -> str | None:
        """The hand's last event at or before time t (None before the first)."""
        last = None
        for when, what in self.hand_events:
            if when <= t:
                last = what
        return last

    @property
    def duration(self) -> float:
        last = self.segments[-1]
        return last.t0 + last.duration

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference joint positions and velocities at time t (clamped to [0, duration])."""
        t = float(t)
        if not math.isfinite(t) or t <= 0.0:
            return self.segments[0].q[0].copy(), np.zeros(7)
        if t >= self.duration:
            return self.segments[-1].q[-1].copy(), np.zeros(7)
        seg = self.segments[-1]
        for candidate in self.segments:
            if t < candidate.t0 + candidate.duration:
                seg = candidate
                break
        tau = (t - seg.t0) / seg.duration
        s, ds = _min_jerk(tau)
        i = int(np.clip(np.searchsorted(seg.s, s, side="right") - 1, 0, len(seg.s) - 2))
        span = seg.s[i + 1] - seg.s[i]
        if span <= 0:
            return seg.q[i].copy(), np.zeros(7)
        w = (s - seg.s[i]) / span
        dq_ds = (seg.q[i + 1] - seg.q[i]) / span
        return seg.q[i] + w * (seg.q[i + 1] - seg.q[i]), dq_ds * ds / seg.duration

    def command(self, t: float, q, pace: float = 1.0) -> np.ndarray:
        """Joint-velocity command (7,) at time t for measured joint positions q, the feed-forward
        scaled by `pace` (how fast the caller's plan clock runs, 0..1: a demonstrator that slows its
        clock while the arm lags). Never raises: non-finite or malformed q gives a zero command."""
        try:
            qm = np.asarray(q, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return np.zeros(7)
        if qm.shape != (7,) or not np.all(np.isfinite(qm)):
            return np.zeros(7)
        q_ref, dq_ref = self.reference(t)
        dq = min(max(float(pace), 0.0), 1.0) * dq_ref + self.gain * (q_ref - qm)
        limit = COMMAND_SPEED_SHARE * np.asarray(DQ_MAX)
        ratio = float(np.max(np.abs(dq) / limit))
        return dq / ratio if ratio > 1.0 else dq


def random_start_pose(rng: np.random.Generator, scale: float = 0.08) -> np.ndarray:
    """Ready pose with per-joint Gaussian jitter (rad), kept 0.2 rad inside the limits."""
    q = np.asarray(READY_POSE) + rng.normal(0.0, scale, 7)
    return np.clip(q, np.asarray(Q_MIN) + 0.2, np.asarray(Q_MAX) - 0.2)


def object_clearance(kin: PandaKinematics, q: np.ndarray, obj: ObjectPose, shape: ObjectSpec,
                     shift=(0.0, 0.0)) -> float:
    """Smallest distance (m) from the arm's links 3-7 (collision-mesh vertices) to the object's
    volume (`shape`'s footprint prism up to its height; optionally shifted on the table by `shift`).
    The hand and fingers are left out: they are meant to touch it. Negative: a link dips into it."""
    pts = kin.link_points(q)
    rel = pts[:, :2] - (np.array([obj.x, obj.y]) + np.asarray(shift))
    if shape.shape == "cylinder":
        d_xy = np.linalg.norm(rel, axis=1) - shape.size[0]
    else:
        c, s = math.cos(obj.yaw), math.sin(obj.yaw)
        local = np.abs(rel @ np.array([[c, -s], [s, c]]))  # into the object's frame
        excess = local - np.array(shape.size[:2]) / 2
        outside = np.linalg.norm(np.maximum(excess, 0.0), axis=1)
        d_xy = np.where(outside > 0, outside, excess.max(axis=1))
    d_z = pts[:, 2] - shape.height
    return float(np.min(np.maximum(d_xy, d_z)))


def _joint_margin(q: np.ndarray) -> float:
    return float(min(np.min(q - np.asarray(Q_MIN)), np.min(np.asarray(Q_MAX) - q)))


_TILT_PENALTY = 0.5  # rad of joint distance one radian of extra tilt is worth when choosing


def _push_candidates(kin: PandaKinematics, pre, hover, direction_xy, tilt: float, seeds, obj: ObjectPose,
                     shape: ObjectSpec):
    """IK solutions of the pre-push pose (hover pose above it reachable) for the task's preferred
    hand flip, or the other flip only when the preferred one has none: (q, rot, clearance)."""
    preferred = preferred_flip(direction_xy)
    for flip in (preferred, not preferred):
        rot = push_rotation(direction_xy, tilt, flip)
        found = []
        for seed in seeds:
            q, ok = kin.ik(pre, rot, seed)
            if not ok or _joint_margin(q) < 0.15:
                continue
            q_hover, ok = kin.ik(hover, rot, q)
            if ok and _joint_margin(q_hover) > 0.05:
                found.append((q, rot, object_clearance(kin, q, obj, shape)))
        if found:
            return found
    return []


def _best_push_configuration(
    kin: PandaKinematics, pre, hover, direction_xy, tilt: float, q_ref: np.ndarray, obj: ObjectPose,
    shape: ObjectSpec,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Pre-push configuration nearest `q_ref` (the task's reference configuration) among IK solutions
    that keep MIN_CLEARANCE between the arm and the object, over the base tilt and the extra tilts
    (a little extra tilt is preferred to another arm configuration); when none keeps the clearance,
    the one with the largest clearance. Choosing by nearness to a fixed reference, not to the
    jittered start, keeps every demonstration of a task in one arm configuration, which a 1-D
    latent action needs. Returns (q_pre, rot, clearance, extra_tilt_deg); PlanError when no
    candidate works."""
    q_ref = np.asarray(q_ref, dtype=float)
    seeds = [q_ref]
    for q7 in (-2.4, -1.2, 0.0, 1.2, 2.4):
        seed = q_ref.copy()
        seed[6] = q7
        seeds.append(seed)
    best = None
    for extra in _EXTRA_TILT_DEG:
        for q, rot, clearance in _push_candidates(kin, pre, hover, direction_xy,
                                                  tilt + math.radians(extra), seeds, obj, shape):
            key = (-min(clearance, MIN_CLEARANCE),
                   float(np.linalg.norm(q - q_ref)) + _TILT_PENALTY * math.radians(extra))
            if best is None or key < best[0]:
                best = (key, q, rot, clearance, extra)
    if best is None:
        raise PlanError(f"no IK solution for the pre-push pose at {np.round(pre, 3).tolist()} "
                        f"(tilt {math.degrees(tilt):.0f} deg) with the hover pose above it")
    return best[1], best[2], best[3], best[4]


_REFERENCE: dict[tuple[str, ObjectSpec], np.ndarray] = {}


def reference_configuration(kin: PandaKinematics, spec: TaskSpec, shape: ObjectSpec) -> np.ndarray:
    """The task's reference pre-push configuration: planned from the ready pose for the object
    (`shape`) at the centre of the workspace (x 0.48 m, y 0, yaw 0) with the middle of every random
    range. Cached per task and shape; deterministic."""
    key = (spec.name, shape)
    if key not in _REFERENCE:
        obj = ObjectPose(spec.object_class, 0.48, 0.0, 0.0, 0.0)
        d = spec.direction_vector
        start_xy = push_start(shape, (obj.x, obj.y), d, mid(APPROACH_GAP))
        hover = max(MIN_HOVER, shape.height + mid(HOVER_EXTRA))
        q, _rot, _c, _e = _best_push_configuration(
            kin, [*start_xy, mid(PUSH_HEIGHT)], [*start_xy, hover], d, math.radians(mid(TILT_RANGE_DEG)),
            np.asarray(READY_POSE), obj, shape)
        _REFERENCE[key] = q
    return _REFERENCE[key].copy()


class _Builder:
    """Accumulates segments: joint-space transits and Cartesian straight lines / loops via IK."""

    def __init__(self, kin: PandaKinematics, q_start: np.ndarray):
        self.kin = kin
        self.q = np.asarray(q_start, dtype=float).copy()
        self.t = 0.0
        self.segments: list[_Segment] = []
        self.waypoints: list[np.ndarray] = []
        self.times: list[float] = []
        self.tcp: list[np.ndarray] = []

    def _ik(self, pos, rot, q0) -> np.ndarray:
        q, ok = self.kin.ik(pos, rot, q0)
        if not ok:
            raise PlanError(f"no IK solution for TCP at {np.round(pos, 3).tolist()}")
        return q

    def _add(self, s: np.ndarray, q: np.ndarray, min_duration: float, keyframe: bool = True) -> None:
        dq = np.abs(np.diff(q, axis=0))
        if len(dq) and float(dq.max()) > 0.2:
            raise PlanError("IK solutions jump along the path (near a singularity or joint limit)")
        # Peak joint speed of a min-jerk profile is 1.875 * (distance / T) on a uniform path; use
        # the steepest part of the path to bound it, and the peak acceleration 5.77 * distance / T^2.
        total = np.abs(q[-1] - q[0]).max() if len(q) > 1 else 0.0
        ds = np.diff(s)
        steep = float(np.max(dq.max(axis=1) / np.maximum(ds, 1e-9))) if len(dq) else 0.0
        duration = max(min_duration, 1.875 * steep / REF_MAX_SPEED,
                       math.sqrt(5.77 * max(total, steep) / REF_MAX_ACCEL), 0.05)
        self.segments.append(_Segment(self.t, duration, s, q))
        self.t += duration
        self.q = q[-1].copy()
        if keyframe:
            self.waypoints.append(self.q.copy())
            self.times.append(self.t)
            self.tcp.append(self.kin.fk(self.q)[0])

    def joint_move(self, pos, rot, speed: float, seed: np.ndarray | None = None) -> None:
        """Joint-space transit to a TCP pose (straight in joint space); IK seeded with `seed`
        (default: the current configuration) to pick the arm configuration."""
        q_goal = self._ik(pos, rot, self.q if seed is None else seed)
        n = 20
        s = np.linspace(0.0, 1.0, n + 1)
        q = self.q + s[:, None] * (q_goal - self.q)
        dist = float(np.linalg.norm(self.kin.fk(q_goal)[0] - self.kin.fk(self.q)[0]))
        self._add(s, q, dist / speed)

    def line(self, pos, rot, speed: float) -> None:
        """Cartesian straight line of the TCP to `pos` at fixed orientation `rot`."""
        p0 = self.kin.fk(self.q)[0]
        p1 = np.asarray(pos, dtype=float)
        length = float(np.linalg.norm(p1 - p0))
        n = max(2, int(math.ceil(length / _DENSE_STEP)))
        s = np.linspace(0.0, 1.0, n + 1)
        qs = [self.q.copy()]
        for si in s[1:]:
            qs.append(self._ik(p0 + si * (p1 - p0), rot, qs[-1]))
        self._add(s, np.array(qs), length / speed)

    def loop(self, points: np.ndarray, rot, speed: float) -> None:
        """TCP through a dense sequence of points (the circle), one smooth segment; keyframes every
        `len(points) // 12` samples."""
        p0 = self.kin.fk(self.q)[0]
        pts = np.vstack([p0, points])
        seglen = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seglen)]) / max(seglen.sum(), 1e-9)
        qs = [self.q.copy()]
        for p in points:
            qs.append(self._ik(p, rot, qs[-1]))
        qs = np.array(qs)
        t0 = self.t
        self._add(s, qs, float(seglen.sum()) / speed, keyframe=False)
        seg = self.segments[-1]
        every = max(1, len(points) // 12)
        for k in range(every, len(qs), every):
            # time at which the min-jerk profile reaches s[k]
            tau = float(np.interp(s[k], _min_jerk(np.linspace(0, 1, 2001))[0], np.linspace(0, 1, 2001)))
            self.waypoints.append(qs[k].copy())
            self.times.append(t0 + tau * seg.duration)
            self.tcp.append(pts[k].copy())
        if self.times[-1] < self.t - 1e-9:
            self.waypoints.append(qs[-1].copy())
            self.times.append(self.t)
            self.tcp.append(pts[-1].copy())

    def dwell(self, seconds: float) -> None:
        self.segments.append(_Segment(self.t, seconds, np.array([0.0, 1.0]), np.vstack([self.q, self.q])))
        self.t += seconds


def plan_task(kin: PandaKinematics, task: TaskSpec | str, obj: ObjectPose, q_start,
              rng: np.random.Generator, catalogue: Catalogue | None = None) -> TaskPlan:
    """Plan one episode of `task` for the object at `obj` starting from joint positions q_start
    (the object's shape from the catalogue, the default one when None). Raises PlanError (a
    ValueError) when the object's pose makes the task unreachable."""
    spec = parse_task(task, catalogue)
    if obj.class_id != spec.object_class:
        raise PlanError(f"task {spec.name} is about {spec.object_class}, got a pose of {obj.class_id}")
    q0 = np.asarray(q_start, dtype=float).reshape(-1)
    if q0.shape != (7,) or not np.all(np.isfinite(q0)):
        raise PlanError(f"q_start must be 7 finite joint positions, got {q_start!r}")
    b = _Builder(kin, q0)
    shape = (catalogue or default_catalogue()).spec(obj.class_id)
    c = np.array([obj.x, obj.y])
    if spec.kind == "push":
        d = spec.direction_vector
        perp = np.array([-d[1], d[0]])
        p = {
            "approach_gap": float(rng.uniform(*APPROACH_GAP)),
            "lateral_offset": float(rng.uniform(-0.012, 0.012)),
            "push_height": float(rng.uniform(*PUSH_HEIGHT)),
            "tilt_deg": float(rng.uniform(*TILT_RANGE_DEG)),
            "hover_height": max(MIN_HOVER, shape.height + float(rng.uniform(*HOVER_EXTRA))),
            "extra_distance": float(rng.uniform(*EXTRA_DISTANCE)),
            "push_speed": float(rng.uniform(*PUSH_SPEED)),
            "transit_speed": float(rng.uniform(*TRANSIT_SPEED)),
            "hold": float(rng.uniform(0.3, 0.6)),  # s at the post-push pose
            "dwell": float(rng.uniform(0.1, 0.4)),
        }
        # Pre- and post-push poses depend on (x, y) only (push_start); the push goes on by the
        # footprint circle's slack, so a loaf lying end-on still moves the task distance plus the extra.
        start_xy = push_start(shape, c, d, p["approach_gap"]) + perp * p["lateral_offset"]
        slack = shape.footprint_radius - shape.min_half_extent
        end_xy = start_xy + d * (p["approach_gap"] + slack + spec.distance + p["extra_distance"])
        zp = p["push_height"]
        q_pre, rot, clearance, extra = _best_push_configuration(
            kin, [*start_xy, zp], [*start_xy, p["hover_height"]], d, math.radians(p["tilt_deg"]),
            reference_configuration(kin, spec, shape), obj, shape)
        p["tilt_deg"] += extra
        p["clearance"] = clearance
        b.joint_move([*start_xy, p["hover_height"]], rot, p["transit_speed"], seed=q_pre)
        b.line([*start_xy, zp], rot, p["transit_speed"] * DESCEND_SHARE)
        b.dwell(p["dwell"])
        b.line([*end_xy, zp], rot, p["push_speed"])
        b.dwell(p["hold"])
    elif spec.uses_hand:
        p = _plan_grasp(b, spec, shape, c, rng)
    elif spec.kind == "circle":
        p = {
            "radius": shape.footprint_radius + float(rng.uniform(*CIRCLE_GAP)),
            "height": shape.height + float(rng.uniform(*CIRCLE_HEIGHT)),
            "speed": float(rng.uniform(*CIRCLE_SPEED)),
            "transit_speed": float(rng.uniform(*TRANSIT_SPEED)),
            "start_angle_jitter": float(rng.uniform(-0.3, 0.3)),
        }
        tcp0 = kin.fk(q0)[0]
        a0 = math.atan2(tcp0[1] - c[1], tcp0[0] - c[0]) + p["start_angle_jitter"]
        n = 72
        angles = a0 + np.linspace(0.0, 2 * math.pi, n + 1)
        pts = np.column_stack([c[0] + p["radius"] * np.cos(angles), c[1] + p["radius"] * np.sin(angles),
                               np.full(n + 1, p["height"])])
        b.joint_move(pts[0], DOWN, p["transit_speed"])
        b.loop(pts[1:], DOWN, p["speed"])
    else:
        raise PlanError(f"unknown task kind {spec.kind!r}")
    events = p.pop("_hand_events", [])
    return TaskPlan(spec, q0, b.waypoints, np.array(b.times), b.tcp, b.segments, p, hand_events=events)


HAND_CLOSE_S = 1.4   # s the demonstrator waits for the fingers to close and squeeze (80 mm at 0.08 m/s)
HAND_OPEN_S = 0.8
# The path of a task with the hand never goes back over itself, so that a 1-D latent has one way
# forward at every state: the hand comes down onto the object sliding along its fingers' gap (from
# the robot's side, -x: the fingers pass either side of it), leaves on another line (a lift rises
# on away from the robot; a pick-and-place rises towards the target and comes down onto it), and
# after the place withdraws along the gap again (back towards the robot, up). A vertical descent
# and a lift over the same line ask the decoder for down and up at the same states under the same
# stick sign: a model trained on such demonstrations never brought the hand down to the object.


def _plan_grasp(b: _Builder, spec: TaskSpec, shape: ObjectSpec, c: np.ndarray, rng) -> dict:
    """Lift: hover behind the object (robot side) and above it, come down onto it along the
    fingers' gap (hand open), close, raise it by the task distance while going on away from the
    robot, hold. Pick and place: close, rise towards the target to the carry height half way there,
    come down onto the target, open, withdraw back and up. The hand points down (DOWN, fingers
    closing along world y): objects that fit the open hand at any yaw (the catalogue checks it), so
    the poses depend on (x, y) only, as the model's context."""
    z_grasp = grasp_height(shape)
    p = {
        "hover_height": z_grasp + float(rng.uniform(*GRASP_HOVER)),
        "approach_run": float(rng.uniform(*APPROACH_RUN)),
        "lift": float(spec.distance if spec.kind == "lift" else rng.uniform(*CARRY_LIFT)),
        "grasp_offset": float(rng.uniform(-0.004, 0.004)),   # along x: how well the hand is centred
        "transit_speed": float(rng.uniform(*GRASP_TRANSIT_SPEED)),
        "approach_speed": float(rng.uniform(*APPROACH_SPEED)),
        "carry_speed": float(rng.uniform(*CARRY_SPEED)),
        "hold": float(rng.uniform(2.4, 2.8) if spec.kind == "lift" else rng.uniform(0.3, 0.5)),
    }
    g = np.array([c[0] + p["grasp_offset"], c[1]])
    events = [(0.0, "open")]
    b.joint_move([g[0] - p["approach_run"], g[1], p["hover_height"]], DOWN, p["transit_speed"])
    b.line([*g, z_grasp], DOWN, p["approach_speed"])
    events.append((b.t, "grasp"))
    b.dwell(HAND_CLOSE_S)
    if spec.kind == "pick_place":
        goal = g + spec.direction_vector * spec.distance
        top = (g + goal) / 2
        b.line([*top, z_grasp + p["lift"]], DOWN, p["carry_speed"])
        b.line([*goal, z_grasp + PLACE_CLEARANCE], DOWN, p["carry_speed"])
        events.append((b.t, "open"))
        b.dwell(HAND_OPEN_S)
        b.line([goal[0] - RETREAT_RUN, goal[1], z_grasp + p["lift"]], DOWN, p["approach_speed"])
    else:
        b.line([g[0] + p["approach_run"], g[1], z_grasp + p["lift"]], DOWN, p["approach_speed"])
    b.dwell(p["hold"])
    p["_hand_events"] = events
    return p


def execute_plan(sim, plan: TaskPlan, safety=None, settle: float = 0.5, control_every: int = 1) -> float:
    """Run `plan` on a PandaSim-like object (q, time, set_velocity_command, step, physics_dt) from
    the simulator's current time, optionally through a SafetyFilter-like `safety.filter(cmd, q,
    now)` (its dt must equal physics_dt * control_every), then hold for `settle` seconds.
    Returns the simulated seconds it took."""
    t0 = sim.time
    period = sim.physics_dt * control_every
    n = int(math.ceil((plan.duration + settle) / period))
    for _ in range(n):
        t = sim.time - t0
        q = sim.q
        cmd = plan.command(t, q)
        if safety is not None:
            cmd, _code, _text = safety.filter(cmd, q, sim.time)
        else:
            cmd = np.clip(cmd, -np.asarray(DQ_MAX), np.asarray(DQ_MAX))
        sim.set_velocity_command(cmd)
        sim.step(control_every)
    sim.set_velocity_command(np.zeros(7))
    return sim.time - t0

"""A human-like operator on a 1-DoF stick: sees the scene, not the decoder.

The oracle teleoperator (sim_teleoperator.py) searches the decoder for the best stick value with the
planner's joint-space waypoint in hand; no person can. This operator sees only what a person sees:
where the hand (TCP) is, where the object is and how big it looks, and the goal as a person is told
it ("push the cereal box 15 cm south", "circle the cereal box"). On latent actions it pushes the
stick, watches after its reaction delay whether the task looks nearer done (the hand behind the
object, then the object moving; the angle gone round it) and keeps or reverses the direction: the
path is the robot's. On the end-effector baseline it makes its own plan of hand positions, no better
than a person told the goal makes (above and behind the object, down, through; round a circled object's
corners) and moves one Cartesian axis at a time, switching modes with a button. (A first version
steered the latent axis towards its own plan of hand positions too; the learned motion takes other
paths, so it reversed while the arm was progressing: docs/results/study.)

Both learn from their practice trial of a setting the same kind of thing (`Lesson`): on latent actions
which way of the stick brought the task nearer, on the end effector whether the object moved before
the hand was in place (then it gives the object more room). Earlier versions gave the end-effector
participant practised knowledge the latent one had not: a ring of ten points for the circle and extra
wrist clearance for pushes towards the robot (issue 33).

Human parameters, from the literature:
- reaction delay: 0.24 s mean (Card, Moran & Newell 1983, The Psychology of Human-Computer
  Interaction: perceptual 100 + cognitive 70 + motor 70 ms), spread 0.05 s; people with motor
  impairments are slower (we sample 0.15-0.5 s).
- perception noise on positions: 0.5-1.5 cm standard deviation (van Beers, Sittig & Denier van der
  Gon 1999, J. Neurophysiol. 81: visual localisation of the hand, ~0.5 cm lateral, ~1 cm in depth).
- motor noise: signal-dependent, sd = k |u| with k ~ 0.1 (Harris & Wolpert 1998, Nature 394),
  plus a floor; limited stick resolution (10 levels per side, a coarse 1-DoF assistive joystick).
- lapses: 2 % of decisions are lost for 0.5-1.5 s (Wichmann & Hill 2001, Percept. Psychophys. 63:
  lapse rates of 0-6 %).
- mode switches (end-effector baseline): each costs a decision and button presses through the
  controller's mode cycle. Calibrated against Herlant, Holladay & Srinivasa 2016 (HRI, "Assistive
  teleoperation of robot arms via automatic time-optimal mode switching"), who measured mode switching
  at 17.4 % of execution time with a joystick:
  - the cycle: the study's controller cycles x, y, z only (`end_effector_axes`, the controller's
    ee_axes; the tasks are done with the hand pointing down), so a switch takes 1 or 2 presses, not
    up to 5 through roll, pitch and yaw (at 34 % of execution time with all six);
  - `press_time` (per press, 0.16-0.28 s): the keystroke time K of the Keystroke-Level Model (Card,
    Moran & Newell 1980, CACM 23(7): 0.20 s for an average skilled typist, 0.28 s for an average
    non-secretary), above the study controller's 0.15 s debounce (`end_effector_debounce`);
  - `switch_time` (the decision, 0.1-0.4 s): a choice among the modes on top of the reaction delay,
    which already delays what the person sees;
  the share the population reaches is in docs/results/study/README.md (above 17.4 %: our tasks are
  short and the arm moves at 0.2 m/s, so a switch weighs more against the motion).
The model never sees the controller's decoder or the planner's waypoints: test_study checks it.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

# The end-effector baseline's full axis cycle (vla_latent_controller.ee_baseline.EE_AXES); a person
# reads the cycle in use (the controller's ee_axes) off the operator station, we repeat the names here
# instead of importing the controller.
EE_CYCLE = ("x", "y", "z", "roll", "pitch", "yaw")
XYZ = ("x", "y", "z")
AWAITING_NEUTRAL = 9  # vla_interfaces/ControllerStatus.AWAITING_NEUTRAL: release the stick


@dataclass(frozen=True)
class HumanParams:
    """One participant's parameters (see the module docstring for the sources)."""

    reaction_s: float = 0.24
    perception_sd_m: float = 0.01
    motor_k: float = 0.1
    motor_floor: float = 0.02
    resolution: int = 10  # stick levels per side
    lapse_p: float = 0.02  # per decision
    lapse_s: float = 1.0
    switch_time: float = 0.25  # decision before a mode switch (s)
    press_time: float = 0.22  # per button press (s): KLM's K; above the study controller's debounce
    commit_s: float = 0.6  # how long a direction is held before it is judged
    gain: float = 1.0  # stick per 0.15 m of remaining path (how boldly the person pushes)
    # the decision policy (not drawn per participant; varied by the sensitivity sweep):
    reverse_margin: float = 2.0  # latent: reverse when the task looks further by this many perception sds
    stall_push: int = 2  # latent: judgements with no visible change before pushing fully
    stall_turn: int = 4  # latent: ... before trying the other way
    reach_tol: float = 0.04  # end effector: how near (m) a point of the plan counts as reached

    def to_dict(self) -> dict:
        return asdict(self)


def population(n: int = 9, seed: int = 2026) -> list[HumanParams]:
    """n participants with parameters drawn around the literature's means (seeded)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(int(n)):
        out.append(HumanParams(
            reaction_s=float(np.clip(rng.normal(0.24, 0.05), 0.15, 0.5)),
            perception_sd_m=float(rng.uniform(0.005, 0.015)),
            motor_k=float(rng.uniform(0.05, 0.15)),
            resolution=int(rng.choice([5, 10, 20])),
            lapse_p=float(rng.uniform(0.0, 0.04)),
            lapse_s=float(rng.uniform(0.5, 1.5)),
            switch_time=float(rng.uniform(0.1, 0.4)),
            press_time=float(rng.uniform(0.16, 0.28)),
            commit_s=float(rng.uniform(0.4, 0.8)),
            gain=float(rng.uniform(0.8, 1.2)),
        ))
    return out


@dataclass(frozen=True)
class TaskGoal:
    """The task as a person is told it and sees it: the object, its size, what to do."""

    kind: str  # "push", "circle" or "pick_place" (hand_participant)
    direction: tuple[float, float] | None  # unit (x, y) for a push or where to put the object
    distance: float  # m to push, or to carry
    object_height: float
    object_radius: float  # footprint radius


@dataclass
class Observation:
    """What the person sees at time t (true values; the model adds its own noise)."""

    t: float
    hand: np.ndarray  # TCP (x, y, z)
    obj: np.ndarray  # object (x, y)
    controller_code: int = 0
    ee_axis: str = "x"
    # tasks with the hand (hand_participant): the object's height, the hand as the fingers show it
    # ("open", "holding", "empty": closed on nothing, "busy": moving) and the controller's mode
    obj_z: float = math.nan
    hand_state: str = ""
    mode: str = ""


@dataclass
class Action:
    axis: float  # stick deflection in [-1, 1]
    press: bool = False  # mode button (end-effector baseline)
    done: bool = False  # the person thinks the task is done
    grasp: bool = False  # the grasp button (tasks with the hand: one press toggles the hand)
    switch_mode: str = ""  # hybrid control: switch the controller to this mode (the station's switch)


@dataclass(frozen=True)
class Lesson:
    """What a participant took from their practice trial of a setting, carried to its test trials (the
    paper's participants practised each strategy first). The same kind of knowledge for both
    strategies: one thing seen to work or to go wrong in practice.
    - latent actions: which way of the stick brought the task nearer (`direction`);
    - end effector: the object moved before the hand was in place to push it (or was knocked on the way
      round), so give it more room (`clearance_m`, 5 cm more each time, at most 15 cm)."""

    direction: float = 1.0
    clearance_m: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict | None) -> Lesson:
        return cls(**{k: float(v) for k, v in (d or {}).items() if k in ("direction", "clearance_m")})


CLEARANCE_STEP, CLEARANCE_MAX = 0.05, 0.15
# How low a person told to push something puts the hand behind it (m above the table): where both
# strategies' participants aim, the end-effector plan's point behind and low and the latent one's
# watched approach. The latent one first counted the hand's height only down to the object's top, so
# behind a tall object (the cereal box, 0.27 m) the ~2 s descent to push height showed no progress and
# it reversed the stick there (issue 34: Seen, test layouts at d516eee, 6 of its 10 failures).
PUSH_LOW_M = 0.03
MOVED_M = 0.04  # the object seen this far from where it stood (5-view means) has moved


def plan_hand_points(goal: TaskGoal, hand: np.ndarray, obj: np.ndarray, clearance: float = 0.0
                     ) -> list[np.ndarray]:
    """The plan of hand positions a person told the goal makes from what they see (not the robot's
    planner, and no practised trick: what practice taught comes in as `clearance`). A push: above and
    behind the object, down, through. A circle: round the object's corners one axis at a time (as the
    end-effector's modes move), once and a quarter more."""
    obj = np.asarray(obj, float)[:2]
    if goal.kind == "push":
        d = np.asarray(goal.direction, float)
        behind = obj - d * (goal.object_radius + 0.04 + clearance)
        hover = max(0.18, goal.object_height + 0.08)
        low = PUSH_LOW_M
        through = behind + d * (goal.distance + 0.06)
        return [np.array([*behind, hover]), np.array([*behind, low]), np.array([*through, low])]
    r = goal.object_radius + 0.04 + clearance
    z = goal.object_height + 0.07
    signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))   # round the object's corners, anticlockwise from above
    corners = [np.array([obj[0] + sx * r, obj[1] + sy * r, z]) for sx, sy in signs]
    first = int(np.argmin([np.linalg.norm(c[:2] - np.asarray(hand, float)[:2]) for c in corners]))
    return [corners[(first + i) % 4] for i in range(6)]


class HumanOperator:
    """Steps at the control rate; `act(obs)` returns the stick (and the mode button)."""

    def __init__(self, params: HumanParams, goal: TaskGoal, mode: str, seed: int = 0,
                 reach_tol: float | None = None, cycle: tuple[str, ...] = EE_CYCLE,
                 lesson: Lesson | None = None) -> None:
        """`cycle`: the axes the end-effector mode button cycles (the controller's ee_axes; with x, y, z).
        `lesson`: what the participant's practice trial of this setting taught (None: no practice)."""
        if mode not in ("latent", "end_effector"):
            raise ValueError(f"mode must be latent or end_effector, got {mode!r}")
        if not set(XYZ) <= set(cycle):
            raise ValueError(f"the mode cycle must hold x, y and z, got {list(cycle)}")
        self.p, self.goal, self.mode, self.cycle = params, goal, mode, tuple(cycle)
        self.rng = np.random.default_rng(seed)
        self.reach_tol = params.reach_tol if reach_tol is None else reach_tol
        self.seen: deque[Observation] = deque()
        self.plan: list[np.ndarray] | None = None
        self.start_obj: np.ndarray | None = None
        self.k = 0  # current plan point
        self.taught = lesson or Lesson()
        self.direction = self.taught.direction
        self.progress = {1.0: 0.0, -1.0: 0.0}  # latent: how much nearer each way of the stick brought it
        self.obj_views: deque[np.ndarray] = deque(maxlen=5)  # the object, last seen (for moved_early)
        self.start_views: list[np.ndarray] = []  # the object, first seen
        self.moved_early = False  # end effector: the object moved before the hand was in place
        self.judge_at = 0.0
        self.last_cost = math.inf
        self.busy_until = 0.0  # lapse, switch decision or press
        self.presses_left = 0
        self.neutral_until = -1.0
        self.axis_index = 0  # what the person believes the mode is (read off the status)
        self.stick = 0.0
        self.done = False
        self.n_inputs = 0
        self.n_switches = 0
        self.switch_s = 0.0
        self.reversals = 0
        self.lapses = 0
        self.next_decision = 0.0
        self.magnitude = 1.0  # latent: how far the person pushes now
        self.stalls = 0  # latent: judgements in a row with no visible progress
        self.sweep = 0.0  # circle: how far round the object the hand has gone (rad, signed)
        self.sweep_sign = 0.0  # circle: the way round the person goes with, once it is seen
        self.last_angle: float | None = None

    # ------------------------------------------------------------------ perception
    def _perceive(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        sd = self.p.perception_sd_m
        return (np.asarray(obs.hand, float) + self.rng.normal(0, sd, 3),
                np.asarray(obs.obj, float)[:2] + self.rng.normal(0, sd, 2))

    def _delayed(self, obs: Observation) -> Observation | None:
        self.seen.append(obs)
        out = None
        while self.seen and self.seen[0].t <= obs.t - self.p.reaction_s + 1e-9:
            out = self.seen.popleft()
        if out is not None:
            self.seen.appendleft(out)  # the newest old-enough view stays until a newer one replaces it
            while len(self.seen) > 1 and self.seen[1].t <= obs.t - self.p.reaction_s + 1e-9:
                self.seen.popleft()
        return out

    def _remaining(self, hand: np.ndarray) -> float:
        """Path left along the plan from the (perceived) hand."""
        pts = self.plan[self.k:]
        if not pts:
            return 0.0
        s = float(np.linalg.norm(pts[0] - hand))
        return s + sum(float(np.linalg.norm(b - a)) for a, b in zip(pts, pts[1:]))

    def _finished(self, obj: np.ndarray) -> bool:
        if self.goal.kind == "push":
            moved = float(np.dot(obj - self.start_obj, np.asarray(self.goal.direction)))
            return moved >= self.goal.distance + 0.01
        if self.mode == "latent":  # all the way round, as the person sees it
            return self.sweep_sign * self.sweep >= 2 * math.pi
        return self.k >= len(self.plan)

    def _follow_sweep(self, hand: np.ndarray) -> None:
        """Circle: the angle the hand has gone round the object's start (summed steps, so perception
        noise does not add up); the person goes with the way round it first sees the hand turn."""
        if self.goal.kind != "circle":
            return
        rel = hand[:2] - self.start_obj
        if np.linalg.norm(rel) < self.goal.object_radius:  # right above the centre: no angle to read
            return
        a = math.atan2(rel[1], rel[0])
        if self.last_angle is not None:
            self.sweep += (a - self.last_angle + math.pi) % (2 * math.pi) - math.pi
        self.last_angle = a
        if not self.sweep_sign and abs(self.sweep) > 0.5:
            self.sweep_sign = math.copysign(1.0, self.sweep)

    def _watch_object(self, obj: np.ndarray) -> None:
        """Whether the object moved before the hand was in place to push it (before the plan's point
        behind and low; for a circle, at any time): a lesson for the next trial (`lesson`)."""
        if len(self.start_views) < 5:
            self.start_views.append(obj)
            return
        self.obj_views.append(obj)
        in_place = self.goal.kind == "push" and self.k >= 2
        moved = float(np.linalg.norm(np.mean(self.obj_views, axis=0) - np.mean(self.start_views, axis=0)))
        if len(self.obj_views) == self.obj_views.maxlen and not in_place and moved > MOVED_M:
            self.moved_early = True

    def lesson(self) -> Lesson:
        """What this trial teaches the next ones of its setting (it was a practice trial)."""
        if self.mode == "latent":
            best = max(self.progress, key=self.progress.get)
            return Lesson(direction=best if self.progress[best] > 0 else self.taught.direction,
                          clearance_m=self.taught.clearance_m)
        more = CLEARANCE_STEP if self.moved_early else 0.0
        return Lesson(direction=self.taught.direction,
                      clearance_m=round(min(CLEARANCE_MAX, self.taught.clearance_m + more), 3))

    def _task_cost(self, hand: np.ndarray, obj: np.ndarray) -> float:
        """How far from done the task looks (m): what a person watches on a latent axis. They do not
        know the path the robot will take (the demonstrations'), only where it has to end up: for a
        push the hand behind the object and low (PUSH_LOW_M), then the object moving the told distance;
        for a circle the hand near the object and the angle still to go round it (metres of arc)."""
        g = self.goal
        if g.kind == "push":
            d = np.asarray(g.direction, float)
            moved = float(np.dot(obj - self.start_obj, d))
            remaining = max(0.0, g.distance + 0.01 - moved)
            contact = obj - d * (g.object_radius + 0.02)
            approach = float(np.linalg.norm(hand[:2] - contact)) + max(0.0, float(hand[2]) - PUSH_LOW_M)
            return 2.0 * remaining + approach
        ring = g.object_radius + 0.065
        off_ring = abs(float(np.linalg.norm(hand[:2] - self.start_obj)) - ring)
        gone = self.sweep_sign * self.sweep if self.sweep_sign else abs(self.sweep)
        knocked = float(np.linalg.norm(obj - self.start_obj))
        return ring * max(0.0, 2 * math.pi - gone) + off_ring + 3.0 * knocked

    def _motor(self, u: float) -> float:
        """Signal-dependent noise, then the stick's resolution."""
        u = u + self.rng.normal(0.0, self.p.motor_k * abs(u) + self.p.motor_floor)
        levels = max(1, int(self.p.resolution))
        return float(np.clip(np.round(u * levels) / levels, -1.0, 1.0))

    # ------------------------------------------------------------------ acting
    def act(self, obs: Observation) -> Action:
        t = obs.t
        if obs.controller_code == AWAITING_NEUTRAL:  # the controller asks for neutral: release it
            self.neutral_until = t + self.p.reaction_s
        if self.mode == "end_effector" and obs.ee_axis in self.cycle:
            self.axis_index = self.cycle.index(obs.ee_axis)
        view = self._delayed(obs)
        if view is None or self.done:
            return self._out(0.0, done=self.done)
        hand, obj = self._perceive(view)
        if self.plan is None:
            self.plan = plan_hand_points(self.goal, hand, obj, self.taught.clearance_m)
            self.start_obj = obj.copy()
        self._watch_object(obj)
        if self.mode == "latent":
            self._follow_sweep(hand)
        if self._finished(obj):
            self.done = True
            return self._out(0.0, done=True)
        if self.mode == "latent":
            return self._latent_turn(t, hand, obj)
        while self.k < len(self.plan) and np.linalg.norm(self.plan[self.k] - hand) < self.reach_tol:
            self.k += 1
            self.last_cost = math.inf
        if self.k >= len(self.plan):
            self.done = self.goal.kind != "push"
            return self._out(0.0, done=self.done)
        if t < self.neutral_until:
            return self._out(0.0)
        if t < self.busy_until:  # thinking about a switch, between presses, or a lapse
            return self._out(0.0 if self.presses_left or self.mode == "end_effector" else self.stick)
        if self.presses_left > 0:  # one press of the mode button, then the next after press_time
            self.presses_left -= 1
            self.busy_until = t + self.p.press_time
            self.n_inputs += 1
            self.stick = 0.0
            return Action(0.0, press=True)
        if t >= self.next_decision:  # a decision every commit_s; some of them are lost (a lapse)
            self.next_decision = t + self.p.commit_s
            if self.rng.random() < self.p.lapse_p:
                self.busy_until = t + self.p.lapse_s
                self.lapses += 1
            return self._out(self.stick)  # a lapse: the hand stays where it was
        return self._end_effector(t, hand)

    def _latent_turn(self, t: float, hand: np.ndarray, obj: np.ndarray) -> Action:
        """The shared timing (neutral requests, lapses, a decision every commit_s), then `_latent`."""
        if t < self.neutral_until:
            return self._out(0.0)
        if t < self.busy_until:  # a lapse: the hand stays where it was
            return self._out(self.stick)
        if t >= self.next_decision:
            self.next_decision = t + self.p.commit_s
            if self.rng.random() < self.p.lapse_p:
                self.busy_until = t + self.p.lapse_s
                self.lapses += 1
                return self._out(self.stick)
        return self._latent(t, hand, obj)

    def _latent(self, t: float, hand: np.ndarray, obj: np.ndarray) -> Action:
        """Push, watch whether the task gets nearer, keep or reverse. On a latent axis the motion's
        shape is the robot's (the demonstrations'), only its direction and extent are the person's, so
        they judge the task, not a path of their own.

        Every commit_s the person compares how far from done the task looks with the last time: worse
        by more than they can see (`reverse_margin` times their perception noise, 2) and they reverse;
        no visible change `stall_push` times in a row (2) and they push fully, `stall_turn` times (4)
        and they try the other way; better and they
        keep going, easing off as the end nears. (Also tried, on a 9-trial circle run, and not kept:
        a stuck person trying other extents of the stick (0.6, 0.3) before turning; no better.)
        """
        if t >= self.judge_at:
            cost = self._task_cost(hand, obj)
            seen = self.p.reverse_margin * self.p.perception_sd_m
            if math.isfinite(self.last_cost):
                if cost > self.last_cost + seen:
                    self.direction = -self.direction
                    self.reversals += 1
                    self.stalls = 0
                elif cost > self.last_cost - seen:
                    self.stalls += 1
                    if self.stalls >= self.p.stall_turn:
                        self.direction = -self.direction
                        self.reversals += 1
                        self.stalls = 0
                else:
                    self.stalls = 0
                    self.progress[self.direction] += self.last_cost - cost
            self.magnitude = 1.0 if self.stalls >= self.p.stall_push else float(
                np.clip(self.p.gain * cost / 0.15, 0.4, 1.0))
            self.last_cost = cost
            self.judge_at = t + self.p.commit_s
        return self._out(self._motor(self.direction * self.magnitude))

    def _end_effector(self, t: float, hand: np.ndarray) -> Action:
        """One axis at a time: the axis with the largest error, switched with the button."""
        err = self.plan[self.k] - hand
        here = self.cycle[self.axis_index]
        rotation = here not in XYZ
        cur = 0 if rotation else XYZ.index(here)
        want = int(np.argmax(np.abs(err)))
        tol = self.reach_tol / 2
        settled = abs(err[cur]) < tol or abs(err[want]) > 3 * abs(err[cur]) + tol
        if rotation or (want != cur and settled):
            presses = (self.cycle.index(XYZ[want]) - self.axis_index) % len(self.cycle)
            if presses:
                self.presses_left = presses
                self.busy_until = t + self.p.switch_time
                self.n_switches += 1
                self.switch_s += self.p.switch_time + presses * self.p.press_time
                return self._out(0.0)
            cur = want
        e = float(err[cur])
        mag = float(np.clip(self.p.gain * abs(e) / 0.05, 0.2, 1.0))
        return self._out(self._motor(math.copysign(mag, e)))

    def _out(self, axis: float, press: bool = False, done: bool = False) -> Action:
        if axis != 0.0 and (self.stick == 0.0 or (axis > 0) != (self.stick > 0)):
            self.n_inputs += 1  # a new deflection: from rest, or the other way
        self.stick = axis
        return Action(axis, press, done)

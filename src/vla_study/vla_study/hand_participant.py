"""The human-like participant's pick-and-place: what a person told the goal does with the hand.

Told "pick up the glass bottle and put it down 15 cm west", a person drives the hand to the bottle
with the fingers open, presses grasp when the fingers look around it, waits for the fingers, carries it
until it looks over the place and low, presses again to let go, and says done once the hand is open.
It is a HumanOperator: the same perception noise, reaction delay, motor noise, stick resolution, lapses
and mode-switch costs as on the pushes. Every strategy gets the same knowledge: the object where it is
seen (careful judgements on `VIEWS`-view means), its size, the hand's position and what the fingers
show (open, holding, closed on nothing, moving), the goal as told; never the planner's grasp point or
place pose, nor the decoder.

Three ways to drive (the study's strategies, `protocol_schema.STRATEGIES`):
- latent (latent-YOLO alone): push the stick, watch whether the phase's goal looks nearer, keep or
  reverse (HumanOperator._latent); press where the fingers look around the bottle, or, once the hand
  has stopped getting nearer within `SETTLE_RANGE`, press there anyway (nothing else moves the hand);
- end_effector: a plan of hand positions a person makes (above the bottle, down round its neck; up,
  over the place, down to where it was grasped), one Cartesian axis at a time with the mode button;
- hybrid (hybrid control): the latent until the hand has stopped getting nearer within `FINE_RANGE`
  of the phase's goal (or anywhere, for `GIVE_UP_S`), then the controller switched to end-effector
  mode (the operator station's mode switch: a decision and a click) to finish the phase, and back to
  the latent for the next one.
What practice teaches (`Lesson`), the same kind of thing as on the pushes: on latent actions which way
of the stick brought the task nearer; on the end effector, if the bottle moved before the grasp, more
room above it on the way down.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from vla_study.participant import (
    AWAITING_NEUTRAL,
    CLEARANCE_MAX,
    CLEARANCE_STEP,
    EE_CYCLE,
    XYZ,
    Action,
    HumanOperator,
    HumanParams,
    Lesson,
    Observation,
    TaskGoal,
)

OPEN, HOLDING, EMPTY, BUSY = "open", "holding", "empty", "busy"   # the hand as the fingers show it
REACH, CLOSE, CARRY, RELEASE = "reach", "close", "carry", "release"
MODES = ("latent", "end_effector", "hybrid")
# the three conditions as the results name them (a row's `condition`)
CONDITIONS = {"latent": "latent alone", "end_effector": "end-effector alone", "hybrid": "hybrid control"}


def condition(mode: str, assistance: str = "off") -> str:
    """A row's condition as the results name it: `latent alone`, `latent with assistance high`."""
    if assistance == "off":
        return CONDITIONS[mode]
    return f"{CONDITIONS[mode].removesuffix(' alone')} with assistance {assistance}"


NECK_BELOW_TOP = 0.035   # m: the fingers (5 cm) closed round the object's top: the hand this far below it
AROUND_XY, AROUND_Z = 0.012, 0.015   # m: the fingers look around the object (means of VIEWS views)
HOVER = 0.08             # m above the grasp point before coming down (end effector; + practice's room)
LIFT = 0.08              # m the object is raised to carry it (end effector)
PLACE_XY, PLACE_Z = 0.02, 0.015      # m: the object looks over its place and low: let go
CARRY_HEIGHT_WEIGHT = 0.3   # latent: how much the object's height counts against it while carried
VIEWS = 5                # views averaged for where the hand and object are (as the object's movement)
LOOK = 10                # views averaged for a grasp's or a place's judgement (0.5 s at 20 Hz: a look)
STALL_S = 2.0            # s without PROGRESS m nearer: the hand has stopped getting nearer
PROGRESS = 0.01
SETTLE_RANGE = 0.08      # latent alone: stopped this near (and as near as it got), the person tries there
FINE_RANGE = 0.15        # hybrid: stopped this near, the person switches to end-effector mode
GIVE_UP_S = 6.0          # hybrid: ... or anywhere, once the latent has not brought it nearer for this long
THERE = 0.025            # end effector: stopped this near the plan's end, the person presses there
HAND_WAIT_S = 1.5        # s after a press with the hand seen unchanged: press again
FINE_TOL, COARSE_TOL = 0.012, 0.03   # m: end-effector plan points that must be exact, or need not
RAMP = 0.10              # m: end effector, the stick full from this far, in proportion nearer (pushes: 5 cm)


class PickPlaceOperator(HumanOperator):
    """`act(obs)` returns the stick, the mode button, the grasp button and, for hybrid control, a
    switch of the controller's mode; `mode`: latent, end_effector or hybrid."""

    def __init__(self, params: HumanParams, goal: TaskGoal, mode: str, seed: int = 0,
                 cycle: tuple[str, ...] = EE_CYCLE, lesson: Lesson | None = None,
                 assistance: str = "off") -> None:
        if goal.kind != "pick_place":
            raise ValueError(f"PickPlaceOperator is for pick_place tasks, got {goal.kind!r}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        super().__init__(params, goal, "end_effector" if mode == "end_effector" else "latent", seed,
                         cycle=cycle, lesson=lesson)
        self.mode, self.assistance = mode, assistance   # the level the station shows (the condition's)
        self.driving = "end_effector" if mode == "end_effector" else "latent"
        self.phase = REACH
        self.hands: deque[np.ndarray] = deque(maxlen=LOOK)
        self.objs: deque[np.ndarray] = deque(maxlen=LOOK)
        self.hand_now = self.obj_now = np.zeros(3)
        self.start: np.ndarray | None = None   # the object where it stood (x, y, z), first seen
        self.pressed_at = -math.inf
        self.grasp_z = math.nan
        self.offset = np.zeros(2)   # the hand's (x, y) from the object's while carried
        self.best, self.best_t = math.inf, 0.0
        self.tols: list[float] = []
        self.planned_for: np.ndarray | None = None
        self.pending_mode, self.mode_sent = "", False
        self.lapse_hold = False
        self.grasp_presses = self.failed_grasps = self.mode_changes = 0

    # ------------------------------------------------------------------ what the person sees
    def _see(self, view: Observation) -> None:
        hand, obj = self._perceive(view)
        z = float(view.obj_z) + float(self.rng.normal(0.0, self.p.perception_sd_m))
        self.hand_now, self.obj_now = hand, np.array([obj[0], obj[1], z])
        self.hands.append(hand)
        self.objs.append(self.obj_now)
        if self.start is None and len(self.objs) == LOOK:
            self.start = np.mean(self.objs, axis=0)
            self.start_obj = self.start[:2].copy()
        if self.phase == REACH:
            self._watch_object(obj)   # moved before the grasp: a lesson (more room above it)

    def hand(self, n: int = VIEWS) -> np.ndarray:
        """Where the hand is seen: the mean of the last `n` views (LOOK: a careful look)."""
        return np.mean(list(self.hands)[-n:], axis=0)

    def obj(self, n: int = VIEWS) -> np.ndarray:
        return np.mean(list(self.objs)[-n:], axis=0)

    def grasp_point(self, n: int = VIEWS) -> np.ndarray:
        h = self.goal.object_height
        return np.array([*self.obj(n)[:2], max(h - NECK_BELOW_TOP, h / 2)])

    def target(self) -> np.ndarray:
        """Where the object is to be put down (x, y), from where it was seen standing."""
        return self.start[:2] + np.asarray(self.goal.direction, float) * self.goal.distance

    def _to_goal(self, hand: np.ndarray, obj: np.ndarray) -> float:
        """How far from the phase's goal (m): the fingers from the neck; the object from its place."""
        if self.phase in (REACH, CLOSE):
            return float(np.linalg.norm(hand - self.grasp_point()))
        above = max(0.0, float(obj[2] - self.start[2]))
        return float(np.linalg.norm(obj[:2] - self.target())) + CARRY_HEIGHT_WEIGHT * above

    def _around(self) -> bool:
        err = self.hand(LOOK) - self.grasp_point(LOOK)
        return float(np.linalg.norm(err[:2])) <= AROUND_XY and abs(float(err[2])) <= AROUND_Z

    def _over_place(self) -> bool:
        obj = self.obj(LOOK)
        return (float(np.linalg.norm(obj[:2] - self.target())) <= PLACE_XY
                and float(obj[2] - self.start[2]) <= PLACE_Z)

    # ------------------------------------------------------------------ acting
    def act(self, obs: Observation) -> Action:
        t = obs.t
        if obs.controller_code == AWAITING_NEUTRAL:
            self.neutral_until = t + self.p.reaction_s
        if obs.ee_axis in self.cycle:
            self.axis_index = self.cycle.index(obs.ee_axis)
        view = self._delayed(obs)
        if view is None or self.done:
            return self._out(0.0, done=self.done)
        self._see(view)
        if self.start is None or t < self.neutral_until:
            return self._out(0.0)   # still looking at the scene, or the controller asks for neutral
        if t < self.busy_until:     # a lapse holds the latent's stick; anything else rests it
            return self._out(self.stick if self.lapse_hold and self.driving == "latent" else 0.0)
        self.lapse_hold = False
        if self.presses_left > 0:   # the end effector's mode button, one press at a time
            self.presses_left -= 1
            self.busy_until = t + self.p.press_time
            self.n_inputs += 1
            self.stick = 0.0
            return Action(0.0, press=True)
        if self.pending_mode:
            return self._switching(t, view.mode)
        step = self._hand_step(t, view.hand_state)
        if step is not None:
            return step
        if t >= self.next_decision:   # a decision every commit_s; some are lost (a lapse)
            self.next_decision = t + self.p.commit_s
            if self.rng.random() < self.p.lapse_p:
                self.busy_until, self.lapse_hold = t + self.p.lapse_s, True
                self.lapses += 1
                return self._out(self.stick if self.driving == "latent" else 0.0)
        if self.driving == "latent":
            return self._latent(t, self.hand_now, self.obj_now[:2])
        return self._ee(t)

    def _task_cost(self, hand: np.ndarray, obj: np.ndarray) -> float:
        """The latent's judgement (HumanOperator._latent) on single views: how far the phase's goal."""
        return self._to_goal(self.hand_now, self.obj_now)

    def _hand_step(self, t: float, seen: str) -> Action | None:
        """The hand's part of a step: wait for the fingers, press grasp, change phase, or switch mode;
        None: drive on."""
        if seen == BUSY:
            return self._out(0.0)   # the fingers move: the person waits for them
        if self.phase == CLOSE:
            return self._closing(t, seen)
        if self.phase == RELEASE:
            if seen == OPEN:
                self.done = True
                return self._out(0.0, done=True)
            return self._press(t, RELEASE) if t - self.pressed_at >= HAND_WAIT_S else self._out(0.0)
        if self.phase == REACH and seen != OPEN:   # closed (the reset leaves it so): open it first
            return self._press(t, REACH) if t - self.pressed_at >= HAND_WAIT_S else self._out(0.0)
        if self.phase == CARRY and seen != HOLDING:   # dropped: back to the bottle, open
            self._enter(REACH, t)
            return self._out(0.0)
        dist = self._to_goal(self.hand(), self.obj())
        if dist < self.best - PROGRESS:
            self.best, self.best_t = dist, t
        stalled = t - self.best_t >= STALL_S
        if self._arrived(dist, stalled):
            return self._press(t, CLOSE if self.phase == REACH else RELEASE)
        if self.mode == "hybrid" and self.driving == "latent" and stalled and (
                dist <= FINE_RANGE or t - self.best_t >= GIVE_UP_S):
            return self._switch(t, "end_effector")
        return None

    def _arrived(self, dist: float, stalled: bool) -> bool:
        """The fingers look around the bottle (or the bottle over its place and low); or the hand has
        stopped getting nearer, close enough that a person tries there."""
        if self.phase == REACH and self._around() or self.phase == CARRY and self._over_place():
            return True
        if not stalled:
            return False
        if self.driving == "end_effector":
            return dist <= THERE
        low = self.phase == REACH or float(self.obj()[2] - self.start[2]) <= 2 * PLACE_Z
        return self.mode == "latent" and dist <= min(SETTLE_RANGE, self.best + PROGRESS) and low

    def _closing(self, t: float, seen: str) -> Action:
        """After the grasp press: holding, carry; closed on nothing, open again and back to the bottle."""
        if seen == HOLDING:
            self._enter(CARRY, t)
            self.grasp_z = float(self.hand()[2])
            self.offset = self.hand()[:2] - self.obj()[:2]
            if self.mode == "hybrid" and self.driving == "end_effector":
                return self._switch(t, "latent")
            return self._out(0.0)
        if seen == EMPTY:
            self.failed_grasps += 1
            return self._press(t, REACH)
        return self._press(t, CLOSE) if t - self.pressed_at >= HAND_WAIT_S else self._out(0.0)

    def _press(self, t: float, phase: str) -> Action:
        """One press of the grasp button (a toggle), the stick released; then the phase."""
        if phase != self.phase:
            self._enter(phase, t)
        self.pressed_at = t
        self.busy_until = t + self.p.press_time
        self.grasp_presses += 1
        self.n_inputs += 1
        self.stick = 0.0
        return Action(0.0, grasp=True)

    def _enter(self, phase: str, t: float) -> None:
        self.phase = phase
        self.best, self.best_t = math.inf, t
        self.last_cost = math.inf
        self.plan, self.planned_for = None, None

    def _switch(self, t: float, mode: str) -> Action:
        """Hybrid control: decide to switch (switch_time), then click the station's mode switch."""
        self.pending_mode, self.mode_sent = mode, False
        self.busy_until = t + self.p.switch_time
        self.switch_s += self.p.switch_time + self.p.press_time
        self.mode_changes += 1
        return self._out(0.0)

    def _switching(self, t: float, shown: str) -> Action:
        """The click, then the stick at rest until the station shows the mode."""
        if shown == self.pending_mode:
            self.driving, self.pending_mode = self.pending_mode, ""
            self.plan, self.last_cost = None, math.inf
            self.best, self.best_t = math.inf, t
            return self._out(0.0)
        if not self.mode_sent:
            self.mode_sent = True
            self.busy_until = t + self.p.press_time
            self.n_inputs += 1
            self.stick = 0.0
            return Action(0.0, switch_mode=self.pending_mode)
        return self._out(0.0)

    # ------------------------------------------------------------------ end-effector mode
    def _ee(self, t: float) -> Action:
        """Along the person's plan for the phase, one axis at a time (HumanOperator._end_effector)."""
        hand = self.hand()
        goal = self.grasp_point() if self.phase == REACH else np.array([*self.target(), 0.0])
        if self.plan is None or np.linalg.norm(goal[:2] - self.planned_for[:2]) > 2 * AROUND_XY:
            self.plan, self.tols = self._ee_plan(hand)
            self.k, self.planned_for = 0, goal
        while self.k < len(self.plan) - 1 and np.linalg.norm(self.plan[self.k] - hand) < self.tols[self.k]:
            self.k += 1
        return self._ee_drive(t, hand, self.plan[self.k], self.tols[self.k])

    def _ee_drive(self, t: float, hand: np.ndarray, point: np.ndarray, tol: float) -> Action:
        """One axis at a time, as on the pushes (HumanOperator._end_effector), but with the care a grasp
        needs: the current axis finished (within tol/2) before switching to the one with the largest
        error (so the hand never comes down beside the bottle), and the stick eased off within RAMP."""
        err = point - hand
        here = self.cycle[self.axis_index]
        cur = XYZ.index(here) if here in XYZ else -1
        want = int(np.argmax(np.abs(err)))
        if abs(err[want]) < tol / 2:
            return self._out(0.0)   # there, as far as the person can tell
        if cur < 0 or (want != cur and abs(err[cur]) < tol / 2):
            presses = (self.cycle.index(XYZ[want]) - self.axis_index) % len(self.cycle)
            self.presses_left = presses
            self.busy_until = t + self.p.switch_time
            self.n_switches += 1
            self.switch_s += self.p.switch_time + presses * self.p.press_time
            return self._out(0.0)
        e = float(err[cur])
        mag = float(np.clip(self.p.gain * abs(e) / RAMP, 0.2, 1.0))
        return self._out(self._motor(math.copysign(mag, e)))

    def _ee_plan(self, hand: np.ndarray) -> tuple[list[np.ndarray], list[float]]:
        """The hand positions a person aims at, and how near each must be: to the bottle, up (when
        beside it and low), above it, down round its neck; to the place, up (when low), over it with
        the bottle, down to where it was grasped."""
        if self.phase == REACH:
            end = self.grasp_point()
            high = end[2] + HOVER + self.taught.clearance_m
        else:
            end = np.array([*(self.target() + self.offset), self.grasp_z + 0.005])
            high = self.grasp_z + LIFT
        pts, tols = [], []
        beside = float(np.linalg.norm(hand[:2] - end[:2])) > AROUND_XY * 2
        if beside and hand[2] < high - COARSE_TOL:
            pts.append(np.array([hand[0], hand[1], high]))
            tols.append(COARSE_TOL)
        if beside:
            pts.append(np.array([end[0], end[1], max(high, float(hand[2])) if not pts else high]))
            tols.append(FINE_TOL)
        return pts + [end], tols + [FINE_TOL]

    # ------------------------------------------------------------------ what it took away
    def lesson(self) -> Lesson:
        """Latent (and hybrid): the stick's way that brought the task nearer; end effector (and
        hybrid): more room above the bottle if it moved before the grasp."""
        direction, room = self.taught.direction, self.taught.clearance_m
        if self.mode != "end_effector":
            best = max(self.progress, key=self.progress.get)
            direction = best if self.progress[best] > 0 else direction
        if self.mode != "latent" and self.moved_early:
            room = round(min(CLEARANCE_MAX, room + CLEARANCE_STEP), 3)
        return Lesson(direction=direction, clearance_m=room)

    def hand_row(self) -> dict:
        """The trial row's fields of the hand: the condition, presses, failed grasps, hybrid control's
        mode changes, the phase reached (reach, close, carry, release)."""
        return {"condition": condition(self.mode, self.assistance), "grasp_presses": self.grasp_presses,
                "failed_grasps": self.failed_grasps, "control_switches": self.mode_changes,
                "hand_phase": self.phase}

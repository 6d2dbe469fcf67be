"""Assistance the person commands: goal inference over what the camera sees, and a pull toward the
inferred goal that grows with confidence (in the spirit of Jeon, Losey and Sadigh, RSS 2020). No rclpy.

The candidate goals are the detected objects, each with its tasks' goal poses (`vla_common.task_goals`:
from the object's class, its centre on the table and the task; the model's tasks say which of an
object's tasks it was taught). The object is found on the table from its detection's box centre and
the camera (`unproject`). Each goal keeps the pose it steers toward next (a push: hover, pre-push,
push end; a circle: a ring; a pick-and-place: hover, grasp, carry, place, retreat).

Inference: every goal gathers evidence from where the *person's* command (the decoder's output for
their stick, before any assistance) takes the hand: progress toward the goal's next pose adds,
motion away subtracts, and old evidence fades with the distance moved (not with time: a pause keeps
it). While a goal steers a stick held forward toward a pose before its last, its motion away and fade
count only by the person's share of the last step: the person holds on to what they watch, and a
decoder that turns away there is a model off its demonstrations (`_infer`). Evidence from the
assisted motion would feed on itself; Aronson and Short (2024) show how such confidence runs away
and traps the user. The object the controller latched (the operator's pick on the station, or
`goal_selection`) starts ahead (`PRIOR_LATCHED`). The belief is a softmax over the goals and "none
of them"; the confidence is the inferred goal's probability.

Command: with the stick forward the command is (1 - a) x person's + a x assistance's, a = the level's
share times how far the confidence is above one half; the assistance's moves the TCP straight toward
the goal's next pose at the demonstrations' speed times |stick| (slowing onto a pose where the hand
acts and onto the last one) and turns the hand toward its orientation. A push keeps the line through
where its object was first seen: a box round the object and the hand behind it is no measure of where
the object stands (the cereal box's stood 5 cm aside; followed, the hand pushed the box's edge, it
turned and toppled). On a push the hand's axis leans toward the push, by the
demonstrations' tilt or more (`_push_axis`); the push of a tall object (TALL_M) comes down
APPROACH_BACK_M farther back than the demonstrations' pre-push, clear of the object's top edge, and
pushes leaning at least TALL_TILT_DEG, the wrist back from it. A joint near its limit is moved back
out in the motion that keeps the TCP's (`_limits_kept`), and the elbow's self-motion is bounded
(`_elbow_bounded`). The person stays in charge:
- the stick at rest gives zero (the controller never calls this then);
- reversed, the assistance retraces the goal's poses and the command never moves the TCP toward the
  goal's next pose, from the first step;
- only the stick's speed: |stick| sets it, the assistance never moves faster than the stick asks;
- confidence falls as fast as it rises: motion away, another object picked (all evidence dropped),
  a goal whose object is no longer in the detections pulls no more from the next step;
- a goal whose last pose is reached (within REACH_M where the hand does nothing there) holds the hand
  there until the stick returns to neutral: it settles onto the pose, then zero; what the person's
  command does meanwhile no longer moves the goal.
The hand is the operator's: the assistance waits above the object until the hand is open, at the
grasp pose until the fingers have closed on the object (the grasp button), and at the place until
they have opened.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from vla_common.catalogue import Catalogue, ObjectSpec, TaskSpec, default_catalogue
from vla_common.detection import Detection
from vla_common.robot import HAND
from vla_common.task_goals import GRASP, OPEN, GoalPose, preferred_flip, push_rotation, task_goal_poses

LEVELS = ("off", "low", "high")
LEVEL_SHARE = {"off": 0.0, "low": 0.5, "high": 1.0}  # the most of the command the assistance takes
CONFIDENCE_FROM = 0.5     # no pull at or below even odds ...
CONFIDENCE_FULL = 0.9     # ... the level's whole share from here on
PRIOR_LATCHED = 1.0       # nats the latched object's goals start ahead of "none of them"
EVIDENCE_M = 0.02         # m of progress toward a goal's next pose worth one nat
MEMORY_M = 0.15           # m of motion over which old evidence fades to 1/e
EVIDENCE_MAX = 6.0        # nats, either way
AWAY_WEIGHT = 3.0         # motion away from a goal counts this many times its progress (falls faster)
REACH_M = 0.02            # a pose passed through counts as reached this close
STOP_REACH_M = 0.005      # a pose where the hand acts; the last one is held from REACH_M on, settled to this
PACE_CAP = 2.0            # the person's pace counts up to this many times the demonstrations' speed
POSITION_GAIN = 2.0       # 1/s onto a pose the hand stops at
ROTATION_GAIN = 2.0       # 1/s
MAX_ROTATION = 0.8        # rad/s at full stick
DAMPING = 0.02            # of the Jacobian's pseudo-inverse
MATCH_M = 0.08            # a detection this close to a goal's object is that object (it may be pushed)
# An object the hand hid while pushing it reappears where the push left it, farther than MATCH_M from
# where it was last seen: the unmatched detection of its class nearest to it, within RELOCATE_M (more
# than a push's length), is that object. As a new object it got a new goal, whose first pose (the
# hover before a push) led the hand back up and pushed it a second time under a stick held on.
RELOCATE_M = 0.3
LOST_KEEP_S = 5.0         # s a goal whose object left the detections is remembered (pulling nothing)
# An object missing from the detections while the hand is in front of it (the hand's or the flange's
# image within HIDDEN_MARGIN_PX of its last box) is hidden, not gone: a push from the camera's side
# covers it. Its goal keeps pulling for HIDDEN_KEEP_S after it was last seen; a goal reached, which holds
# the hand still at its last pose (in front of the object it pushed), as long as the stick is held.
HIDDEN_MARGIN_PX = 40.0
HIDDEN_KEEP_S = 3.0
FLANGE_M = 0.1034         # the flange behind the TCP along the hand's axis
DETECTIONS_MAX_AGE = 2.0  # s: older detections show nothing (no goal pulls)
HAND_STEADY_M = 0.0005    # m the finger gap may change over HAND_STEADY_S and count as at rest
HAND_STEADY_S = 0.3
HAND_OPEN_ABOVE = HAND.max_width - 0.008   # m: a gap at rest above this is an open hand ...
HAND_EMPTY_BELOW = 0.005                   # ... below this a shut, empty one; between, it holds something
# The push of an object at least TALL_M high comes down APPROACH_BACK_M farther back than the
# demonstrations' pre-push, then pushes on to their push end: beside the cereal box (0.27 m) the descent
# stalled with the wrist on the box's top edge, turned the box and toppled it (Seen, development layouts
# 310000-310019 through the graph: 15/20 -> 18/20). The milk carton (0.20) comes down clean and keeps the
# demonstrations' poses; the glass bottle (0.22) did not with the matched models
# (development/assist_base.yaml: 5/9 -> 8/9 with TALL_M lowered from 0.25).
TALL_M = 0.21
APPROACH_BACK_M = 0.04
# ... and the hand leans toward the push at least this much while it pushes: a decoder that straightened the
# hand during the push brought the wrist forward onto the box's top edge (Seen, development layouts at
# 47fda13). At the planner's tilt for the cereal box (34-35 deg at its centre layouts) the forearm, reaching
# over the box to push it toward the arm, still came down on its top edge and tipped it over sideways; the
# wrist higher, it passes above (development, the assistance alone in MuJoCo, 200 random layouts of the
# box's push south: 19 boxes toppled at 34 deg, 2 at 45, 9 at 52; 66 at 25).
TALL_TILT_DEG = 45.0
CLEARANCE_M = 0.02        # the arm's links keep this far above (and outside) a detected object
CLEARANCE_LINKS = ("panda_link3", "panda_link4", "panda_link5", "panda_link6")  # not the wrist on the hand
CLEARANCE_GAIN = 4.0      # 1/s: how fast a link below that rises
# Only points of the links at most CLEARANCE_DEPTH below that height are raised: the footprint is a circle, so
# points far below it beside a thin object (the wrist by the hand pushing the cereal box) count as over it,
# cannot rise there without the TCP, and weigh in the least-squares rise against the points that can
# (development, the assistance alone in MuJoCo on 200 random layouts of the cereal box's push: 33 -> 19
# boxes toppled; 0.04-0.08 m alike, no gain at 0.12). At the push's pose the null space left is small:
# the hand's lean (TALL_TILT_DEG), not this rise, is what keeps the forearm off the box's top.
CLEARANCE_DEPTH = 0.08
MAX_STEP_S = 0.1          # s: a longer gap between steps counts as this much motion
# The elbow's self-motion (what moves neither the TCP nor the hand's axes: the decoder's, and the links'
# clearance) is kept no faster than this (rad/s, its norm). Pushing the cereal box, the decoder beside
# its demonstrations and a clearance the links could not reach that way swung the elbow at 1-4.6 rad/s;
# the safety layer's per-joint limits on such a swing let it into the hand, which jumped 5 cm aside at
# the push's start (Seen, development layouts 340000-: 0.3-0.5 m/s at the TCP). The demonstrations' own
# self-motion, on the approach, is 0.05-0.11 rad/s.
NULL_SPEED_MAX = 0.5
# A joint within LIMIT_ZONE of its limit is moved back out of it at LIMIT_GAIN x its depth in the zone
# (rad/s), in the motion that keeps the TCP's (Liegeois's gradient projection); the hand's lean gives way
# there. The decoder beside its demonstrations brought the cereal box's far pushes (the box 0.3 m to the
# side) down with the shoulder leant forward and the elbow straight, where the safety layer's margin held
# the elbow and the hand stayed 5 cm above the pre-push pose for the rest of the trial; with the elbow
# bent the pose is in reach, but not by a motion that keeps the hand's lean as well (the elbow's angle is
# then fixed). Seen, development layouts 330000- (development/assist_seen.yaml): 24 -> 27 of 27 with
# `_backed_past`; keeping the lean, 26 of 27.
LIMIT_ZONE = 0.35
LIMIT_GAIN = 2.0


def check_level(level: str) -> str | None:
    return None if level in LEVELS else f"assistance {level!r} is not one of {LEVELS}"


@dataclass
class Seen:
    """One object the detections show, followed from array to array (it may be pushed)."""

    class_id: str
    anchor: np.ndarray            # (x, y) where it was first seen: its goal poses' centre
    xy: np.ndarray                # where it was last seen
    pixel: tuple[float, float]    # its box centre in the detector's image (px)
    box: tuple[float, float]      # its box's width and height (px)
    image_size: tuple[int, int]
    start: np.ndarray             # the TCP when it was first seen: where a reversed stick leads back to
    visible: bool = True          # in the latest detections, or hidden behind the hand since
    seen_t: float = 0.0           # when it was last in the detections


@dataclass
class Goal:
    """One candidate goal: an object and one of its tasks, with the pose it steers toward next."""

    obj: Seen
    task: TaskSpec
    poses: list[GoalPose]
    stage: int = 0                # the next pose; len(poses): every pose reached
    evidence: float = 0.0

    @property
    def done(self) -> bool:
        return self.stage >= len(self.poses)

    def target(self) -> GoalPose:
        return self.poses[min(self.stage, len(self.poses) - 1)]

    def previous(self) -> np.ndarray:
        """Where a reversed stick heads: the pose before the next one (the TCP where it was first seen)."""
        if self.stage == 0:
            return self.obj.start
        return self.poses[min(self.stage, len(self.poses)) - 1].position


@dataclass
class AssistState:
    """What the status shows: the level, the inferred goal and how sure, and the share it takes."""

    level: str = "off"
    goal_task: str = ""
    confidence: float = 0.0
    share: float = 0.0
    stage: str = ""
    goal_xy: tuple[float, float] = (math.nan, math.nan)
    goal_image_xy: tuple[float, float] = (math.nan, math.nan)  # normalised by the image size
    reason: str = ""


@dataclass
class _Hand:
    """The finger gap over the last HAND_STEADY_S: closed (on something) or open, once at rest."""

    samples: list[tuple[float, float]] = field(default_factory=list)
    known: bool = False

    def add(self, width: float, now: float) -> None:
        self.known = True
        self.samples = [s for s in self.samples if now - s[0] <= HAND_STEADY_S] + [(now, width)]

    def state(self) -> str:
        """"holding", "open", "shut" (closed on nothing) or "" (moving, or no finger joints seen)."""
        if not self.known or not self.samples:
            return ""
        widths = [w for _, w in self.samples]
        if self.samples[-1][0] - self.samples[0][0] < HAND_STEADY_S * 0.5 or \
                max(widths) - min(widths) > HAND_STEADY_M:
            return ""
        w = widths[-1]
        return "open" if w > HAND_OPEN_ABOVE else "shut" if w < HAND_EMPTY_BELOW else "holding"


class Assistance:
    """Goal inference and blending for the controller core (see the module docstring).

    ``kinematics`` has ``tcp_state(q)`` -> (position, rotation, 6x7 Jacobian) over the model's joints
    (the Panda's); ``camera()`` gives the detector's camera (`vla_common.camera_model.PinholeCamera`:
    ``project``, ``unproject``), or None while it is not calibrated (no goals then)."""

    def __init__(self, kinematics=None, camera: Callable | None = None, catalogue: Catalogue | None = None):
        self.kinematics = kinematics
        self.camera = camera
        self.catalogue = catalogue or default_catalogue()
        self.level = "off"
        self.tasks: dict[str, list[TaskSpec]] = {}
        self.objects: list[Seen] = []
        self.goals: list[Goal] = []
        self._dets_t = -math.inf
        self._latched: tuple[str, float, float] | None = None
        self._hand = _Hand()
        self._presses = 0  # grasp button presses: the hand's state where no finger joints are seen
        self._last_t: float | None = None
        self._held: tuple[Goal, float] | None = None  # a reached goal holding the hand, and its share
        self._steering: tuple[Goal, float] | None = None  # the goal that pulled the last step, and its share
        self.lost = ""  # the last command was a stop: the reached goal's object left the view (why)
        self.state = AssistState()

    # ----------------------------------------------------------------- inputs
    def set_tasks(self, tasks: Mapping[str, Sequence[str]]) -> None:
        """The tasks the model was taught, by class ({class: [task names]}); unknown tasks are left out."""
        self.tasks = {}
        for cls, names in tasks.items():
            for name in names:
                try:
                    spec = self.catalogue.task(name)
                except ValueError:
                    continue
                self.tasks.setdefault(cls, []).append(spec)
        self.reset()

    def reset(self) -> None:
        """A new episode (a re-detect, a new model): every goal forgotten, and so no goal shown."""
        self.objects, self.goals, self._dets_t, self._latched = [], [], -math.inf, None
        self._last_t = self._held = self._steering = None
        self.lost, self.state = "", AssistState(level=self.state.level)

    def restamp(self, f: Callable[[float], float]) -> None:
        """The core's clock moved its origin (`TeleopCore.restamp`): every time kept, mapped by `f`."""
        self._dets_t = f(self._dets_t)
        self._last_t = None if self._last_t is None else f(self._last_t)
        for o in self.objects:
            o.seen_t = f(o.seen_t)
        self._hand.samples = [(f(t), w) for t, w in self._hand.samples]

    def on_fingers(self, width: float, now: float) -> None:
        """The gap between the fingers (m) from joint_states."""
        if math.isfinite(width):
            self._hand.add(float(width), now)

    def on_grasp_press(self) -> None:
        self._presses += 1

    def observe(self, dets: Sequence[Detection], image_size, dets_t: float, latched, q, now: float) -> None:
        """Track the objects of the latest detections (once per new array) and note the latched one
        ((class, u, v) in detector pixels, or None). A goal whose object is missing pulls no more."""
        if latched != self._latched:
            self._latched, self._held = latched, None
            for g in self.goals:    # the operator chose another object: only the prior counts now
                g.evidence = 0.0
        camera = self.camera() if self.camera is not None else None
        if dets_t != self._dets_t and self.kinematics is not None and camera is not None:
            self._dets_t = dets_t
            p, R, _J = self.kinematics.tcp_state(q)
            hand = [camera.project(p), camera.project(p - FLANGE_M * R[:, 2])]
            self._track(self._located(dets, image_size, camera), p, hand, image_size, now)
        self._expire(now)

    def _located(self, dets, image_size, camera) -> list[tuple[Detection, np.ndarray]]:
        """The detections of classes with a task, with where each object stands on the table; most
        confident first, and one whose centre stands inside a more confident one's footprint left out:
        two objects cannot stand there, it is that object seen as another class (the detector called
        a loaf with the hand on it a milk carton at 0.39, and that goal took the hand off the push)."""
        out = []
        if not image_size:
            return out
        for d in sorted(dets, key=lambda d: -d.score):
            if d.class_id not in self.tasks or not d.is_finite():
                continue
            try:
                point = camera.unproject((d.cx, d.cy), 0.5 * self.catalogue.spec(d.class_id).height)
            except (ValueError, ArithmeticError):
                point = None
            if point is None or not np.all(np.isfinite(point)):
                continue
            xy = np.asarray(point, float)[:2]
            if not any(np.linalg.norm(xy - k) < self.catalogue.spec(o.class_id).footprint_radius
                       for o, k in out):
                out.append((d, xy))
        return out

    def _track(self, located, tcp, hand, image_size, now: float) -> None:
        """Match each located detection to the nearest remembered object of its class within MATCH_M
        (nearest pairs first), then the rest within RELOCATE_M (moved while hidden); the others are new
        objects; objects matched by none are not visible, unless the hand hides them (`hand`: its
        pixels)."""
        held = self._held[0].obj if self._held is not None else None
        for o in self.objects:   # the goal reached holds the hand on its object as long as it hides it
            o.visible = o.visible and (now - o.seen_t <= HIDDEN_KEEP_S or o is held) and _behind(o, hand)
        pairs = sorted((float(np.linalg.norm(o.xy - xy)), i, j) for i, (d, xy) in enumerate(located)
                       for j, o in enumerate(self.objects) if o.class_id == d.class_id)
        used_d, used_o = set(), set()
        for within in (MATCH_M, RELOCATE_M):   # the nearest pairs first; then the moved while hidden
            for dist, i, j in pairs:
                if dist <= within and i not in used_d and j not in used_o:
                    used_d.add(i)
                    used_o.add(j)
                    d, xy = located[i]
                    o = self.objects[j]
                    o.xy, o.pixel, o.box = xy, (d.cx, d.cy), (d.width, d.height)
                    o.image_size, o.visible, o.seen_t = tuple(image_size), True, now
        start = np.asarray(tcp, float) if tcp is not None else np.full(3, math.nan)
        for i, (d, xy) in enumerate(located):
            # no new object under the hand (objects do not appear there, the hand is misdetected there),
            # nor one where a remembered object went missing (`_instead_of`)
            missing = [o for j, o in enumerate(self.objects) if j not in used_o]
            if i not in used_d and not _under(d, hand) and not _instead_of(d, missing):
                o = Seen(d.class_id, xy.copy(), xy.copy(), (d.cx, d.cy), (d.width, d.height),
                         tuple(image_size), start, seen_t=now)
                self.objects.append(o)
                shape = self.catalogue.spec(d.class_id)
                self.goals += [Goal(o, spec, _poses(spec, shape, xy, tcp))
                               for spec in self.tasks[d.class_id]]

    def _expire(self, now: float) -> None:
        if now - self._dets_t > DETECTIONS_MAX_AGE:
            for o in self.objects:
                o.visible = False
        self.objects = [o for o in self.objects if o.visible or now - o.seen_t <= LOST_KEEP_S]
        self.goals = [g for g in self.goals if any(g.obj is o for o in self.objects)]

    def shown(self, level: str, moving: bool) -> AssistState:
        """The state for the status: the last step's while the assistance commands; otherwise the
        goal last inferred with no share (nothing pulls while the command is zero)."""
        self.level = level
        if level == "off":
            self.state = AssistState()
        elif not moving:
            self.state = replace(self.state, level=level, share=0.0)
        return self.state

    # ----------------------------------------------------------------- the command
    def on_neutral(self) -> None:
        """The stick is back at rest: a reached goal lets go of the hand."""
        self._held, self._last_t = None, None

    def command(self, q: np.ndarray, u: float, person: np.ndarray, now: float) -> np.ndarray:
        """The command for stick u (!= 0) given the person's (the decoder's) ``person``; updates the
        inference. Returns ``person`` itself when the assistance is off or has nothing to add."""
        dt = 0.0 if self._last_t is None else min(max(now - self._last_t, 0.0), MAX_STEP_S)
        self._last_t, self.lost = now, ""
        steering, self._steering = self._steering, None
        if self.level == "off" or self.kinematics is None or u == 0.0:
            self.state = AssistState(level=self.level)
            return person
        if self._held is not None:
            goal, share = self._held
            if u > 0 and goal.obj.visible:  # reached, the stick still forward: hold as when reached
                return self._settle(goal, q, share, person, u)
            self._held = None
            if u > 0:   # its object left the view: a stop the person did not choose (they return to neutral)
                self.lost = f"the {goal.obj.class_id} of the goal reached is no longer detected"
                return np.zeros_like(person)
        p, R, J = self.kinematics.tcp_state(q)
        visible = [g for g in self.goals if g.obj.visible]
        self._stages(visible, p, u)
        if not self._waiting(visible, p):
            self._infer(visible, p, J[:3] @ person, dt, steering if u > 0 else None)
        best, confidence = self._best(visible)
        share = LEVEL_SHARE[self.level] * _ramp(confidence) if best is not None else 0.0
        self.state = self._state(best, confidence, share)
        if best is None or share == 0.0:
            return person
        self._steering = (best, share)
        if u > 0 and best.done:
            self._held = (best, share)
            return self._settle(best, q, share, person, u)
        pace = float(np.linalg.norm(J[:3] @ person))
        rows, twist = self._toward(best, p, R, J, u, pace) if u > 0 else self._back(best, p, J, u, pace)
        out = person + share * _solve(rows, twist - rows @ person)
        kept = rows if best.task.kind == "push" else J[:3]
        out = _elbow_bounded(self._limits_kept(q, self._clear(q, out, kept, best, p), J[:3]), J)
        return out if u > 0 else _not_toward(out, best.target().position - p, J)

    def _settle(self, goal: Goal, q: np.ndarray, share: float, person: np.ndarray, u: float) -> np.ndarray:
        """A reached goal's hold: the hand settles onto its last pose (the approach that slows onto it,
        the person's command kept out by the share it had when reached), then zero. Held 15 s, the hand
        came within 5-10 mm of a push's end and no nearer; the person's decoder drove on meanwhile and,
        counted as motion away, handed the pull to another object's goal, whose push moved the box on."""
        p, R, J = self.kinematics.tcp_state(q)
        if np.linalg.norm(goal.target().position - p) <= STOP_REACH_M:
            return (1.0 - share) * person
        rows, twist = self._toward(goal, p, R, J, u, 0.0)
        return (1.0 - share) * person + share * _solve(rows, twist)

    def _clear(self, q: np.ndarray, dq: np.ndarray, J_tcp: np.ndarray, best: Goal,
               tcp: np.ndarray) -> np.ndarray:
        """Keep the arm's links (not the wrist and hand: they are meant to come close) CLEARANCE_M
        above the detected objects' tops where they pass over them, moving them up in the null space
        of `J_tcp`: the TCP's motion (a steeper forearm, more tilt: what the planner's extra tilt does
        for the demonstrations), and on a push the hand's lean as well: there the wrist, lifted where it
        cannot rise, was brought upright and forward onto the cereal box's top edge, which toppled the
        box. The object a goal grasps is not an obstacle to it."""
        grasps = any(pose.hand for pose in best.poses)   # the hand closes round its object: no obstacle
        obstacles = [o for o in self.objects if o.visible and not (grasps and o is best.obj)]
        if not obstacles or not hasattr(self.kinematics, "arm_points"):
            return dq
        points, jacobians = self.kinematics.arm_points(q, CLEARANCE_LINKS)
        need = np.zeros(len(points))
        for o in obstacles:
            shape = self.catalogue.spec(o.class_id)
            xy = _pushed_to(o, best, tcp, shape) if o is best.obj else o.xy
            over = np.linalg.norm(points[:, :2] - xy, axis=1) < shape.footprint_radius + CLEARANCE_M
            need = np.maximum(need, np.where(over, shape.height + CLEARANCE_M - points[:, 2], 0.0))
        index = np.flatnonzero((need > 0.0) & (need < CLEARANCE_DEPTH))
        if not len(index):
            return dq
        Jz = jacobians(index)[:, 2, :]
        short = CLEARANCE_GAIN * need[index] - Jz @ dq      # how much faster each point must rise
        if np.all(short <= 0.0):
            return dq
        null = np.eye(len(dq)) - _solve(J_tcp, J_tcp)
        return dq + null @ _solve(Jz @ null, np.maximum(short, 0.0))

    def _limits_kept(self, q: np.ndarray, dq: np.ndarray, J_pos: np.ndarray) -> np.ndarray:
        """``dq`` with the joints inside LIMIT_ZONE of a limit moving back out at least as fast as
        their depth asks, through the null space of ``J_pos`` (the TCP's motion): at a limit the safety
        layer stops the joint, and a command that needs it to go on moves nothing, though the arm could
        reach the pose another way."""
        lo, hi = getattr(self.kinematics, "q_min", None), getattr(self.kinematics, "q_max", None)
        if lo is None or hi is None:
            return dq
        depth_lo, depth_hi = lo + LIMIT_ZONE - q, q - (hi - LIMIT_ZONE)
        away = np.where(depth_lo > 0.0, 1.0, np.where(depth_hi > 0.0, -1.0, 0.0))
        index = np.flatnonzero(away)
        if not len(index):
            return dq
        depth = np.maximum(depth_lo, depth_hi)[index]
        short = LIMIT_GAIN * depth - away[index] * dq[index]   # how much faster each must move away
        if np.all(short <= 0.0):
            return dq
        select = np.diag(away)[index]                            # each joint's velocity away from its limit
        null = np.eye(len(dq)) - np.linalg.pinv(J_pos, rcond=1e-3) @ J_pos
        return dq + null @ _solve(select @ null, np.maximum(short, 0.0))

    def _hand_state(self) -> str:
        """"holding", "open", "shut" or "" (moving): from the fingers; where none are seen, from the
        grasp button's presses (a toggle first opens a closed hand, then closes it on the object)."""
        if self._hand.known:
            return self._hand.state()
        return "shut" if not self._presses else "open" if self._presses % 2 else "holding"

    def _waiting(self, goals: Sequence[Goal], p: np.ndarray) -> bool:
        """The inferred goal holds the hand at a pose where the hand acts, waiting for the operator's
        button: the person's motion then says nothing about the goal (the decoder heads on toward the
        carry), so the inference waits too."""
        best, _ = self._best(goals)
        if best is None or best.done:
            return False
        pose = best.target()
        return bool(pose.hand) and np.linalg.norm(pose.position - p) < STOP_REACH_M

    def _stages(self, goals: Sequence[Goal], p: np.ndarray, u: float) -> None:
        """Forward: on past every pose reached. Reversed: back to the pose before once there, or once
        the hand is farther from the next pose than the pose before is (it backed away past it another
        way: the person's own reversal beside the goal's at a low share; forward again, the pull went
        straight from there to the pre-push and the hand knocked the cereal box over on its way, Seen,
        development layouts 330000-), but never back onto one the hand as it is cannot reach: with the
        object in the hand, a reversal in the carry stops at the grasp pose (the hover above wants an
        open hand: pushed forward again, the hand would wait there for good, a trap only dropping the
        object ended)."""
        hand = self._hand_state()
        for g in goals:
            if u > 0:
                while not g.done and self._reached(g, p, hand):
                    g.stage += 1
            elif g.stage > 0 and _backed_past(g, p) and \
                    not (hand == "holding" and g.poses[min(g.stage, len(g.poses)) - 1].hand == OPEN):
                g.stage -= 1

    @staticmethod
    def _reached(g: Goal, p: np.ndarray, hand: str) -> bool:
        """The hand is at the goal's next pose: within STOP_REACH_M where it acts, REACH_M elsewhere
        (the last pose too: its hold settles the hand onto it)."""
        pose = g.target()
        if np.linalg.norm(pose.position - p) >= (STOP_REACH_M if pose.hand else REACH_M):
            return False
        if pose.hand == GRASP:
            return hand == "holding"
        if pose.hand == OPEN:
            return hand == "open"
        return True

    def _infer(self, goals: Sequence[Goal], p: np.ndarray, v: np.ndarray, dt: float,
               steering: tuple[Goal, float] | None = None) -> None:
        """Evidence from the person's TCP velocity v over dt: progress toward a goal's next pose, or the
        pose after it (a model that cuts a corner, or heads on to the carry while the hand waits to
        close, still does that task); motion away from both counts AWAY_WEIGHT times; old evidence
        fades with the distance the person's command moves.

        `steering`: the goal that pulled the last step and its share, with the stick still forward.
        On the way to its last pose, progress toward it counts as ever, and motion away and the fade
        count only by the part the person's command had in what the arm did (1 - share). The person
        watches the arm go, assisted, toward that goal and holds on; a decoder that disagrees then is
        a model off its demonstrations, not the person (the matched Far model turned down and out
        three quarters round the ring and took a held stick's confidence from 0.98 to 0.03 in a
        second, over and over). Toward the last pose (a push itself, a place) the decoder counts
        whole again: there a model that turns back knows the push went far enough or the object
        turned (kept there too, a held stick pushed the cereal box on into a reflex and 35 deg off).
        The other goals gather evidence as ever; a reversal (the stick no longer forward) judges every
        goal by the person's command alone, and another object picked drops all evidence: each lowers
        the goal's pull at once."""
        moved = float(np.linalg.norm(v)) * dt
        for g in goals:
            progress = max((_progress(v, pose.position - p) for pose in g.poses[g.stage:g.stage + 2]),
                           default=0.0) * dt
            led = steering is not None and steering[0] is g and g.stage < len(g.poses) - 1
            own = 1.0 - steering[1] if led else 1.0
            if progress < 0.0:
                progress *= AWAY_WEIGHT * own
            kept = g.evidence * math.exp(-own * moved / MEMORY_M)
            g.evidence = float(np.clip(kept + progress / EVIDENCE_M, -EVIDENCE_MAX, EVIDENCE_MAX))

    def _best(self, goals: Sequence[Goal]) -> tuple[Goal | None, float]:
        """The most probable goal and its probability (against the others and "none of them")."""
        if not goals:
            return None, 0.0
        scores = np.array([g.evidence + (PRIOR_LATCHED if self._is_latched(g) else 0.0) for g in goals])
        top = float(max(scores.max(), 0.0))
        weights = np.exp(scores - top)
        total = float(weights.sum()) + math.exp(-top)
        i = int(np.argmax(scores))
        return goals[i], float(weights[i] / total)

    def _is_latched(self, g: Goal) -> bool:
        """The goal's object is the one the controller latched: the nearest of its class to the latch."""
        lat = self._latched
        if lat is None or lat[0] != g.obj.class_id:
            return False
        same = [o for o in self.objects if o.class_id == lat[0] and o.visible]
        return min(same, key=lambda o: math.hypot(o.pixel[0] - lat[1], o.pixel[1] - lat[2])) is g.obj

    def _state(self, best: Goal | None, confidence: float, share: float) -> AssistState:
        if best is None:
            return AssistState(self.level, reason="no goal in view")
        o = best.obj
        w, h = o.image_size
        return AssistState(self.level, best.task.name, confidence, share,
                           "done" if best.done else best.target().name,
                           (float(o.anchor[0]), float(o.anchor[1])), (o.pixel[0] / w, o.pixel[1] / h))

    def _toward(self, g: Goal, p, R, J, u: float, pace: float) -> tuple[np.ndarray, np.ndarray]:
        """(Jacobian rows, the twist they should give): the TCP straight toward the goal's next pose at
        the stick's speed (`_speed`), and where the pose says so the hand's axis turned to its axis.
        The rest of the motion (the hand's turn about its axis, the elbow, a push's tilt) stays the
        person's: the decoder's, which keeps the demonstrations' arm configuration (a forced tilt put
        the forearm on a tall box's top)."""
        pose = g.target()
        to = pose.position - p
        dist = float(np.linalg.norm(to))
        speed = _speed(u, pose.speed, pace)
        if pose.hand or g.stage >= len(g.poses) - 1:
            speed = min(speed, POSITION_GAIN * dist)
        v = to / dist * speed if dist > 1e-9 else np.zeros(3)
        if not pose.aligns:
            return J[:3], v
        z, target = R[:, 2], pose.rotation[:, 2]
        if g.task.kind == "push":
            target = _push_axis(z, target)
        w = ROTATION_GAIN * np.cross(z, target)       # turns z toward the target axis, never about z
        wn = float(np.linalg.norm(w))
        if wn > abs(u) * MAX_ROTATION:
            w *= abs(u) * MAX_ROTATION / wn
        if pose.hand:   # where the hand closes or opens it does not turn about its axis either
            return J, np.concatenate([v, w])
        across = np.eye(3) - np.outer(z, z)
        return np.vstack([J[:3], across @ J[3:]]), np.concatenate([v, w])

    def _back(self, g: Goal, p, J, u: float, pace: float) -> tuple[np.ndarray, np.ndarray]:
        """(Jacobian rows, twist): the TCP retracing the goal's poses, toward the one before its next."""
        back = g.previous() - p
        dist = float(np.linalg.norm(back))
        if not np.all(np.isfinite(back)) or dist < 1e-9:
            return J[:3], np.zeros(3)
        return J[:3], back / dist * _speed(u, g.target().speed, pace)


def _poses(spec: TaskSpec, shape: ObjectSpec, xy, tcp) -> list[GoalPose]:
    """The assistance's goal poses: the demonstrations' (`task_goal_poses`, shared with the planner); a
    push's with the hand's lean toward the push held all the way (`aligns`, at least the poses' tilt:
    `_push_axis`), and for an object at least TALL_M high the hover and the pre-push APPROACH_BACK_M
    farther back along the push (its end stays) and, pushing, a lean of at least TALL_TILT_DEG: the
    hand comes down clear of the object and pushes with the wrist back from its top (asked from the
    hover on, the lean held the hand still short of it: Seen and Near, development layouts)."""
    poses = task_goal_poses(spec, shape, xy, tcp)
    if spec.kind != "push":
        return poses
    if shape.height < TALL_M:
        return [replace(p, aligns=True) for p in poses]
    d = spec.direction_vector
    back = APPROACH_BACK_M * np.array([*d, 0.0])
    rot = push_rotation(d, math.radians(TALL_TILT_DEG), preferred_flip(d))
    return [replace(p, rotation=rot, aligns=True) if p.name == "push_end"
            else replace(p, position=p.position - back, aligns=True) for p in poses]


def _pushed_to(o: Seen, g: Goal, tcp: np.ndarray, shape: ObjectSpec) -> np.ndarray:
    """Where the object a push pushes stands, for the links' clearance: where it was last seen, or,
    once the push is under way, no nearer along the push than its least half-extent ahead of the hand
    (the hand before it hides it, and the detections come 2 a second). Where the links kept clear of
    the box as last seen, the forearm reaching over the cereal box to push it toward the arm came down
    on its top edge as it went and tipped it over sideways (development, the assistance alone in
    MuJoCo: 79 of 200 boxes toppled, 22 where the box's true place was used)."""
    if g.task.kind != "push" or g.stage < len(g.poses) - 1:
        return o.xy
    d = g.task.direction_vector
    ahead = float((tcp[:2] - o.xy) @ d) + shape.min_half_extent
    return o.xy + d * max(0.0, ahead)


def _backed_past(g: Goal, p: np.ndarray) -> bool:
    """The hand is back at the goal's pose before its next, or farther from the next than that one."""
    before, ahead = g.previous(), g.target().position
    return bool(np.linalg.norm(before - p) < REACH_M or
                np.linalg.norm(ahead - p) > np.linalg.norm(ahead - before) + REACH_M)


def _push_axis(z: np.ndarray, demonstrated: np.ndarray) -> np.ndarray:
    """The hand's axis on a push: tilted toward the push as the demonstrations' (finger tips
    leading, the hand's body back from the object), by their tilt or more where the hand is tilted
    more (the extra tilt that keeps the forearm off a tall object stays). A decoder that tilted the
    hand the other way brought its body down onto the glass bottle's top (test layouts at d516eee,
    matched_detector_base_s0: 6 of 6 glass bottles failed, the hand's axis leaning 110 deg from the push)."""
    lean = demonstrated[:2] / max(float(np.linalg.norm(demonstrated[:2])), 1e-9)
    tilt = max(_tilt(z), _tilt(demonstrated))
    return np.array([*(math.sin(tilt) * lean), -math.cos(tilt)])


def _tilt(axis: np.ndarray) -> float:
    """How far (rad) a hand's axis leans from pointing straight down."""
    return math.acos(float(np.clip(-axis[2], -1.0, 1.0)))


def _behind(o: Seen, hand) -> bool:
    """The hand's image (any of its pixels) lies on or near the object's last box."""
    w, h = o.box[0] / 2 + HIDDEN_MARGIN_PX, o.box[1] / 2 + HIDDEN_MARGIN_PX
    return any(px is not None and abs(px[0] - o.pixel[0]) <= w and abs(px[1] - o.pixel[1]) <= h
               for px in hand)


def _instead_of(d: Detection, missing: Sequence[Seen]) -> bool:
    """The detection's centre lies in the last box of a remembered object of another class that this
    array does not show: that object, seen as another class, not a new one. With the hand on it the
    cereal box was called bread; as a new object its push took the hand off the box (Seen, held stick,
    development layouts 340000-340039). In the image, as the class sets the height a box is placed at
    on the table, and so where."""
    return any(o.class_id != d.class_id and abs(d.cx - o.pixel[0]) <= o.box[0] / 2 and
               abs(d.cy - o.pixel[1]) <= o.box[1] / 2 for o in missing)


def _under(d: Detection, hand) -> bool:
    """The hand's image (any of its pixels) lies inside the detection's box."""
    return any(px is not None and abs(px[0] - d.cx) <= d.width / 2 and abs(px[1] - d.cy) <= d.height / 2
               for px in hand)


def _progress(v: np.ndarray, to: np.ndarray) -> float:
    """The speed (m/s) at which velocity v closes the distance along ``to``."""
    n = float(np.linalg.norm(to))
    return float(v @ to) / n if n > 1e-9 else 0.0


def _speed(u: float, demonstrated: float, pace: float) -> float:
    """The TCP speed the stick asks for: |u| x the demonstrations' speed toward the pose, or the
    person's own pace (the decoder's speed at that stick) where it is faster, up to PACE_CAP times."""
    base = abs(u) * demonstrated
    return min(max(base, pace), PACE_CAP * base)


def _ramp(confidence: float) -> float:
    """How much of the level's share the confidence earns: none up to CONFIDENCE_FROM, all from
    CONFIDENCE_FULL on, linear between."""
    return float(np.clip((confidence - CONFIDENCE_FROM) / (CONFIDENCE_FULL - CONFIDENCE_FROM), 0.0, 1.0))


def _solve(J: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Damped least squares: the joint velocities (min norm) that give ``twist``."""
    return J.T @ np.linalg.solve(J @ J.T + DAMPING**2 * np.eye(J.shape[0]), twist)


def _elbow_bounded(dq: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``dq`` with its part in the exact null space of the TCP's Jacobian ``J`` at most NULL_SPEED_MAX."""
    free = dq - np.linalg.pinv(J, rcond=1e-3) @ (J @ dq)
    n = float(np.linalg.norm(free))
    return dq if n <= NULL_SPEED_MAX else dq - free * (1.0 - NULL_SPEED_MAX / n)


def _not_toward(dq: np.ndarray, to: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``dq`` without any TCP velocity along ``to`` (a reversed stick never approaches the goal)."""
    n = float(np.linalg.norm(to))
    if n < 1e-9:
        return dq
    g = to / n
    toward = float((J[:3] @ dq) @ g)
    if toward <= 0.0:
        return dq
    return dq - _solve(J[:3], toward * g)

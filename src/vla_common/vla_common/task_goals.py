"""Where a task takes the hand: its goal poses, as data (plain NumPy, no simulator, no kinematics).

A task's goal poses are the TCP poses a demonstration passes through, computed from what the
detector and the catalogue say: the object's class (its shape), its centre (x, y) on the table and
the task (kind, direction, distance). They depend on (x, y) only, never on the object's yaw, which
the learned model does not see either. The planner (`vla_sim.planner`) draws each demonstration
around these poses (its random ranges are declared here), the controller's assistance
(`vla_latent_controller.assistance`) steers toward their middle. One home for both, so that the
assistance aims where the demonstrations went.

- push: hover above the pusher's start (outside the circle round the footprint, opposite the push
  direction), down to push height, along the direction by the task distance plus the footprint's
  slack and a margin;
- circle: a ring round the object above its top, entered where the hand is and gone round the way
  the demonstrations go (counter-clockwise seen from above), a little more than once;
- lift / pick_place (the hand pointing down): hover behind the object (robot side) with the hand
  open, down onto it along the fingers' gap (the hand closes here: the operator's grasp button), then
  up away from the robot (lift) or up and over to the target, down, open, and back.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vla_common.catalogue import ObjectSpec, TaskSpec

FINGER_HALF_THICKNESS = 0.0087  # finger tip extent along the hand's x axis (URDF collision boxes)
TILT_RANGE_DEG = (18.0, 26.0)  # gripper tilt while pushing: finger tips lead, the wrist stays back
DOWN = np.diag([1.0, -1.0, -1.0])  # TCP pointing down, hand x along world x (as in the ready pose)

# The demonstrator's random ranges (vla_sim.planner draws each episode in them; the assistance aims at
# their middle). Push:
APPROACH_GAP = (0.02, 0.04)      # m between the footprint's circle and the finger tips at the start
PUSH_HEIGHT = (0.02, 0.03)       # m of the TCP above the table while pushing
HOVER_EXTRA = (0.06, 0.12)       # m above the object's top before coming down (at least MIN_HOVER)
MIN_HOVER = 0.18
EXTRA_DISTANCE = (0.03, 0.06)    # m pushed beyond the task distance
PUSH_SPEED = (0.06, 0.11)        # m/s
TRANSIT_SPEED = (0.15, 0.25)     # m/s to the hover pose
DESCEND_SHARE = 0.6              # of the transit speed, coming down to push height
# Circle:
CIRCLE_GAP = (0.05, 0.08)        # m outside the footprint's circle
CIRCLE_HEIGHT = (0.05, 0.09)     # m above the object's top
CIRCLE_SPEED = (0.10, 0.16)      # m/s
# Grasps from above: the finger tips this far below the object's top (the free finger is ~5 cm), and
# never below its middle; a place ends with the object this far above its resting height.
GRASP_DEPTH = 0.035
PLACE_CLEARANCE = 0.004
GRASP_HOVER = (0.08, 0.12)       # m above the grasp height before coming down
APPROACH_RUN = (0.05, 0.07)      # m along x covered while descending onto the object
RETREAT_RUN = 0.06               # m back along x while rising after the place
CARRY_LIFT = (0.08, 0.11)        # m the object is raised while carried (pick and place)
GRASP_TRANSIT_SPEED = (0.15, 0.22)
APPROACH_SPEED = (0.06, 0.09)
CARRY_SPEED = (0.08, 0.12)

RING_POINTS = 16                 # goal poses on a circle's ring
RING_SWEEP = 2 * math.pi * 1.05  # how far round they go (the task needs 330 deg)

# What the hand does on arriving at a goal pose
GRASP, OPEN = "grasp", "open"


def mid(bounds: tuple[float, float]) -> float:
    return 0.5 * (bounds[0] + bounds[1])


@dataclass(frozen=True)
class GoalPose:
    """One pose a task passes through: TCP position (m) and rotation in the robot base frame, the
    speed (m/s) a demonstration moves toward it at, what the hand does on arriving ("" nothing,
    GRASP: it closes on the object, OPEN: it lets go), and whether the hand's axis must point as the
    rotation's z there (`aligns`: the hand down over a grasp or a circle; a push's tilt is left to the
    demonstrations, whose extra tilt keeps the forearm off a tall object)."""

    name: str
    position: np.ndarray
    rotation: np.ndarray
    speed: float
    hand: str = ""
    aligns: bool = False


def push_rotation(direction_xy, tilt: float, flip: bool = False) -> np.ndarray:
    """TCP orientation for pushing along a unit (x, y) direction: approach axis (z) down, tilted by
    `tilt` rad so the finger tips lead; hand x axis along +direction (-direction with `flip`: the
    hand is symmetric, the two choices give different arm configurations)."""
    d = np.array([direction_xy[0], direction_xy[1], 0.0], dtype=float)
    d /= np.linalg.norm(d)
    z = np.array([math.sin(tilt) * d[0], math.sin(tilt) * d[1], -math.cos(tilt)])
    x = -d if flip else d
    x = x - z * (x @ z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def preferred_flip(direction_xy) -> bool:
    """The hand flip used for every episode of a push direction: the one whose hand x axis points
    away from the robot (+x), or to +y when the push is sideways. A fixed choice per task keeps all
    its demonstrations in one arm configuration, which a 1-D latent action needs."""
    d = np.asarray(direction_xy, dtype=float)
    if abs(d[0]) > 1e-6:
        return bool(d[0] < 0)
    return bool(d[1] < 0)


def push_start(shape: ObjectSpec, center_xy, direction_xy, gap: float) -> np.ndarray:
    """The TCP's (x, y) before a push: `gap` outside the circle round the object's footprint,
    opposite the push direction. It depends on the object's (x, y), not its yaw: the learned model's
    context (class, x, y) carries no yaw, so a yaw-dependent start cannot be learned (measured: bread
    pushed from where the average loaf's edge would be, off-centre, 20-39 deg off)."""
    d = np.asarray(direction_xy, dtype=float)
    return np.asarray(center_xy, dtype=float) - d * (shape.footprint_radius + FINGER_HALF_THICKNESS + gap)


def grasp_height(shape: ObjectSpec) -> float:
    """The TCP's height when the fingers close on the object from above."""
    return max(shape.height - GRASP_DEPTH, shape.height / 2)


def task_goal_poses(spec: TaskSpec, shape: ObjectSpec, center_xy, tcp=None) -> list[GoalPose]:
    """The goal poses of `spec` for its object (`shape`) centred at `center_xy`, in order. A circle
    is entered at the ring's point nearest `tcp` (the TCP's position; None: from the robot's side)."""
    c = np.asarray(center_xy, dtype=float).reshape(2)
    if spec.kind == "push":
        return _push(spec, shape, c)
    if spec.kind == "circle":
        return _circle(shape, c, tcp)
    if spec.uses_hand:
        return _grasp(spec, shape, c)
    raise ValueError(f"task {spec.name}: no goal poses for kind {spec.kind!r}")


def _push(spec: TaskSpec, shape: ObjectSpec, c: np.ndarray) -> list[GoalPose]:
    d = spec.direction_vector
    gap, z = mid(APPROACH_GAP), mid(PUSH_HEIGHT)
    start = push_start(shape, c, d, gap)
    slack = shape.footprint_radius - shape.min_half_extent
    end = start + d * (gap + slack + spec.distance + mid(EXTRA_DISTANCE))
    rot = push_rotation(d, math.radians(mid(TILT_RANGE_DEG)), preferred_flip(d))
    hover = max(MIN_HOVER, shape.height + mid(HOVER_EXTRA))
    transit = mid(TRANSIT_SPEED)
    return [GoalPose("hover", np.array([*start, hover]), rot, transit),
            GoalPose("pre_push", np.array([*start, z]), rot, transit * DESCEND_SHARE),
            GoalPose("push_end", np.array([*end, z]), rot, mid(PUSH_SPEED))]


def _circle(shape: ObjectSpec, c: np.ndarray, tcp) -> list[GoalPose]:
    r = shape.footprint_radius + mid(CIRCLE_GAP)
    z = shape.height + mid(CIRCLE_HEIGHT)
    if tcp is None:
        a0 = math.pi  # the robot's side
    else:
        a0 = math.atan2(float(tcp[1]) - c[1], float(tcp[0]) - c[0])
    angles = a0 + np.linspace(0.0, RING_SWEEP, RING_POINTS + 1)
    speed = mid(CIRCLE_SPEED)
    out = [GoalPose("ring_entry", np.array([c[0] + r * math.cos(a0), c[1] + r * math.sin(a0), z]), DOWN,
                    mid(TRANSIT_SPEED), aligns=True)]
    out += [GoalPose(f"ring_{i}", np.array([c[0] + r * math.cos(a), c[1] + r * math.sin(a), z]), DOWN, speed,
                     aligns=True) for i, a in enumerate(angles[1:], 1)]
    return out


def _grasp(spec: TaskSpec, shape: ObjectSpec, c: np.ndarray) -> list[GoalPose]:
    zg = grasp_height(shape)
    run, lift = mid(APPROACH_RUN), (spec.distance if spec.kind == "lift" else mid(CARRY_LIFT))
    approach = mid(APPROACH_SPEED)
    out = [GoalPose("hover", np.array([c[0] - run, c[1], zg + mid(GRASP_HOVER)]), DOWN,   # the hand open
                    mid(GRASP_TRANSIT_SPEED), OPEN, aligns=True),
           GoalPose("grasp", np.array([c[0], c[1], zg]), DOWN, approach, GRASP, aligns=True)]
    if spec.kind == "lift":
        return out + [GoalPose("lift", np.array([c[0] + run, c[1], zg + lift]), DOWN, approach, aligns=True)]
    goal = c + spec.direction_vector * spec.distance
    top = (c + goal) / 2
    carry = mid(CARRY_SPEED)
    return out + [GoalPose("carry", np.array([*top, zg + lift]), DOWN, carry, aligns=True),
                  GoalPose("place", np.array([*goal, zg + PLACE_CLEARANCE]), DOWN, carry, OPEN, aligns=True),
                  GoalPose("retreat", np.array([goal[0] - RETREAT_RUN, goal[1], zg + lift]), DOWN, approach,
                           aligns=True)]

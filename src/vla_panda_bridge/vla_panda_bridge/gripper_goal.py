"""control_msgs/action/GripperCommand on the gripper core (plain Python): the request a goal makes
and what its feedback and result say. The node's side is `gripper_action.py`.

Conventions, as MoveIt and franka_ros2's franka_gripper (its `~/gripper_action`) take them:
- `position` is one finger's travel, half the gap between the fingers (the Franka Hand's finger joint,
  0..0.04 m), in the goal, the feedback and the result alike; `max_effort` the grasping force (N, 0:
  the core's default);
- a goal at or beyond the gap the hand has now opens (a move to the gap); a narrower one closes as a
  grasp with that force, which succeeds wherever the fingers stop on an object between the goal and
  where they started (epsilon down to the goal, up to the start), so closing on an object of any size
  is a success, as franka_gripper's is with wide epsilons;
- the result: `reached_goal` when the gap ends within REACHED_TOLERANCE of the goal's, `stalled` when
  the hand holds an object short of it (squeezing with `max_effort`: `effort` is that force while it
  holds, 0 otherwise). The goal succeeds when it reached the goal or holds an object, and aborts when
  the hand stopped elsewhere (the e-stop, a lost hand, a refused motion).
Everything the core checks (range, finite numbers, the force rating, the e-stop, requests too close
together) refuses a goal as it refuses a `~/gripper` request.
"""
from __future__ import annotations

from dataclasses import dataclass

from vla_panda_bridge import gripper

REACHED_TOLERANCE = 0.002   # m of gap: the goal counts as reached within this
RUNNING = (gripper.MOVING, gripper.GRASPING)


@dataclass(frozen=True)
class GoalRequest:
    """The core request of one goal (`gripper.GripperCore.request`'s arguments)."""

    command: int
    width: float
    force: float = 0.0
    epsilon_inner: float = gripper.DEFAULT_EPSILON
    epsilon_outer: float = gripper.DEFAULT_EPSILON


def goal_request(position: float, max_effort: float, width_now: float, max_width: float) -> GoalRequest:
    """What the goal asks of the hand whose gap is `width_now`: a move to open, a grasp to close (its
    band from the goal's gap up to where the fingers start, within the hand's range)."""
    target = 2.0 * float(position)
    if not target < width_now - REACHED_TOLERANCE:      # also NaN: the core's check refuses it
        return GoalRequest(gripper.MOVE, target)
    inner = min(max(target, 0.0), max_width)
    outer = min(max(width_now - target, gripper.DEFAULT_EPSILON), max_width)
    return GoalRequest(gripper.GRASP, target, float(max_effort), epsilon_inner=inner, epsilon_outer=outer)


@dataclass(frozen=True)
class GoalProgress:
    """Feedback and result fields, and whether the goal is over and how."""

    position: float
    effort: float
    stalled: bool
    reached_goal: bool
    done: bool
    succeeded: bool


def goal_progress(state: int, width: float, target_width: float, force: float) -> GoalProgress:
    """The goal's fields from the core's state and measured gap (`target_width` is the goal's gap)."""
    holding = state == gripper.HOLDING
    reached = abs(width - target_width) <= REACHED_TOLERANCE
    done = state not in RUNNING
    return GoalProgress(position=width / 2.0, effort=float(force) if holding else 0.0,
                        stalled=holding and not reached, reached_goal=done and reached,
                        done=done, succeeded=done and (reached or holding))

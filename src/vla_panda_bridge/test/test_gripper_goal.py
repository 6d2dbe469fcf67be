"""control_msgs/GripperCommand goals on the gripper core (gripper_goal.py): the request each goal makes
and the feedback and result it gets. The ROS side (the action served beside ~/gripper) is tested with a
control_msgs built from its definition: test/test_control_msgs.py."""
import math

import pytest
from vla_panda_bridge.gripper_goal import goal_progress, goal_request

from vla_panda_bridge import gripper


def request(position, width_now, max_effort=0.0):
    return goal_request(position, max_effort, width_now=width_now, max_width=0.08)


def test_a_goal_at_or_beyond_the_gap_opens_and_a_narrower_one_grasps():
    assert request(0.04, width_now=0.0).command == gripper.MOVE      # position is half the gap: 0.08
    assert request(0.04, width_now=0.0).width == pytest.approx(0.08)
    assert request(0.02, width_now=0.06).command == gripper.GRASP
    assert request(0.02, width_now=0.041).command == gripper.MOVE    # within 2 mm: a move
    close = request(0.0, width_now=0.08, max_effort=30.0)            # MoveIt's "close"
    assert (close.command, close.width, close.force) == (gripper.GRASP, 0.0, 30.0)
    assert close.epsilon_outer == pytest.approx(0.08)    # an object anywhere between: a success
    wide = request(0.0, width_now=0.0802)                # a hand read a hair over its range
    assert wide.epsilon_outer == 0.08                    # the band stays within it (the core checks it)
    assert request(math.nan, width_now=0.05).command == gripper.MOVE  # the core's check refuses it


@pytest.mark.parametrize("state, width, target, done, ok, reached, stalled", [
    (gripper.MOVING, 0.03, 0.08, False, False, False, False),
    (gripper.IDLE, 0.0795, 0.08, True, True, True, False),      # opened
    (gripper.GRASP_FAILED, 0.0005, 0.0, True, True, True, False),  # closed on nothing: at the goal
    (gripper.HOLDING, 0.031, 0.0, True, True, False, True),     # closed on an object: stalled there
    (gripper.STOPPED, 0.02, 0.08, True, False, False, False),   # the e-stop stopped it
    (gripper.LOST, 0.02, 0.08, True, False, False, False),
])
def test_progress_and_outcome(state, width, target, done, ok, reached, stalled):
    p = goal_progress(state, width, target, force=30.0)
    assert (p.done, p.succeeded, p.reached_goal, p.stalled) == (done, ok, reached, stalled)
    assert p.position == pytest.approx(width / 2)
    assert p.effort == (30.0 if state == gripper.HOLDING else 0.0)

"""The simulated operator's grasp button: phases from a pick-and-place plan, and presses only where a
person would press (open first, close around the object, open over the target), never a flood."""
from types import SimpleNamespace

import numpy as np
from vla_common.catalogue import default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.objects import ObjectPose
from vla_common.robot import PANDA
from vla_evaluation.sim_grasp import (
    BUSY,
    CLOSED,
    FINE_RANGE,
    OPEN,
    SETTLE_TIME,
    GraspButton,
    hand_phases,
    hand_seen,
)
from vla_sim.planner import plan_task

from vla_interfaces.msg import GripperStatus

# hover, grasp point, lift, over the target, place, raise (as the planner's pick and place)
TCP = [(0.5, 0.0, 0.19), (0.5, 0.0, 0.087), (0.5, 0.0, 0.175), (0.5, 0.15, 0.175), (0.5, 0.15, 0.091),
       (0.5, 0.15, 0.175)]
PLAN = SimpleNamespace(times=[2.3, 3.6, 6.0, 7.3, 8.3, 10.1], tcp_waypoints=TCP,
                       hand_events=[(0.0, "open"), (3.6, "grasp"), (8.3, "open")])


def test_a_pick_and_place_plan_has_three_phases_split_at_its_hand_events():
    phases = hand_phases(PLAN)
    assert [p.waypoint_indices for p in phases] == [(0, 1), (2, 3, 4), (5,)]
    assert [p.want for p in phases] == [OPEN, CLOSED, OPEN]
    assert np.allclose(phases[0].end_tcp, TCP[1]) and np.allclose(phases[1].end_tcp, TCP[4])
    assert phases[2].end_tcp is None


def test_the_planners_pick_and_place_splits_the_same_way():
    cat = default_catalogue()
    spec = cat.task("soda_can/pick_place_west")
    plan = plan_task(PandaKinematics(), spec, ObjectPose("soda_can", 0.5, 0.0, 0.0),
                     np.array(PANDA.ready_pose), np.random.default_rng(0), cat)
    phases = hand_phases(plan)
    assert [p.want for p in phases] == [OPEN, CLOSED, OPEN]
    assert sum(len(p.waypoint_indices) for p in phases) == len(plan.waypoints)


def test_presses_open_then_grasp_at_the_object_then_open_over_the_target():
    b = GraspButton(hand_phases(PLAN))
    far = np.array([0.4, 0.0, 0.3])
    assert b.step(0.0, far, CLOSED)            # the hand starts closed: open it
    assert not b.step(0.1, far, BUSY)          # opening
    assert not b.step(1.0, far, OPEN)          # open, far from the object: nothing
    assert not b.step(1.5, np.array(TCP[1]) - [0.01, 0.0, 0.0], OPEN)   # 1 cm short: not yet round it
    assert b.step(2.0, np.array(TCP[1]) + 0.002, OPEN) and b.phase == 1   # fingers round it: grasp
    assert not b.step(2.1, np.array(TCP[1]), BUSY)
    assert not b.step(3.0, np.array(TCP[3]), CLOSED)                        # carrying
    assert b.step(5.0, np.array(TCP[4]), CLOSED) and b.phase == 2           # low over the target
    assert not b.step(6.0, np.array(TCP[5]), OPEN)
    assert b.presses == 3


def test_close_enough_and_no_longer_closer_is_a_press_too():
    b = GraspButton(hand_phases(PLAN))
    near = np.array(TCP[1]) + np.array([0.0, 0.03, 0.0])     # 3 cm off, and stuck there
    assert not any(b.step(t, near, OPEN) for t in np.arange(0.0, 1.4, 0.1))
    assert b.step(1.6, near, OPEN) and b.phase == 1


def test_a_failed_grasp_goes_back_to_the_approach_and_reopens():
    b = GraspButton(hand_phases(PLAN))
    assert b.step(0.0, np.array(TCP[1]), OPEN)      # at the grasp point at once: grasp
    assert b.phase == 1
    assert b.step(1.0, np.array(TCP[2]), CLOSED, failed=True) and b.phase == 0   # reopen


def test_never_a_flood_and_nothing_on_a_non_finite_tcp():
    b = GraspButton(hand_phases(PLAN))
    presses = [b.step(t, np.array([0.4, 0.0, 0.3]), CLOSED) for t in np.arange(0.0, 2.0, 0.01)]
    assert sum(presses) == 4                      # at most one per 0.5 s while the hand stays closed
    assert not b.step(5.0, np.array([np.nan, 0.0, 0.0]), CLOSED)


def test_what_a_person_sees_of_the_hand():
    assert hand_seen(GripperStatus.MOVING, 0.05) == BUSY
    assert hand_seen(GripperStatus.HOLDING, 0.06) == CLOSED
    assert hand_seen(GripperStatus.IDLE, 0.08) == OPEN
    assert hand_seen(GripperStatus.IDLE, 0.0) == CLOSED


def test_the_stick_rests_while_the_hand_closes_and_steers_again_once_it_holds():
    """A person presses grasp at the object and waits for the fingers before carrying on: steering
    on towards the carry waypoints while they closed dragged them off the object."""
    b = GraspButton(hand_phases(PLAN))
    assert not b.holds_still(OPEN)                                          # approaching, hand open
    assert b.step(2.0, np.array(TCP[1]), OPEN) and b.phase == 1             # grasp pressed
    assert b.holds_still(OPEN)                                              # not yet closing
    assert b.holds_still(BUSY)                                              # closing
    assert not b.holds_still(CLOSED)                                        # holding: carry on


def test_releases_once_the_carried_object_is_over_its_target_and_low():
    """Carrying: a person puts the object down once they see it over its target (within 3 cm) with
    the hand low (at most 3 cm above the demonstrator's release), even where the learned path comes
    no nearer the release point, and not while the object is still off the target or high."""
    b = GraspButton(hand_phases(PLAN))
    b.step(0.0, np.array(TCP[1]), OPEN)                     # grasp at once
    assert b.phase == 1
    low = np.array(TCP[4]) + [0.0, 0.02, 0.02]              # 2 cm beside, 2 cm above the release point
    high = np.array(TCP[4]) + [0.0, 0.0, 0.05]
    assert not b.step(1.0, low, CLOSED, to_target=0.045)    # object 4.5 cm off: carry on
    assert not b.step(1.1, high, CLOSED, to_target=0.01)    # over it, 5 cm up: lower it first
    assert b.step(1.2, low, CLOSED, to_target=0.025) and b.phase == 2


def test_the_grasp_button_asks_for_fine_alignment_where_the_path_settles_and_never_presses_there():
    near = np.array(TCP[1]) + np.array([0.0, 0.03, 0.0])     # 3 cm off, and stuck there
    b = GraspButton(hand_phases(PLAN), fine=True)
    ts = np.arange(0.0, 3.0, 0.1)
    assert not any(b.step(t, near, OPEN) for t in ts)       # the settle rule's press is off
    assert b.wants_fine(ts[-1], near, OPEN) and b.phase == 0
    assert not b.wants_fine(ts[-1], near, CLOSED)           # the hand not as the phase wants
    far = np.array(TCP[1]) + np.array([0.0, FINE_RANGE + 0.01, 0.0])
    b2 = GraspButton(hand_phases(PLAN), fine=True)
    for t in ts:
        b2.step(t, far, OPEN)
    assert not b2.wants_fine(ts[-1], far, OPEN)             # too far: steer the latent on
    assert b.step(3.5, np.array(TCP[1]) + 0.002, OPEN) and b.phase == 1   # aligned: grasp
    assert not GraspButton(hand_phases(PLAN)).wants_fine(SETTLE_TIME + 1, near, OPEN)  # fine off


def test_over_the_target_during_alignment_releases():
    b = GraspButton(hand_phases(PLAN), fine=True)
    b.step(0.0, np.array(TCP[1]), OPEN)
    assert b.phase == 1
    assert b.step(5.0, np.array(TCP[4]) + [0.02, 0.0, 0.0], CLOSED, to_target=0.02) and b.phase == 2


def test_the_approach_end_point_moves_with_the_object_and_the_carry_one_does_not():
    b = GraspButton(hand_phases(PLAN), fine=True)
    b.object_shift = np.array([0.02, 0.0, 0.0])              # a finger nudged the bottle 2 cm
    assert np.allclose(b.end_point(), np.array(TCP[1]) + [0.02, 0.0, 0.0])
    assert not b.step(0.0, np.array(TCP[1]), OPEN)           # the old grasp point: nothing there now
    assert b.step(0.5, np.array(TCP[1]) + [0.02, 0.0, 0.0], OPEN) and b.phase == 1
    assert np.allclose(b.end_point(), TCP[4])                # carrying: the target does not move


def test_while_aligning_the_user_finishes_the_alignment_before_releasing():
    near = np.array(TCP[4]) + [0.0, -0.025, 0.0]             # 2.5 cm short of the release point, low
    b = GraspButton(hand_phases(PLAN), fine=True)
    b.step(0.0, np.array(TCP[1]), OPEN)
    assert b.step(0.6, near, CLOSED, to_target=0.025) and b.phase == 2   # not aligning: over it, release
    b2 = GraspButton(hand_phases(PLAN), fine=True)
    b2.step(0.0, np.array(TCP[1]), OPEN)
    ts = np.arange(0.1, 1.5, 0.1)
    for t in ts:
        b2.step(t, near + [0.0, -0.05, 0.0], CLOSED, to_target=0.075)   # 7.5 cm short and stuck
    assert b2.wants_fine(ts[-1], near + [0.0, -0.05, 0.0], CLOSED) and b2.fining
    assert not b2.step(2.0, near, CLOSED, to_target=0.025) and b2.phase == 1   # aligning: not yet
    assert b2.step(3.0, np.array(TCP[4]), CLOSED, to_target=0.0) and b2.phase == 2

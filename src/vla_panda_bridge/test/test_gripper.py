"""The gripper layer (plain Python) with a fake hand driver: the hand's range, bad input, a failed
grasp reported once and never retried, the e-stop (stops a moving hand, never opens a closed one), a
flood of toggles, a lost hand; the states agree with vla_interfaces/GripperStatus."""
import math

import pytest
from vla_common.robot import FR3, PANDA
from vla_panda_bridge.gripper import GripperCore, HandOp, HandReading

from vla_panda_bridge import gripper


class FakeHand:
    """A hand whose motions finish when the test says; a grasp stops at `object_width` (None: no
    object, the fingers close to 0)."""

    max_width = 0.08

    def __init__(self, object_width=None):
        self.width = 0.0
        self.object_width = object_width
        self.started: list[HandOp] = []
        self.stops = 0
        self.moving = False
        self.error = ""
        self.raise_on_read = None

    def start(self, op):
        self.started.append(op)
        self.moving = True

    def stop(self):
        self.stops += 1
        self.moving = False

    def finish(self):
        op = self.started[-1]
        if op.kind == gripper.GRASP:
            self.width = self.object_width if self.object_width is not None else 0.0
        else:
            self.width = op.width
        self.moving = False

    def read(self):
        if self.raise_on_read is not None:
            raise self.raise_on_read
        held = self.object_width is not None and self.started and self.started[-1].kind == gripper.GRASP
        return HandReading(self.width, self.moving, grasped=bool(held) and not self.moving,
                           holding="soda_can" if held and not self.moving else "", error=self.error)


def core(object_width=None):
    hand = FakeHand(object_width)
    return GripperCore(hand), hand


def test_states_and_commands_agree_with_the_messages():
    from vla_interfaces.msg import GripperStatus
    from vla_interfaces.srv import GripperCommand

    for value, name in gripper.STATE_NAMES.items():
        assert getattr(GripperStatus, name) == value
    for value, name in gripper.COMMAND_NAMES.items():
        assert getattr(GripperCommand.Request, name.upper()) == value


def test_the_hand_spec_is_the_franka_hands():
    assert PANDA.hand.finger_joints == ("panda_finger_joint1", "panda_finger_joint2")
    assert FR3.hand.finger_joints == ("fr3_finger_joint1", "fr3_finger_joint2")
    assert (PANDA.hand.max_width, PANDA.hand.max_force, PANDA.hand.max_speed) == (0.08, 70.0, 0.1)


def test_a_grasp_that_closes_on_the_object_holds_it():
    c, hand = core(object_width=0.066)
    ok, text = c.request(gripper.GRASP, 1.0, width=0.066, speed=0.05, force=30.0)
    assert ok, text
    assert c.status.state == gripper.GRASPING
    hand.finish()
    assert c.update(1.5)
    assert c.status.state == gripper.HOLDING and c.holding == "soda_can"
    assert "holding soda_can" in c.status.text


def test_a_grasp_with_nothing_between_the_fingers_is_reported_once_and_never_retried():
    c, hand = core(object_width=None)
    assert c.request(gripper.GRASP, 1.0, width=0.066, force=30.0)[0]
    hand.finish()
    c.update(1.5)
    assert c.status.state == gripper.GRASP_FAILED
    assert "grasp failed" in c.status.text and "not retried" in c.status.text
    for t in range(100):
        assert not c.update(2.0 + t)          # reported once: no further change ...
    assert len(hand.started) == 1             # ... and no second attempt


@pytest.mark.parametrize("kwargs, why", [
    ({"width": math.nan}, "non-finite"),
    ({"width": math.inf}, "non-finite"),
    ({"force": math.nan}, "non-finite"),
    ({"width": -0.01}, "outside the hand's range"),
    ({"width": 0.5}, "outside the hand's range"),
    ({"width": 1e308}, "outside the hand's range"),
    ({"width": 0.05, "force": 1e6}, "rating"),
    ({"width": 0.05, "force": -5.0}, "rating"),
    ({"width": 0.05, "force": 70.1}, "rating"),
    ({"width": 0.05, "speed": 0.11}, "speed"),
    ({"width": 0.05, "speed": -0.05}, "speed"),
    ({"width": 0.05, "epsilon_inner": -1.0}, "epsilon"),
    ({"width": "wide"}, "non-finite"),
])
def test_requests_outside_the_hands_range_are_refused_with_the_reason(kwargs, why):
    c, hand = core(object_width=0.05)
    for command in (gripper.GRASP, gripper.MOVE):
        ok, text = c.request(command, 1.0, **kwargs)
        assert not ok and why in text, text
    assert hand.started == []
    assert c.status.commands_rejected == 2 and c.status.commands_received == 2


@pytest.mark.parametrize("command", [-1, 6, 255, 3.5, True, "grasp", None])
def test_unknown_commands_are_refused(command):
    c, hand = core()
    ok, text = c.request(command, 1.0)
    assert not ok and "unknown gripper command" in text
    assert hand.started == []


def test_at_the_limits_is_accepted_and_the_force_never_exceeds_the_rating():
    c, hand = core(object_width=0.0)
    assert c.request(gripper.GRASP, 1.0, width=0.0, speed=0.1, force=70.0)[0]
    assert c.request(gripper.MOVE, 2.0, width=0.08, speed=0.1)[0]
    assert all(op.force <= PANDA.hand.max_force and op.speed <= 0.1 for op in hand.started)
    assert hand.started[0].width == 0.0 and hand.started[1].width == 0.08


def test_defaults_fill_zero_speed_force_and_epsilon():
    c, hand = core(object_width=0.066)
    assert c.request(gripper.GRASP, 1.0, width=0.066)[0]
    op = hand.started[-1]
    assert (op.speed, op.force, op.epsilon_inner, op.epsilon_outer) == (
        gripper.DEFAULT_SPEED, gripper.DEFAULT_FORCE, gripper.DEFAULT_EPSILON, gripper.DEFAULT_EPSILON)


def test_the_estop_stops_a_moving_hand_and_takes_only_stop_until_released():
    c, hand = core()
    assert c.request(gripper.OPEN, 1.0)[0]
    c.set_estop(True)
    assert hand.stops == 1 and c.status.state == gripper.STOPPED
    ok, text = c.request(gripper.OPEN, 5.0)
    assert not ok and "e-stop" in text
    assert c.request(gripper.STOP, 5.1)[0]
    c.set_estop(False)
    assert len(hand.started) == 1              # releasing starts nothing
    assert c.request(gripper.OPEN, 6.0)[0]


def test_the_estop_never_opens_a_hand_that_holds():
    c, hand = core(object_width=0.066)
    c.request(gripper.GRASP, 1.0, width=0.066, force=30.0)
    hand.finish()
    c.update(1.5)
    assert c.status.state == gripper.HOLDING
    c.set_estop(True)
    assert hand.stops == 0                     # nothing sent to a holding hand
    assert c.status.state == gripper.HOLDING and c.holding == "soda_can"
    assert not c.request(gripper.OPEN, 3.0)[0]  # nor an open while latched
    assert not c.request(gripper.TOGGLE, 3.5)[0]
    assert [op.kind for op in hand.started] == [gripper.GRASP]


def test_a_flood_of_toggles_is_refused_not_obeyed():
    c, hand = core(object_width=0.066)
    times = [1.0 + 0.001 * k for k in range(1000)]           # 1000 toggles in one second
    results = [c.request(gripper.TOGGLE, t) for t in times]
    accepted = [t for t, (ok, _text) in zip(times, results) if ok]
    assert len(accepted) == len(hand.started) <= 1 / gripper.MIN_INTERVAL + 1
    assert all(b - a >= gripper.MIN_INTERVAL - 1e-9 for a, b in zip(accepted, accepted[1:]))
    assert all("too soon" in text for ok, text in results if not ok)
    # spaced toggles alternate open / grasp
    c2, hand2 = core(object_width=0.066)
    for k in range(4):
        assert c2.request(gripper.TOGGLE, 1.0 + k)[0]
        hand2.finish()
        c2.update(1.5 + k)
    kinds = [(op.kind, op.width) for op in hand2.started]
    assert kinds[0] == (gripper.MOVE, 0.08) and kinds[1][0] == gripper.GRASP
    assert kinds[2] == (gripper.MOVE, 0.08) and kinds[3][0] == gripper.GRASP
    assert c2.status.state == gripper.HOLDING


def test_a_toggled_grasp_on_nothing_fails():
    c, hand = core(object_width=None)
    c.request(gripper.TOGGLE, 1.0)       # opens (the hand starts closed)
    hand.finish()
    c.update(1.1)
    c.request(gripper.TOGGLE, 2.0)       # grasps
    hand.finish()
    c.update(2.1)
    assert c.status.state == gripper.GRASP_FAILED


def test_a_lost_hand_is_reported_and_refuses_motion():
    c, hand = core(object_width=0.066)
    hand.error = "connection to 172.16.0.2:1338 closed"
    assert c.update(1.0)
    assert c.status.state == gripper.LOST and "connection" in c.status.text
    ok, text = c.request(gripper.GRASP, 2.0, width=0.066)
    assert not ok and "lost" in text and "arm keeps working" in text
    hand.error = ""
    c.update(3.0)
    assert c.status.state == gripper.IDLE


def test_a_driver_that_raises_is_a_lost_hand_not_a_crash():
    c, hand = core()
    hand.raise_on_read = OSError("network unreachable")
    c.update(1.0)
    assert c.status.state == gripper.LOST and "network unreachable" in c.status.text
    hand.raise_on_read = None

    class Broken(FakeHand):
        def start(self, op):
            raise RuntimeError("gripper server refused")

    c2 = GripperCore(Broken())
    ok, text = c2.request(gripper.OPEN, 1.0)
    assert not ok and "refused" in text and c2.status.state == gripper.LOST


def test_a_non_finite_reading_is_a_lost_hand():
    c, hand = core()
    hand.width = math.nan
    c.update(1.0)
    assert c.status.state == gripper.LOST

"""The one supervisor of the bridge's helper processes (child_process.py) and the hand's slots on the
one IPC (hand_slots.py, shm.py), without a robot: a clock of the test's, shells as children."""
import math

from vla_panda_bridge.child_process import RESTART_MAX, RESTART_MIN, START_TIMEOUT, ChildProcess
from vla_panda_bridge.gripper import GRASP, HandOp, HandReading
from vla_panda_bridge.hand_slots import HandSlots


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def shell(script: str, clock: Clock, stuck=None) -> ChildProcess:
    """A child whose prefix runs `script` (the `python -m` after it is sh's ignored arguments)."""
    return ChildProcess("test", "unused", [], prefix=["sh", "-c", script, "sh"], stuck_timeout=stuck,
                        clock=clock)


def test_a_child_that_exits_is_restarted_with_back_off():
    clock = Clock()
    c = shell("exit 3", clock)
    c.start()
    c._proc.wait()
    assert c.poll(0.0) == "the test process exited with code 3; restarting it"
    waits = []
    for _ in range(6):
        start = clock.t
        while True:
            clock.t += 0.25
            note = c.poll(0.0)
            if "restarted" in note:
                break
        waits.append(clock.t - start)
        c._proc.wait()
        assert "exited with code 3" in c.poll(0.0)
    assert waits[0] == RESTART_MIN and waits[-1] == RESTART_MAX and c.restarts == 6
    assert all(b >= a for a, b in zip(waits, waits[1:]))


def test_a_child_that_makes_no_progress_is_killed_and_one_that_does_is_left():
    clock = Clock()
    c = shell("sleep 600", clock, stuck=3.0)
    c.start()
    for i in range(10):                       # progress changes: working
        clock.t += 1.0
        assert c.poll(float(i)) == ""
    clock.t += 3.5                            # the same progress for longer than stuck_timeout
    assert "wrote nothing for 3 s and was killed" in c.poll(9.0)
    assert c._proc.poll() is not None
    assert c.close(1.0)


def test_a_child_slow_to_start_is_given_start_timeout_and_a_restarted_one_again():
    """At load 30 the loop process wrote nothing for over 3 s after its start (Python importing) or
    inside libfranka's connect: a 3 s bound killed every start. After its first progress, and while
    not `patient`, stuck_timeout is the bound."""
    clock = Clock()
    c = shell("sleep 600", clock, stuck=3.0)
    c.start()
    assert c.poll(5.0) == ""                  # the slots' counter as the previous process left it
    clock.t += START_TIMEOUT - 1.0            # still starting, longer than stuck_timeout: left
    assert c.poll(5.0) == "" and c._proc.poll() is None
    clock.t += 2.0                            # but not for ever
    note = c.poll(5.0)
    assert f"wrote nothing for {START_TIMEOUT:g} s while starting or connecting and was killed" in note
    clock.t += RESTART_MIN
    assert "restarted" in c.poll(5.0)
    clock.t += START_TIMEOUT - 1.0            # the restarted one starts slowly too: left
    assert c.poll(5.0) == "" and c._proc.poll() is None
    clock.t += 0.5
    assert c.poll(6.0) == ""                  # its first write: working now
    clock.t += 3.5                            # blocked connecting (the caller says so): left
    assert c.poll(6.0, patient=True) == "" and c._proc.poll() is None
    assert "wrote nothing for 3 s and was killed" in c.poll(6.0)
    assert c.close(1.0)


def test_close_kills_a_child_that_does_not_leave():
    c = shell("trap '' TERM; sleep 600", Clock())
    c.start()
    assert not c.close(0.2) and c._proc.poll() is not None


def test_the_hand_slots_carry_motions_and_readings_across_processes_views():
    node = HandSlots.create()
    hand = HandSlots.attach(node.path)
    try:
        assert hand.read_op() == (0, HandOp(0, 0.0, 0.0, 0.0, 0.0, 0.0)) and node.read_reading() is None
        node.write_op(7, HandOp(GRASP, 0.03, 0.05, 40.0, 0.01, 0.02))
        assert hand.read_op() == (7, HandOp(GRASP, 0.03, 0.05, 40.0, 0.01, 0.02))
        hand.write_reading(HandReading(width=0.031, moving=False, grasped=True, error="", failed="x",
                                       finger_velocity=-0.01), done=7)
        reading, done = node.read_reading()
        assert done == 7 and reading == HandReading(width=0.031, moving=False, grasped=True, error="",
                                                    failed="x", finger_velocity=-0.01)
        hand.write_reading(HandReading(width=math.nan, moving=True, error="lost"), done=7)
        reading, _ = node.read_reading()
        assert reading.grasped is None and reading.error == "lost" and math.isnan(reading.width)
    finally:
        hand.close()
        node.close()

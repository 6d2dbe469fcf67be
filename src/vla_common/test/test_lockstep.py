"""The lockstep core (no ROS): the step barrier, its pacing, and inputs handed over by stamp."""
import pytest
from vla_common.lockstep import RUNS_FREELY, LockstepError, StampedInputs, StepBarrier, StepPacer

MS = 1_000_000


def test_a_step_advances_only_once_every_participant_answered_it():
    b = StepBarrier(["controller_node", "detector_node"])
    b.begin(10 * MS, wall_now=0.0)
    assert not b.may_advance() and b.waiting_for == ["controller_node", "detector_node"]
    assert b.answer("controller_node", 10 * MS) is None
    assert not b.may_advance() and b.waiting_for == ["detector_node"]
    assert b.answer("detector_node", 10 * MS) is None
    assert b.may_advance()
    assert b.advance() == 1 and not b.may_advance()       # the next step waits for its own answers
    with pytest.raises(LockstepError):
        b.advance()


def test_answers_for_another_step_twice_or_from_strangers_do_not_count():
    b = StepBarrier(["controller_node"])
    b.begin(20 * MS, wall_now=0.0)
    assert b.answer("controller_node", 10 * MS) == ""                # an earlier step's, again
    assert "current one" in b.answer("controller_node", 30 * MS)     # one from the future: a bug
    assert "not a lockstep participant" in b.answer("operator", 20 * MS)
    assert not b.may_advance()
    assert b.answer("controller_node", 20 * MS) is None
    assert b.answer("controller_node", 20 * MS) == ""           # the same answer again: nothing new


def test_it_holds_where_run_says_and_an_idle_graph_is_held():
    b = StepBarrier(["c"], hold=True)
    assert b.hold_step == 0
    b.begin(0, 0.0)
    b.answer("c", 0)
    assert b.held() and not b.may_advance()
    assert b.run(2) == 2
    for step in (1, 2):
        assert b.may_advance()
        b.advance()
        b.begin(step * MS, 0.0)
        assert not b.held()                                  # held needs the answers too
        b.answer("c", step * MS)
    assert b.held() and b.step == 2
    assert b.run(None) == RUNS_FREELY and b.may_advance()
    assert b.run(0) == 2 and b.held()                        # 0: hold where it is


def test_how_long_a_step_has_waited_is_wall_time_of_the_missing_answers():
    b = StepBarrier(["c"])
    b.begin(0, wall_now=100.0)
    assert b.waited(130.0) == pytest.approx(30.0)
    b.answer("c", 0)
    assert b.waited(1000.0) == 0.0


@pytest.mark.parametrize("names", [[], [""], ["c", "c"]])
def test_participants_are_named_once_each(names):
    with pytest.raises(LockstepError):
        StepBarrier(names)


def test_pacing_only_delays_and_a_late_step_goes_at_once():
    p = StepPacer(unit=0.01, real_time_factor=0.5)             # a step every 20 ms of wall time
    assert p.delay(100.0, 1) == pytest.approx(0.02)
    assert p.delay(100.015, 1) == pytest.approx(0.005)
    assert p.delay(100.02, 2) == pytest.approx(0.02)
    assert p.delay(100.5, 3) == 0.0 and p.lag_events == 1      # far behind: a new schedule, at once
    assert p.delay(100.5, 4) == pytest.approx(0.02)
    assert StepPacer(0.01, 0.0).delay(0.0, 1) == 0.0            # 0: as fast as the answers come


def test_inputs_come_in_stamp_order_and_only_in_their_step():
    inp = StampedInputs()
    inp.add("joy", 20, "joy@20")
    inp.add("detections", 10, "dets@10")
    inp.add("image", 20, "image@20")                           # the step's own frame: next step
    inp.add("joy", 10, "joy@10")
    assert inp.has("joy", 20) and not inp.has("joy", 30)
    assert inp.due(20, now_kinds=("joy",)) == [("detections", 10, "dets@10"), ("joy", 10, "joy@10"),
                                                ("joy", 20, "joy@20")]
    assert inp.due(30) == [("image", 20, "image@20")]
    assert len(inp) == 0

"""The link's safety rules, without a browser or ROS: every rule of vla_operator.link."""
import json

import pytest
from vla_operator.link import Link, LinkParams


def msg(**kw) -> str:
    return json.dumps(kw)


def inp(seq, t_ms, axis) -> str:
    return msg(type="input", seq=seq, t=t_ms, axis=axis)


def driving(now=10.0) -> tuple[Link, int]:
    link = Link()
    c = link.connect(now)
    assert link.on_message(c.cid, inp(0, 0.0, 0.0), now).publish  # neutral arms
    return link, c.cid


def test_a_new_driver_moves_only_after_neutral():
    link = Link()
    c = link.connect(0.0)
    v = link.on_message(c.cid, inp(0, 0.0, 0.8), 0.0)
    assert "neutral" in v.error and link.value(0.0) == 0.0 and link.counters.not_armed == 1
    assert link.on_message(c.cid, inp(1, 10.0, 0.0), 0.01).publish
    assert link.on_message(c.cid, inp(2, 30.0, 0.8), 0.03).publish
    assert link.value(0.03) == 0.8


def test_held_input_expires_after_the_staleness_bound():
    link, cid = driving()
    link.on_message(cid, inp(1, 100.0, 0.5), 10.1)
    assert link.value(10.1 + 0.149) == 0.5
    assert link.value(10.1 + 0.151) == 0.0   # no new input: a cut link stops without a close


def test_late_and_reordered_inputs_are_dropped():
    link, cid = driving(10.0)                      # base delay 10 s (browser clock at 0)
    assert link.on_message(cid, inp(1, 100.0, 0.5), 10.1).publish
    v = link.on_message(cid, inp(2, 200.0, 0.9), 10.2 + 0.2)   # sent at 0.2, arrived 0.2 s late
    assert "late" in v.error and link.value(10.4) == 0.0
    v = link.on_message(cid, inp(1, 300.0, 0.9), 10.3)         # a replayed sequence number
    assert "not newer" in v.error and link.counters.stale == 2


def test_inputs_faster_than_the_rate_are_coalesced_latest_wins():
    link, cid = driving()
    assert link.on_message(cid, inp(1, 100.0, 0.2), 10.1).publish
    link.published(10.1)
    v = link.on_message(cid, inp(2, 102.0, 0.4), 10.102)
    assert not v.publish and not v.error and link.counters.coalesced == 1
    assert link.value(10.105) == 0.4


def test_a_press_after_neutral_is_published_at_once_with_that_neutral_first():
    """The station publishes the operator's neutral again just before a press (the controller may
    have missed the neutral stream and would wait for one); a resend or a change while moving does
    not, and a press right after a publish is not held back by the coalescing."""
    link, cid = driving()
    link.published(10.0)
    v = link.on_message(cid, inp(1, 5.0, 0.6), 10.005)          # 5 ms after the neutral's publish
    assert v.publish and v.from_neutral and link.counters.coalesced == 0
    link.published(10.005)
    v = link.on_message(cid, inp(2, 45.0, 0.6), 10.045)         # the page's resend while held
    assert v.publish and not v.from_neutral
    v = link.on_message(cid, inp(3, 85.0, -0.6), 10.085)        # a change of direction
    assert v.publish and not v.from_neutral
    assert link.value(10.3) == 0.0                              # expired: not the operator's neutral
    v = link.on_message(cid, inp(4, 300.0, 0.6), 10.3)
    assert v.publish and not v.from_neutral


def test_close_hidden_and_silence_give_zero_at_once():
    link, cid = driving()
    link.on_message(cid, inp(1, 100.0, 0.5), 10.1)
    assert link.on_message(cid, msg(type="hidden"), 10.11).publish and link.value(10.11) == 0.0
    assert "neutral" in link.on_message(cid, inp(2, 120.0, 0.5), 10.12).error   # re-arm after hide
    link.on_message(cid, inp(3, 130.0, 0.0), 10.13)
    link.on_message(cid, inp(4, 140.0, 0.5), 10.14)
    assert link.disconnect(cid) and link.value(10.14) == 0.0
    link2, cid2 = driving()
    link2.on_message(cid2, inp(1, 100.0, 0.5), 10.1)
    assert not link2.tick(10.1 + 0.4)
    assert link2.tick(10.1 + 0.6) and link2.value(10.6) == 0.0
    assert "neutral" in link2.on_message(cid2, inp(2, 700.0, 0.5), 10.7).error   # must re-arm


def test_a_silence_at_rest_does_not_disarm_the_next_press():
    link, cid = driving(10.0)
    assert not link.tick(10.0 + 2.0)                       # a starved page, nothing held: nothing to stop
    v = link.on_message(cid, inp(1, 2000.0, 0.5), 12.0)    # its next press is new input
    assert v.publish and link.value(12.0) == 0.5
    assert not link.tick(12.0 + 0.4)
    assert link.tick(12.0 + 0.6) and link.value(12.6) == 0.0   # silent while moving: zero, disarmed


def test_a_watch_only_page_never_drives():
    link = Link()
    w = link.connect(0.0, may_drive=False)
    assert not w.driver and link.driver() is None
    assert "another station drives" in link.on_message(w.cid, inp(0, 0.0, 0.0), 0.01).error
    d = link.connect(0.02)
    assert d.driver


def test_one_driver_watchers_may_only_estop():
    link, cid = driving()
    w = link.connect(10.0)
    assert not w.driver
    for m in (inp(0, 0.0, 0.0), msg(type="gripper"), msg(type="release_estop", confirm=True),
              msg(type="claim"), msg(type="episode", action="start", task="bread/push_east")):
        assert link.on_message(w.cid, m, 10.1).error
    assert link.on_message(w.cid, msg(type="estop"), 10.1).request == {"type": "estop"}
    assert link.counters.forbidden == 5
    link.disconnect(cid)
    assert link.on_message(w.cid, msg(type="claim"), 10.2).request == {"type": "claim", "taken_from": None}
    assert link.driver() is w


def test_the_end_effector_mode_button_is_the_drivers_only():
    link, cid = driving()
    w = link.connect(10.0)
    assert link.on_message(cid, msg(type="ee_next"), 10.1).request == {"type": "ee_next"}
    assert link.on_message(w.cid, msg(type="ee_next"), 10.1).error   # a watcher cannot change the axis
    assert link.counters.forbidden == 1


def test_a_watcher_takes_control_only_confirmed_and_with_the_driver_at_rest():
    """Take control: never while the driver's input moves the arm, never without confirm: true; then a
    zero at once, the old driver watches, and the new driver moves only after a neutral input."""
    link, d = driving(10.0)
    w = link.connect(10.0)
    assert link.on_message(d, inp(1, 100.0, 0.5), 10.1).publish            # the driver moves the arm
    v = link.on_message(w.cid, msg(type="claim", confirm=True), 10.12)
    assert "moving the arm" in v.error and link.driver().cid == d and link.value(10.12) == 0.5
    assert "confirm" in link.on_message(w.cid, msg(type="claim"), 10.13).error
    link.on_message(d, inp(2, 140.0, 0.0), 10.14)                          # the driver lets go
    assert "confirm" in link.on_message(w.cid, msg(type="claim"), 10.15).error
    v = link.on_message(w.cid, msg(type="claim", confirm=True), 10.16)
    assert v.publish and v.request == {"type": "claim", "taken_from": d}
    assert link.driver() is w and link.value(10.16) == 0.0
    assert "another station drives" in link.on_message(d, inp(3, 170.0, 0.5), 10.17).error
    # the new driver: a key held through the change moves nothing; a neutral, then a press, moves
    assert "neutral" in link.on_message(w.cid, inp(0, 180.0, 0.5), 10.18).error
    assert link.on_message(w.cid, inp(1, 190.0, 0.0), 10.19).publish
    assert link.on_message(w.cid, inp(2, 200.0, 0.5), 10.2).publish and link.value(10.2) == 0.5


def test_taking_control_from_a_silent_driver_and_never_by_a_display():
    link, d = driving(10.0)
    link.on_message(d, inp(1, 100.0, 0.5), 10.1)
    w = link.connect(10.1)
    shown = link.connect(10.1, may_drive=False)
    assert link.tick(10.7) and link.value(10.7) == 0.0          # the driver's page went silent moving
    assert "watch" in link.on_message(shown.cid, msg(type="claim", confirm=True), 10.8).error
    assert link.on_message(w.cid, msg(type="claim", confirm=True), 10.8).publish
    assert link.driver() is w
    link.disconnect(w.cid)                                      # nobody drives: a display still never does
    assert "watch" in link.on_message(shown.cid, msg(type="claim"), 10.9).error
    assert link.driver() is None


@pytest.mark.parametrize("raw, counter", [
    ("{", "malformed"), ("[1]", "malformed"), ('{"type": 3}', "malformed"),
    (msg(type="input", seq=1, t=0, axis=float("nan")), "malformed"),
    ('{"type": "input", "seq": 1, "t": 0, "axis": NaN}', "malformed"),
    (inp(1, 0, 1.5), "malformed"), (msg(type="input", seq=True, t=0, axis=0.5), "malformed"),
    (msg(type="release_estop"), "malformed"), (msg(type="select", by="nearest"), "malformed"),
    (msg(type="episode", action="start"), "malformed"), (msg(type="launch_missiles"), "unknown"),
    ("x" * 5000, "oversized"), (b"\xff\xfe", "malformed"),
])
def test_bad_messages_are_counted_and_never_move(raw, counter):
    link, cid = driving()
    v = link.on_message(cid, raw, 10.1)
    assert v.error and not v.publish and v.request is None
    assert getattr(link.counters, counter) == 1 and link.value(10.1) == 0.0
    assert link.on_message(cid, inp(5, 110.0, 0.3), 10.11).publish   # the connection survives


def test_params_bound():
    assert LinkParams().stale_after == 0.15


def test_a_hold_stops_refuses_motion_and_needs_a_neutral_after_it():
    """The caregiver's stop on a stale view (Link.hold): zero at once, motion refused while held, and a
    stop as any other after it: the driver's next motion needs a neutral input first."""
    link, cid = driving(10.0)
    assert link.on_message(cid, inp(1, 100.0, 0.5), 10.1).publish and link.value(10.1) == 0.5
    assert link.hold("the live view stopped") and link.value(10.1) == 0.0
    assert not link.hold("again")                                      # once
    v = link.on_message(cid, inp(2, 120.0, 0.5), 10.12)
    assert "the live view stopped" in v.error and link.counters.held == 1 and link.value(10.12) == 0.0
    assert link.on_message(cid, inp(3, 140.0, 0.0), 10.14).publish     # a neutral is fine while held
    v = link.on_message(cid, inp(4, 160.0, 0.5), 10.16)
    assert v.error and link.value(10.16) == 0.0                        # still held
    link.release_hold()
    v = link.on_message(cid, inp(5, 180.0, 0.5), 10.18)                # held through: let go first
    assert "neutral input first (the live view stopped)" in v.error and link.value(10.18) == 0.0
    assert link.on_message(cid, inp(6, 200.0, 0.0), 10.2).publish
    assert link.on_message(cid, inp(7, 220.0, 0.5), 10.22).publish and link.value(10.22) == 0.5


def test_the_arming_rule_is_vla_commons():
    """One owner of the rule: the link's clients arm through vla_common.arming."""
    from vla_common.arming import Arming

    link = Link()
    c = link.connect(0.0)
    assert isinstance(c.arming, Arming) and not c.armed and c.arming.reason == "a new or reloaded page"


def test_a_hold_at_rest_disarms_nothing():
    link, cid = driving(10.0)
    assert link.hold("the live view stopped") and link.value(10.1) == 0.0
    link.release_hold()
    assert link.on_message(cid, inp(1, 200.0, 0.5), 10.2).publish and link.value(10.2) == 0.5

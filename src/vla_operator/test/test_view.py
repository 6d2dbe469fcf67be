"""The stale view (issue 32): the pages are told when no new frame came for about 1 s, and when the
view comes back. A fake clock steps through a stopped camera as the node's timer sees it."""
from vla_operator.view import CHECK_PERIOD_S, RESEND_STALE_S, STALE_AFTER_S, ViewWatch


def test_no_frame_yet_is_stale_with_no_age():
    v = ViewWatch(clock=lambda: 5.0)
    assert v.fields() == {"view_stale": True, "view_age_s": None}


def test_a_stopped_camera_shows_as_stale_within_1_5_s_and_a_frame_brings_it_back():
    now = [100.0]
    v = ViewWatch(clock=lambda: now[0])
    v.seen()
    assert v.changed() == {"view_stale": False, "view_age_s": 0.0}
    told = []
    while not told:                       # the node's timer, every CHECK_PERIOD_S: the camera stopped
        now[0] += CHECK_PERIOD_S
        f = v.changed()
        if f is not None:
            told.append((now[0] - 100.0, f))
    after, f = told[0]
    assert f["view_stale"] and STALE_AFTER_S < after <= 1.5 and f["view_age_s"] == round(after, 2)
    now[0] += CHECK_PERIOD_S
    assert v.changed() is None            # stale, already said: not again at once...
    now[0] += RESEND_STALE_S
    assert v.changed()["view_stale"]      # ...but its age, once a second
    v.seen()
    assert v.changed() == {"view_stale": False, "view_age_s": 0.0}
    assert v.changed() is None

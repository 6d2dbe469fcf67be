"""The station's questionnaire (issue 24): the page is untrusted, so its answers are checked against the
questionnaire that waits (whole numbers on the scale, exactly the statements asked), malformed ones
dropped and counted, a second send refused; and the action ~/questionnaire served by the node, in
process (a page is a link client without a browser: test/test_operator_station.py has the browser)."""
import json

import pytest
from vla_operator.link import Link
from vla_operator.questionnaire import Questionnaire, goal_refusal

STATEMENTS = ("The strategy was easy to use", "The strategy was helpful", "I would use it again")


def waiting(qid=3) -> tuple[Link, int, Questionnaire]:
    link = Link()
    cid = link.connect(0.0).cid
    q = Questionnaire(qid, "About latent-YOLO", STATEMENTS)
    link.questionnaire = q
    return link, cid, q


def answers(qid=3, **over) -> str:
    a = {s: 4 for s in STATEMENTS}
    a.update(over.pop("values", {}))
    for s in over.pop("drop", ()):
        a.pop(s)
    return json.dumps({"type": "answers", "id": qid, "answers": a, **over})


@pytest.mark.parametrize("values, drop, words", [
    ({STATEMENTS[0]: 0}, (), "whole number from 1 to 7"),
    ({STATEMENTS[0]: 8}, (), "whole number from 1 to 7"),
    ({STATEMENTS[1]: 4.5}, (), "whole number from 1 to 7"),
    ({STATEMENTS[1]: 4.0}, (), "whole number from 1 to 7"),      # JSON 4.0 is not a whole number here
    ({STATEMENTS[1]: True}, (), "whole number from 1 to 7"),
    ({STATEMENTS[2]: "5"}, (), "whole number from 1 to 7"),
    ({STATEMENTS[2]: None}, (), "whole number from 1 to 7"),
    ({}, (STATEMENTS[2],), "missing: 'I would use it again'"),
    ({"The robot was fast": 5}, (), "'The robot was fast' was not asked"),
])
def test_answers_that_are_not_on_the_scale_or_not_the_statements_are_dropped_and_counted(values, drop, words):
    link, cid, _q = waiting()
    v = link.on_message(cid, answers(values=values, drop=drop), 1.0)
    assert words in v.error and v.request is None and not v.publish, v
    assert link.counters.malformed == 1 and link.counters.accepted == 0
    assert link.questionnaire is not None            # still waiting: the page may send a corrected one


@pytest.mark.parametrize("raw, words", [
    (json.dumps({"type": "answers", "id": "3", "answers": {}}), "answers.id must be a whole number"),
    (json.dumps({"type": "answers", "id": 3, "answers": [4, 4, 4]}), "answers.answers must be an object"),
    (json.dumps({"type": "answers", "answers": {}}), "answers.id is missing"),
    (answers(qid=10**400), "answers.id must be a whole number"),
    (answers(values={STATEMENTS[0]: 10**400}), "whole number from 1 to 7"),
])
def test_answers_of_the_wrong_shape_are_malformed(raw, words):
    link, cid, _q = waiting()
    assert words in link.on_message(cid, raw, 1.0).error
    assert link.counters.malformed == 1


def test_exact_answers_go_to_the_node_in_the_statements_order_once():
    link, cid, _q = waiting()
    raw = json.dumps({"type": "answers", "id": 3, "answers": {STATEMENTS[2]: 7, STATEMENTS[0]: 1,
                                                                STATEMENTS[1]: 5}})
    v = link.on_message(cid, raw, 1.0)
    assert v.request == {"type": "answers", "id": 3, "answers": [1, 5, 7]} and not v.error
    assert link.questionnaire is None and link.counters.accepted == 1
    again = link.on_message(cid, raw, 1.1)          # a replay, a double click, a reloaded page's resend
    assert "not waiting" in again.error and again.request is None and link.counters.stale == 1


def test_only_the_driver_answers_and_only_the_questionnaire_that_waits():
    link, driver, _q = waiting()
    watcher = link.connect(0.5).cid
    v = link.on_message(watcher, answers(), 1.0)
    assert "watcher" in v.error and link.counters.forbidden == 1
    v = link.on_message(driver, answers(qid=2), 1.0)  # an older questionnaire's id
    assert "questionnaire 2 is not waiting" in v.error and link.counters.stale == 1
    link.questionnaire = None                         # withdrawn
    assert "not waiting" in link.on_message(driver, answers(), 1.0).error


def test_oversized_answers_are_dropped_before_parsing():
    link, cid, _q = waiting()
    v = link.on_message(cid, answers(values={STATEMENTS[0]: 4, "x" * 3000: 1}), 1.0)
    assert "over 2048 bytes" in v.error and link.counters.oversized == 1


@pytest.mark.parametrize("statements, smin, smax, lo, hi, words", [
    ([], 1, 7, "a", "b", "1 to 20 statements"),
    (["a"] * 21, 1, 7, "a", "b", "1 to 20 statements"),
    (["a", " "], 1, 7, "a", "b", "1 to 300 characters"),
    (["a", "a"], 1, 7, "a", "b", "twice"),
    (["a"], 1, 1, "a", "b", "2 to 11 points"),
    (["a"], 7, 1, "a", "b", "2 to 11 points"),
    (["a"], 1, 7, "", "b", "both ends of the scale need words"),
    ([f"{i} " + "x" * 200 for i in range(10)], 1, 7, "a", "b", "would not fit in one message"),
])
def test_a_questionnaire_that_cannot_be_shown_is_refused(statements, smin, smax, lo, hi, words):
    assert words in goal_refusal("t", statements, smin, smax, lo, hi)


def test_the_papers_questionnaire_is_accepted():
    assert goal_refusal("About latent-YOLO", list(STATEMENTS), 1, 7, "strongly disagree",
                        "strongly agree") is None


# ---------------------------------------------------------------------- the action, in process
@pytest.fixture
def station(tmp_path):
    from rclpy.action import ActionClient
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from vla_common.ros.testing import RosHarness
    from vla_operator.station_node import StationNode

    from vla_interfaces.action import Questionnaire as Action

    h = RosHarness()
    node = h.add(StationNode(context=h.context, parameter_overrides=[
        Parameter("port", value=0), Parameter("settings_file", value=str(tmp_path / "s.json")),
        Parameter("controller", value="no_such_controller_for_this_test")]))
    client_node = h.add(Node("questionnaire_test_client", context=h.context))
    client = ActionClient(client_node, Action, "operator_station/questionnaire")
    yield h, node, client
    client.destroy()  # destroy_node leaves an action client, and its context, alive
    h.shutdown()


def send(h, client, statements=STATEMENTS):
    from vla_interfaces.action import Questionnaire as Action

    feedback = []
    assert client.wait_for_server(timeout_sec=10.0)
    sent = client.send_goal_async(Action.Goal(title="About latent-YOLO", statements=list(statements)),
                                  feedback_callback=lambda m: feedback.append(m.feedback))
    assert h.spin_until(sent.done, 10.0)
    return sent.result(), feedback


@pytest.mark.ros
def test_the_driving_page_answers_and_the_client_gets_the_answers(station):
    from action_msgs.msg import GoalStatus

    h, node, client = station
    page = node.station.link.connect(0.0).cid        # a driving page (a link client, no browser)
    handle, feedback = send(h, client)
    assert handle.accepted
    shown = node.state["questionnaire"]
    assert shown["statements"] == list(STATEMENTS) and (shown["min"], shown["max"]) == (1, 7)
    assert shown["min_label"] == "strongly disagree" and shown["max_label"] == "strongly agree"
    assert h.spin_until(lambda: bool(feedback), 5.0) and feedback[-1].driver and feedback[-1].pages == 1
    result = handle.get_result_async()
    bad = {"type": "answers", "id": shown["id"], "answers": {s: 9 for s in STATEMENTS}}
    node.station._on_message(peer(node, page), json.dumps(bad))
    assert node.station.link.counters.malformed == 1
    h.spin_for(0.3)
    assert not result.done()                         # still waiting for a whole answer
    good = {"type": "answers", "id": shown["id"], "answers": dict(zip(STATEMENTS, (2, 6, 7)))}
    node.station._on_message(peer(node, page), json.dumps(good))
    assert h.spin_until(result.done, 10.0)
    r = result.result()
    assert r.status == GoalStatus.STATUS_SUCCEEDED and r.result.answered
    assert list(r.result.answers) == [2, 6, 7]
    assert node.state["questionnaire"] is None       # the pages hide it
    node.station._on_message(peer(node, page), json.dumps(good))  # sent again: refused, nothing changes
    assert node.station.link.counters.stale == 1


@pytest.mark.ros
def test_without_a_driving_page_it_is_aborted_with_the_reason(station):
    from action_msgs.msg import GoalStatus

    h, node, client = station
    handle, _ = send(h, client)
    result = handle.get_result_async()
    assert h.spin_until(result.done, 10.0)
    r = result.result()
    assert r.status == GoalStatus.STATUS_ABORTED and not r.result.answered
    assert "no page drives the operator station" in r.result.message
    assert node.state["questionnaire"] is None


@pytest.mark.ros
def test_one_waits_at_a_time_and_a_cancel_withdraws_it_from_the_pages(station):
    from action_msgs.msg import GoalStatus

    h, node, client = station
    page = node.station.link.connect(0.0).cid
    first, _ = send(h, client)
    qid = node.state["questionnaire"]["id"]
    second, _ = send(h, client)
    r2 = second.get_result_async()
    assert h.spin_until(r2.done, 10.0) and "another questionnaire is waiting" in r2.result().result.message
    result = first.get_result_async()
    cancel = first.cancel_goal_async()
    assert h.spin_until(lambda: cancel.done() and result.done(), 10.0)
    assert result.result().status == GoalStatus.STATUS_CANCELED and not result.result().result.answered
    assert node.state["questionnaire"] is None and node.station.link.questionnaire is None
    late = {"type": "answers", "id": qid, "answers": {s: 4 for s in STATEMENTS}}
    node.station._on_message(peer(node, page), json.dumps(late))   # answers what was withdrawn: refused
    assert node.station.link.counters.stale == 1


def peer(node, cid: int):
    """A page of the link (no socket) as the server's message handler takes it."""
    from vla_operator.server import Limits, Peer
    return Peer(cid, None, None, Limits())

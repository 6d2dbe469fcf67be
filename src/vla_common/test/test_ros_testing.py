"""RosHarness: its shutdown may be called twice (a test that ends its node early, then its fixture)."""
from __future__ import annotations

import pytest
from vla_common.ros.testing import RosHarness

pytestmark = pytest.mark.ros


def test_shutdown_twice_is_harmless():
    import rclpy

    h = RosHarness()
    node = h.add(rclpy.create_node("harness_probe", context=h.context))
    assert node.context.ok()
    h.shutdown()
    assert h.ended
    h.shutdown()          # before: rclpy.shutdown raised on the context already shut down


def test_an_ended_context_has_no_participant_left_and_ending_it_again_does_nothing():
    """The harness's shutdown deletes the participant at once, even where the test left an action
    client on its node (before: rclpy's destroy_node left the client, which held the node and its
    participant until some later collection; a dozen of them in one process could deadlock Fast DDS)."""
    import rclpy
    from rclpy.action import ActionClient
    from vla_common.ros.context import end_context

    from vla_interfaces.action import Questionnaire

    before = _participants()
    h = RosHarness()
    node = h.add(rclpy.create_node("harness_probe", context=h.context))
    ActionClient(node, Questionnaire, "nothing")
    assert _participants() == before + 1
    h.shutdown()
    assert _participants() == before
    end_context(h.context)


def _participants() -> int:
    """This process's Fast DDS participants: one event thread (`dds.ev...`) each."""
    import os

    count = 0
    for task in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{task}/comm") as comm:
                count += comm.read().startswith("dds.ev")
        except OSError:  # the thread ended meanwhile
            pass
    return count


def test_a_harness_sees_only_its_own_nodes_unless_it_talks_to_other_processes():
    """Two harnesses for other processes discover each other; the in-process one sees neither and is
    seen by neither (so a participant an earlier test left behind cannot reach it), and the variable
    it set for its init is back as it was for the processes a test starts."""
    import os

    import rclpy
    from vla_common.ros.domain import DISCOVERY_VARIABLE

    before = os.environ.get(DISCOVERY_VARIABLE)
    alone, one, two = RosHarness(), RosHarness(other_processes=True), RosHarness(other_processes=True)
    try:
        assert os.environ.get(DISCOVERY_VARIABLE) == before
        a = alone.add(rclpy.create_node("harness_alone", context=alone.context))
        b = one.add(rclpy.create_node("harness_one", context=one.context))
        two.add(rclpy.create_node("harness_two", context=two.context))
        assert one.spin_until(lambda: "harness_two" in b.get_node_names(), 20.0)
        assert "harness_alone" not in b.get_node_names()
        assert a.get_node_names() == ["harness_alone"]
    finally:
        for h in (alone, one, two):
            h.shutdown()


def test_discovered_by_is_true_once_the_other_participant_answers_and_false_for_nobody():
    """The answering node spins in its own thread, as a process of its own would."""
    import threading

    import rclpy

    one, two = RosHarness(other_processes=True), RosHarness(other_processes=True)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            two.executor.spin_once(timeout_sec=0.05)

    try:
        asking = one.add(rclpy.create_node("harness_asking", context=one.context))
        two.add(rclpy.create_node("harness_answering", context=two.context))
        server = threading.Thread(target=serve, daemon=True)
        server.start()
        assert one.discovered_by(asking, "/harness_answering", 20.0)
        assert not one.discovered_by(asking, "/harness_nobody", 1.0)
        stop.set()
        server.join()
    finally:
        stop.set()
        for h in (one, two):
            h.shutdown()

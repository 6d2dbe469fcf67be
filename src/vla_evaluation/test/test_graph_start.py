"""The evaluation graph's lockstep start (GraphEvaluator._start_lockstep) without a graph: the detector's
camera subscription is waited for before the first steps render any frame, and the detector check is one
reset (a frame rendered twice at the held step left the controller waiting for the missed one)."""
from __future__ import annotations

from types import SimpleNamespace

import pytest
from vla_evaluation.graph import DETECTOR, START_TRIES, FirstFrameMissedError, GraphError, GraphEvaluator


class Obs:
    def __init__(self, detector_answers: bool, subscribed_after: int = 2):
        self.calls: list[str] = []
        self.polls = 0
        self.subscribed_after = subscribed_after
        self.detector_answers = detector_answers
        self.detections_stamp = 0.0
        self.reset_cli = "reset"
        self.steps = SimpleNamespace(run=self._run)
        self.node = SimpleNamespace(get_namespace=lambda: "/", get_subscriptions_info_by_topic=self._subs)

    def _subs(self, topic):
        assert topic == "/camera/image_raw"
        self.polls += 1
        return [SimpleNamespace(node_name=DETECTOR)] if self.polls > self.subscribed_after else []

    def _run(self, steps, what):
        self.calls.append("steps")
        return 1.2

    def wait_for(self, predicate, timeout, what, alive=None):
        self.calls.append(f"wait: {what}")
        while not predicate():
            if "subscription" not in what:
                raise GraphError(f"timed out waiting for {what}")

    def call(self, client, request, timeout, what):
        self.calls.append(what)
        if self.detector_answers:
            self.detections_stamp = 1.2
        return SimpleNamespace(success=True)


def start(obs: Obs) -> None:
    ev = GraphEvaluator.__new__(GraphEvaluator)
    ev.obs = obs
    ev.config = SimpleNamespace(steps=lambda s: int(round(s * 100)), startup_timeout=5.0)
    ev.alive = lambda: None
    ev.log = lambda text: None
    ev._start_lockstep()


def test_the_detector_is_listening_before_any_frame_is_rendered_and_checked_with_one_reset():
    obs = Obs(detector_answers=True)
    start(obs)
    assert obs.calls[:2] == ["wait: the detector's subscription to the camera", "steps"]
    assert obs.calls.count("reset") == 1 and obs.polls == 3


def test_a_detector_that_misses_the_checks_frame_fails_the_graph_after_one_reset():
    obs = Obs(detector_answers=False)
    with pytest.raises(FirstFrameMissedError, match="in 1 tries"):
        start(obs)
    assert obs.calls.count("reset") == 1


def test_a_graph_whose_detector_missed_its_first_frame_is_launched_again():
    """start() launches again on FirstFrameMissedError (a test or a sweep gets a graph, not the error), up to
    START_TRIES times; any other GraphError is the caller's."""
    ev = GraphEvaluator.__new__(GraphEvaluator)
    ev.log = lambda text: None
    launches = []

    def once(fail: int, other: bool = False):
        def start_once():
            launches.append(1)
            if other:
                raise GraphError("a process ended")
            if len(launches) <= fail:
                raise FirstFrameMissedError("the detector did not answer a camera frame in 1 tries")
        return start_once

    ev._start_once = once(fail=START_TRIES - 1)
    ev.start()
    assert len(launches) == START_TRIES
    launches.clear()
    ev._start_once = once(fail=START_TRIES)
    with pytest.raises(FirstFrameMissedError):
        ev.start()
    assert len(launches) == START_TRIES
    launches.clear()
    ev._start_once = once(fail=0, other=True)
    with pytest.raises(GraphError, match="process ended"):
        ev.start()
    assert len(launches) == 1

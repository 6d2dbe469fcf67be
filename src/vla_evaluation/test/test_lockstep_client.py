"""lockstep_client.await_detector: a detector that missed the first frames (its subscription matched
after the first steps, which take well under a second) gets a new frame from a reset at the held step,
until it answers or the tries run out, loudly."""
from __future__ import annotations

import pytest
from vla_evaluation.lockstep_client import DETECTOR_TRIES, LockstepError, await_detector, steps_to_grid


def run(answers_after: int) -> tuple[list[str], list[float]]:
    resets: list[str] = []
    waits: list[float] = []

    def detected(timeout: float) -> bool:
        waits.append(timeout)
        return len(resets) > answers_after

    await_detector(lambda: resets.append("reset"), detected, lambda text: None)
    return resets, waits


def test_a_detector_that_sees_the_first_frame_costs_one_reset():
    assert run(answers_after=0) == (["reset"], [10.0])


def test_a_late_detector_gets_a_new_frame_each_try_and_longer_to_answer():
    resets, waits = run(answers_after=2)
    assert len(resets) == 3 and waits == [10.0, 20.0, 30.0]


def test_a_deaf_detector_is_an_error_that_says_what_to_check():
    with pytest.raises(LockstepError, match="is it subscribed"):
        run(answers_after=DETECTOR_TRIES)


def test_chunks_are_anchored_at_the_episodes_start_wherever_the_loop_first_looked():
    """0.1 s chunks of 10 ms steps from an episode that started at 5.00 s: the first chunk ends at
    5.10 s whether the loop saw it running at 5.01, 5.02 or 5.09 s, or at 5.10 s itself (then 5.20)."""
    start, unit = 5_000_000_000, 0.01
    for seen_ms, steps in ((5010, 9), (5020, 8), (5090, 1), (5100, 10), (5000, 10)):
        assert steps_to_grid(seen_ms * 1_000_000, start, unit, 10) == steps, seen_ms
    # a start a nanosecond off its step (start + elapsed rounded) still counts whole steps
    assert steps_to_grid(5_030_000_000, start + 1, unit, 10) == 7


def test_a_hang_says_what_the_nodes_said_they_waited_for():
    from vla_evaluation.lockstep_client import lockstep_says
    log = "\n".join([
        "[controller_node-3] [INFO] [1.0] [controller_node]: latched bread",
        "[controller_node-3] [WARN] [11.0] [controller_node]: lockstep: the joint state stamped 1220000000 "
        "ns "
        "has waited 10 s for the detections of the camera frame stamped 1200000000 ns",
        "[panda_bridge-1] [ERROR] [61.0] [panda_bridge]: lockstep hang: step 22 ...",
        "[controller_node-3] [WARN] [21.0] [controller_node]: lockstep: the joint state stamped 1220000000 "
        "ns "
        "has waited 20 s for the detections of the camera frame stamped 1200000000 ns",
    ])
    said = lockstep_says(log, lines=1)
    assert said.startswith("\n  ") and "waited 20 s for the detections of the camera frame" in said
    assert "waited 10 s" in lockstep_says(log) and "lockstep hang" not in lockstep_says(log)
    assert lockstep_says("") == ""


def test_with_one_try_a_missed_first_frame_is_an_error_and_not_rendered_again():
    """Where a controller counts every frame, a second rendering at the held step would leave it waiting
    for the missed frame's detections: one reset, one wait, then the error (the graph is restarted)."""
    resets: list[str] = []
    waits: list[float] = []

    def detected(timeout: float) -> bool:
        waits.append(timeout)
        return False

    with pytest.raises(LockstepError, match="in 1 tries"):
        await_detector(lambda: resets.append("reset"), detected, lambda text: None, tries=1, wait_s=60.0)
    assert resets == ["reset"] and waits == [60.0]

"""The study's questionnaire after each strategy: on the operator station's page when the study runs
with it, else on the terminal; the row in `likert.jsonl` is the same either way.

The station serves the action `operator_station/questionnaire` (vla_interfaces/action/Questionnaire;
see src/vla_operator/README.md). `StationQuestionnaire` sends it the statements and waits for the
participant's answers; when the station does not answer (its action is not there, no page drives it,
no page has driven it for `page_gone_s`, it went away, or it sent something that is not an answer on
the scale) it says why and the runner asks on the terminal instead, so no questionnaire is lost.
Ctrl-C while waiting withdraws the questionnaire from the page (the goal is canceled) and stops the
study as before.
"""
from __future__ import annotations

import threading
import time
import weakref
from collections.abc import Callable, Sequence
from typing import Protocol as TypingProtocol

ACTION = "operator_station/questionnaire"
SCALE = (1, 7)
LABELS = ("strongly disagree", "strongly agree")


class StationAsker(TypingProtocol):
    def ask(self, title: str, statements: Sequence[str]) -> tuple[list[int] | None, str]:
        """The answers in the statements' order, or None and why the station did not answer."""


def likert_row(participant: str, strategy: str, statements: Sequence[str], terminal: Callable[[], dict],
               station: StationAsker | None, log: Callable[[str], None] = print) -> dict:
    """The questionnaire's row: from the station when there is one and it answers, else `terminal()`
    (the runner's `ask_likert`, which gives the same row)."""
    if station is not None:
        log(f"[study] questionnaire for {participant}, strategy {strategy}: on the operator station's page")
        answers, why = station.ask(f"About the strategy you just used: {strategy}", statements)
        if answers is not None:
            log(f"[study] questionnaire answered on the operator station: {answers}")
            return {"participant": participant, "strategy": strategy,
                    "answers": dict(zip(statements, answers))}
        log(f"[study] the operator station did not take the questionnaire ({why}): asking on the terminal")
    return terminal()


def check_answers(answers, n: int, scale: tuple[int, int] = SCALE) -> str | None:
    """Why a station's result is not an answer to `n` statements on `scale`, or None."""
    answers = list(answers)
    if len(answers) != n:
        return f"{len(answers)} answers to {n} statements"
    if not all(isinstance(a, int) and scale[0] <= a <= scale[1] for a in answers):
        return f"an answer is not a whole number from {scale[0]} to {scale[1]}"
    return None


class StationQuestionnaire:
    """The action's client on a node that someone else spins (the study's observer)."""

    def __init__(self, node, action: str = ACTION, server_wait_s: float = 5.0, page_gone_s: float = 60.0,
                 log: Callable[[str], None] = print, poll_s: float = 0.2) -> None:
        from rclpy.action import ActionClient

        from vla_interfaces.action import Questionnaire

        self.Questionnaire = Questionnaire
        self.client = ActionClient(node, Questionnaire, action)
        self.action, self.server_wait_s, self.page_gone_s = action, server_wait_s, page_gone_s
        self.log, self.poll_s = log, poll_s
        self._feedback = None

    def ask(self, title: str, statements: Sequence[str]) -> tuple[list[int] | None, str]:
        from action_msgs.msg import GoalStatus

        if not self.client.wait_for_server(timeout_sec=self.server_wait_s):
            return None, f"its action {self.action} is not available"
        goal = self.Questionnaire.Goal(title=title, statements=list(statements), scale_min=SCALE[0],
                                       scale_max=SCALE[1], min_label=LABELS[0], max_label=LABELS[1])
        self._feedback = None
        sent = self.client.send_goal_async(goal, feedback_callback=self._on_feedback)
        if not _wait(sent, self.server_wait_s):
            return None, "it did not answer the request"
        handle = sent.result()
        if not handle.accepted:
            return None, "it refused the questionnaire (its log says why)"
        result = handle.get_result_async()
        self.log("[study] waiting for the participant's answers on the station's page (Ctrl-C stops the "
                 "study; the questionnaire is then withdrawn)")
        try:
            why = self._wait(result)
        except BaseException:
            handle.cancel_goal_async()   # the page hides it; the study stops as before
            raise
        if why:   # withdrawn; answers that came in meanwhile are still the result
            cancel = handle.cancel_goal_async()
            _wait(cancel, self.server_wait_s)
            if not (_wait(result, self.server_wait_s) and result.result().result.answered):
                return None, why
        r = result.result()
        if r.status != GoalStatus.STATUS_SUCCEEDED or not r.result.answered:
            return None, r.result.message or f"the goal ended with status {r.status}"
        answers = [int(a) for a in r.result.answers]
        problem = check_answers(answers, len(statements))
        if problem:
            return None, f"it sent {problem}"
        return answers, ""

    def _on_feedback(self, msg) -> None:
        self._feedback = msg.feedback

    def _wait(self, result) -> str:
        """'' once the result is there; else why to stop waiting: no page has driven the station, or
        the station has been gone, for `page_gone_s`."""
        done = threading.Event()
        result.add_done_callback(lambda _f: done.set())
        since = None
        while not done.wait(self.poll_s):
            fb = self._feedback
            missing = ("the station went away" if not self.client.server_is_ready() else
                       "no page drives the station" if fb is not None and not fb.driver else "")
            if not missing:
                since = None
                continue
            since = since if since is not None else (time.monotonic(), missing)
            if time.monotonic() - since[0] > self.page_gone_s:
                return f"{since[1]} for {self.page_gone_s:g} s"
        return ""


def _wait(future, timeout: float) -> bool:
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    return done.wait(timeout)


_askers: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def station_for(backend, log: Callable[[str], None] = print) -> StationAsker | None:
    """The station's asker for this backend: its own `questionnaire` when it has one (a test's, another
    front end's), else the action's client on its observer's node (the launched graph, or a robot's
    graph the study attaches to); None without a ROS node (a backend without one: the terminal)."""
    own = getattr(backend, "questionnaire", None)
    if own is not None:
        return own
    obs = getattr(getattr(backend, "ev", None), "obs", None) or getattr(backend, "obs", None)
    node = getattr(obs, "node", None)
    if node is None:
        return None
    try:
        if backend not in _askers:
            _askers[backend] = StationQuestionnaire(node, log=log)
        return _askers[backend]
    except TypeError:   # not weakly referable: a new client each time
        return StationQuestionnaire(node, log=log)

"""The station's questionnaire (no rclpy): what a questionnaire may ask, and what an answer from a page
must be. The page is untrusted: the answers it sends are checked here against the questionnaire that is
waiting, and only a complete, exact answer reaches the action's client.

A questionnaire (the action ``vla_interfaces/action/Questionnaire``, served by the node as
``~/questionnaire``) is a list of statements, each answered with one whole number on a scale
(``scale_min`` to ``scale_max``, words for both ends). One waits at a time. The page answers with
``{type: answers, id, answers: {statement: number, ...}}``: the id of the questionnaire it shows, and one
number for every statement asked, no other.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

MAX_STATEMENTS = 20
MAX_STATEMENT_CHARS = 300
MAX_LABEL_CHARS = 60
MAX_TITLE_CHARS = 120
SCALE_POINTS = (2, 11)


@dataclass(frozen=True)
class Questionnaire:
    qid: int                     # this station's number for it: a page answers the one it shows
    title: str
    statements: tuple[str, ...]
    scale_min: int = 1
    scale_max: int = 7
    min_label: str = "strongly disagree"
    max_label: str = "strongly agree"

    def to_page(self) -> dict:
        return {"id": self.qid, "title": self.title, "statements": list(self.statements),
                "min": self.scale_min, "max": self.scale_max, "min_label": self.min_label,
                "max_label": self.max_label}


def goal_refusal(title: str, statements, scale_min: int, scale_max: int, min_label: str,
                 max_label: str, max_message_bytes: int = 2048) -> str | None:
    """Why a questionnaire cannot be shown, or None (the action's goal is then accepted). The page's
    answer (keyed by the statements) must fit in one message of the link's `max_message_bytes`."""
    statements = list(statements)
    if not 1 <= len(statements) <= MAX_STATEMENTS:
        return f"a questionnaire has 1 to {MAX_STATEMENTS} statements, not {len(statements)}"
    for s in statements:
        if not s.strip() or len(s) > MAX_STATEMENT_CHARS:
            return f"each statement has 1 to {MAX_STATEMENT_CHARS} characters"
    if len(set(statements)) != len(statements):
        return "a statement is there twice"
    if not SCALE_POINTS[0] <= scale_max - scale_min + 1 <= SCALE_POINTS[1]:
        return f"the scale has {SCALE_POINTS[0]} to {SCALE_POINTS[1]} points, not {scale_min}..{scale_max}"
    if not (min_label.strip() and max_label.strip()) or max(len(min_label), len(max_label)) > MAX_LABEL_CHARS:
        return f"both ends of the scale need words (1 to {MAX_LABEL_CHARS} characters)"
    if len(title) > MAX_TITLE_CHARS:
        return f"the title has at most {MAX_TITLE_CHARS} characters"
    answer = {"type": "answers", "id": 2**53, "answers": {s: -128 for s in statements}}   # the longest
    if len(json.dumps(answer, ensure_ascii=False).encode()) > max_message_bytes:
        return (f"the answers to these statements would not fit in one message of the page "
                f"({max_message_bytes} bytes): fewer or shorter statements")
    return None


def answers_problem(q: Questionnaire | None, msg: dict) -> tuple[str, str] | None:
    """Why an answers message is dropped, as (counter, reason), or None. ``malformed``: not the shape
    of an answer, a statement missing or not asked, a value that is not a whole number on the scale;
    ``stale``: no questionnaire waits, or the message answers another (already answered, withdrawn)."""
    qid, answers = msg.get("id"), msg.get("answers")
    if not _int(qid) or not isinstance(answers, dict):
        return "malformed", "answers needs an integer id and answers: {statement: number}"
    if q is None or qid != q.qid:
        return "stale", f"questionnaire {qid} is not waiting (answered or withdrawn)"
    missing = [s for s in q.statements if s not in answers]
    if missing:
        return "malformed", f"every statement needs an answer; missing: {_quote(missing[0])}"
    extra = [k for k in answers if k not in q.statements]
    if extra:
        return "malformed", f"{_quote(str(extra[0]))} was not asked"
    for s in q.statements:
        v = answers[s]
        if not _int(v) or not q.scale_min <= v <= q.scale_max:
            return "malformed", (f"the answer to {_quote(s)} must be a whole number from {q.scale_min} "
                                 f"to {q.scale_max}")
    return None


def ordered(q: Questionnaire, answers: dict) -> list[int]:
    """The checked answers in the statements' order (the action's result)."""
    return [int(answers[s]) for s in q.statements]


def _quote(s: str, n: int = 60) -> str:
    return repr(s if len(s) <= n else s[: n - 1] + "…")


def _int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)

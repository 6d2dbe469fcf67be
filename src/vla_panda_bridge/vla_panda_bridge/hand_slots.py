"""The Franka Hand process's slots: its layout of the bridge's one IPC (`shm.py`), beside the loop's
(`libfranka_slots.py`). Plain Python.

Blocks (float64):
- op (node -> hand, seqlock): the latest motion, numbered (`seq`); the hand process runs each number
  once;
- control (node -> hand, plain): the stop request counter, the close flag, the node's pid;
- reading (hand -> node, seqlock): the hand's latest reading and the number of the last motion that
  finished; written every REPORT_PERIOD, so its counter is the process's liveness;
- texts (hand -> node): the reading's error and the last motion's failure.
"""

from __future__ import annotations

import numpy as np

from vla_panda_bridge.gripper import HandOp, HandReading
from vla_panda_bridge.shm import SharedFile, Texts, read_seqlock, write_seqlock

OP = ("seq", "kind", "width", "speed", "force", "epsilon_inner", "epsilon_outer")
CONTROL = {name: i for i, name in enumerate(("stop_req", "close", "parent_pid"))}
READING = ("width", "moving", "grasped", "finger_velocity", "done")   # grasped: -1 unknown, 0, 1
TEXTS = ("error", "failed")
MAX_TEXT = 1024

_OP_AT = 1                                   # after its counter
_CONTROL_AT = _OP_AT + len(OP)
_READING_SEQ_AT = _CONTROL_AT + len(CONTROL)
_READING_AT = _READING_SEQ_AT + 1
_TEXT_SEQ_AT = _READING_AT + len(READING)
_TEXT_LEN_AT = _TEXT_SEQ_AT + len(TEXTS)
_N_DOUBLES = _TEXT_LEN_AT + len(TEXTS)


class HandSlots(SharedFile):
    """`HandSlots.create()` on the node's side, `HandSlots.attach(path)` in the hand process."""

    SIZE = 8 * _N_DOUBLES + len(TEXTS) * MAX_TEXT
    PREFIX = "vla-hand-"
    VIEWS = ("_d", "_op_seq", "op", "control", "_reading_seq", "reading", "_text", "texts")

    def _views(self) -> None:
        d = self._d = self.doubles(_N_DOUBLES)
        self._op_seq, self.op = d[0:1], d[_OP_AT:_OP_AT + len(OP)]
        self.control = d[_CONTROL_AT:_CONTROL_AT + len(CONTROL)]
        self._reading_seq = d[_READING_SEQ_AT:_READING_SEQ_AT + 1]
        self.reading = d[_READING_AT:_READING_AT + len(READING)]
        self._text = np.frombuffer(self._mm, dtype=np.uint8, count=len(TEXTS) * MAX_TEXT,
                                   offset=8 * _N_DOUBLES)
        self.texts = Texts(TEXTS, d[_TEXT_SEQ_AT:_TEXT_SEQ_AT + len(TEXTS)],
                           d[_TEXT_LEN_AT:_TEXT_LEN_AT + len(TEXTS)], self._text, MAX_TEXT)
        self._op_scratch = np.zeros(len(OP))
        self._reading_scratch = np.zeros(len(READING))
        self._said = {name: "" for name in TEXTS}

    # ------------------------------------------------------------------ node -> hand
    def write_op(self, seq: int, op: HandOp) -> None:
        write_seqlock(self._op_seq, self.op, [seq, op.kind, op.width, op.speed, op.force, op.epsilon_inner,
                                              op.epsilon_outer])

    def read_op(self) -> tuple[int, HandOp] | None:
        """Hand side: (number, motion) of the latest, or None while the node is inside a write."""
        v = read_seqlock(self._op_seq, self.op, self._op_scratch, tries=1000)
        if v is None:
            return None
        return int(v[0]), HandOp(int(v[1]), float(v[2]), float(v[3]), float(v[4]), float(v[5]), float(v[6]))

    # ------------------------------------------------------------------ hand -> node
    def write_reading(self, r: HandReading, done: int) -> None:
        """Hand side: the reading (texts only when they change) and the last finished motion."""
        for name, text in (("error", r.error), ("failed", r.failed)):
            if text != self._said[name]:
                self.texts.write(name, text)
                self._said[name] = text
        grasped = -1.0 if r.grasped is None else float(bool(r.grasped))
        write_seqlock(self._reading_seq, self.reading, [r.width, float(r.moving), grasped, r.finger_velocity,
                                                        done])

    def read_reading(self) -> tuple[HandReading, int] | None:
        """Node side: (the reading, the number of the last finished motion), or None while the hand
        process is inside a write (or has written nothing yet)."""
        if self.reading_seq == 0.0:
            return None
        v = read_seqlock(self._reading_seq, self.reading, self._reading_scratch, tries=1000)
        error, failed = self.texts.read("error"), self.texts.read("failed")
        if v is None or error is None or failed is None:
            return None
        grasped = None if v[2] < 0 else bool(v[2])
        return (HandReading(width=float(v[0]), moving=bool(v[1]), grasped=grasped, error=error, failed=failed,
                            finger_velocity=float(v[3])), int(v[4]))

    @property
    def reading_seq(self) -> float:
        """Changes with every reading the hand process writes: its liveness."""
        return float(self._reading_seq[0])

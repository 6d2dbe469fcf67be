"""The controller's side of a lockstep simulation (no rclpy; vla_common.lockstep says why it works).

In lockstep the controller commands once per joint state, in answer to it: step k (the state stamped
t_k) is computed once the operator's Joy stamped t_k is in, from the inputs stamped for it (the Joy of
this step; frames and detections stamped before it), and its command goes back in the step's answer.
A re-latch waits for the detections of the first camera frame it may use: the frame itself came
before the joint state (the bridge publishes it first), but the detector answers in its own time, so
without the wait the latched detection would depend on the detector's speed.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from vla_common.lockstep import StampedInputs

JOY, DETECTIONS, IMAGE = "joy", "detections", "image"
KEEP_EARLY = 100   # detections remembered that came before their frame's camera_info


class LockstepInputs:
    """The pending joint state, the other inputs by stamp, and the frames whose detections are out."""

    def __init__(self) -> None:
        self.inputs = StampedInputs()
        self.state: tuple[int, Any] | None = None     # (stamp ns, message) of the step to answer
        self.answered_ns = -1                          # the last step answered
        # Counts by stamp, not sets: a reset at a held step renders that step again, so two frames (and
        # two detections) can share a stamp, and a set kept one of them waited for when both
        # detections came before both frames (a lockstep hang).
        self._frames: Counter[int] = Counter()         # camera frames (their stamps) without detections
        self._detected: Counter[int] = Counter()       # detections that came before their frame

    def on_state(self, stamp_ns: int, msg: Any) -> bool:
        """Keep a new step's joint state; True when it is the step just answered again (the bridge
        repeats step 0 until every participant has answered: the answer may have been lost)."""
        if stamp_ns > self.answered_ns:
            self.state = (int(stamp_ns), msg)
        return stamp_ns == self.answered_ns

    def on_joy(self, stamp_ns: int, msg: Any) -> None:
        self.inputs.add(JOY, stamp_ns, msg)

    def on_image(self, stamp_ns: int, value: Any) -> None:
        self.inputs.add(IMAGE, stamp_ns, value)

    def on_frame(self, stamp_ns: int) -> None:
        """A camera frame was published (its camera_info): its detections will follow."""
        stamp_ns = int(stamp_ns)
        if not _take_one(self._detected, stamp_ns):
            self._frames[stamp_ns] += 1

    def on_detections(self, stamp_ns: int, value: Any) -> None:
        self.inputs.add(DETECTIONS, stamp_ns, value)
        stamp_ns = int(stamp_ns)
        if not _take_one(self._frames, stamp_ns):
            self._detected[stamp_ns] += 1
            while len(self._detected) > KEEP_EARLY:   # a frame whose camera_info never comes
                del self._detected[min(self._detected)]

    def missing(self, wanted_since_ns: int | None) -> str | None:
        """What the pending step still waits for (None: it can be computed). `wanted_since_ns`: the
        controller waits to latch a detection of a frame stamped at or after this (None: it needs none)."""
        if self.state is None:
            return "a joint state"
        t = self.state[0]
        if not self.inputs.has(JOY, t):
            return f"the operator's joy stamped {t} ns"
        if wanted_since_ns is not None:
            for frame in sorted(self._frames):
                if frame < wanted_since_ns:
                    del self._frames[frame]           # older than the re-latch: never needed
                elif frame < t:
                    return f"the detections of the camera frame stamped {frame} ns"
        return None

    def take(self) -> tuple[int, Any, list[tuple[str, int, Any]]]:
        """(stamp, joint state, inputs due in that step in stamp order); the step counts as answered."""
        t, msg = self.state
        self.state, self.answered_ns = None, t
        return t, msg, self.inputs.due(t, now_kinds=(JOY,))


def _take_one(counts: Counter[int], stamp_ns: int) -> bool:
    """One of `stamp_ns` out of `counts` (its entry gone at zero); False when there was none."""
    if not counts.get(stamp_ns):
        return False
    counts[stamp_ns] -= 1
    if not counts[stamp_ns]:
        del counts[stamp_ns]
    return True


class EpisodeClock:
    """Lockstep: the core's times, in seconds since an origin that each re-latch (~/redetect, a target
    picked: an evaluation's new episode) moves to its step. Seconds are floats: 5.63 - 5.62 and 1.83 -
    1.82 round differently, and those last bits (a step's dt in the assistance's inference, a window's
    edge) grew into a different outcome, so the same episode came out differently after others on one
    graph than alone on a fresh one (issue 33). Counted from the episode's re-latch, the times a core
    sees are the same floats whatever ran before."""

    def __init__(self) -> None:
        self.origin_ns = 0   # until the first re-latch: the clock's own seconds, as without lockstep

    def seconds(self, stamp_ns: int) -> float:
        return (int(stamp_ns) - self.origin_ns) * 1e-9

    def stamp_ns(self, seconds: float) -> int:
        """The stamp (ns) of a time in this clock's seconds (rounded up to the ns: the earliest stamp
        at or after it)."""
        return math.ceil(seconds * 1e9 - 0.5) + self.origin_ns

    def restart(self, origin_ns: int) -> Callable[[float], float]:
        """Count from `origin_ns` on; returns the map of a time kept in the old seconds to the new ones
        (exact: the value the new origin would have given it; infinities stay)."""
        old, self.origin_ns = self.origin_ns, int(origin_ns)

        def restamp(t: float) -> float:
            if not math.isfinite(t):
                return t
            return (round(t * 1e9) + old - self.origin_ns) * 1e-9
        return restamp

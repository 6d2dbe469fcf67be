"""Lockstep simulation, without ROS: the simulated Panda owns time and moves on one state period only
when every node in the loop has answered the current one (Gazebo's lockstep, CARLA's synchronous mode).

A step is one joint state: step k is the k-th state the bridge publishes, stamped t_k. Its answer is a
participant's message stamped t_k, sent after everything else the participant does in that step. What
makes the outcome a function of the seeds and the code alone, whatever the load:

- the bridge publishes a step's other outputs (status, scene, camera frame) before its joint state, and
  advances only once every answer for it is in (`StepBarrier`); pacing (`StepPacer`) only delays;
- a participant publishes its side outputs (status, service requests) before its answer, so everything a
  step caused reaches every node before the next joint state (one writer's messages to one reader arrive
  in order, and each node handles them in arrival order: the EventsExecutor);
- a node that takes inputs from several writers uses, in step k, exactly the inputs stamped for it
  (`StampedInputs`: the operator's Joy stamped t_k, frames and detections stamped before t_k), so it
  never matters which of them arrived first;
- an orchestrator acts only while the simulation holds (`StepBarrier.run`: run n steps, then hold with
  every answer in: the graph is idle), so a reset, a re-detection or an episode's start happens a fixed
  count of steps after the one before;
- a participant that never answers is a hang (`StepBarrier.waited` past a wall-clock bound): reported,
  never skipped.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

RUNS_FREELY = 2**64 - 1   # vla_interfaces/LockstepStatus.RUNS_FREELY: no hold
EPOCH_NS = 1_000_000_000  # the lockstep clock's step 0 (1 s: never 0, which a sim-time node reads as
#                           "no /clock yet"; the same every run, so stamps and their floats repeat)


class LockstepError(ValueError):
    """A lockstep configuration that cannot work (no participants, a name twice)."""


class StepBarrier:
    """Which participants answered which step, and whether the simulation may move on.

    `begin(stamp, wall)` opens a step (after its joint state is published); `answer(node, stamp)` takes
    an answer; `may_advance()` says all are in and the hold is ahead; `advance()` moves to the next step
    (the caller steps physics, publishes the state and calls `begin`). `run(n)` holds n steps from the
    current one; `held()` is the idle graph an orchestrator acts in."""

    def __init__(self, participants: Iterable[str], hold: bool = False) -> None:
        names = [str(n) for n in participants]
        if not names or any(not n for n in names):
            raise LockstepError("lockstep needs at least one participant, each with a name "
                                f"(the nodes that answer every step), got {names}")
        if len(set(names)) != len(names):
            raise LockstepError(f"a lockstep participant is named twice: {names}")
        self.participants = tuple(names)
        self.step = 0
        self.stamp_ns: int | None = None           # the current step's stamp, once begun
        self.hold_step = 0 if hold else RUNS_FREELY
        self._answered: set[str] = set()
        self._since = 0.0                          # wall time the current step began
        self.hang_reported = False                 # the current step's hang has been reported

    def begin(self, stamp_ns: int, wall_now: float) -> None:
        """Step `self.step` is published with this stamp: it waits for every participant from now."""
        self.stamp_ns = int(stamp_ns)
        self._answered = set()
        self._since = wall_now
        self.hang_reported = False

    def answer(self, node: str, stamp_ns: int) -> str | None:
        """Take `node`'s answer for the step stamped `stamp_ns`; None when it counts, "" for an answer
        given again (to this step or an earlier one: step 0 is repeated until all have answered it), else
        why not (a node that is no participant, an answer for a step not yet published: bugs worth a
        warning)."""
        if node not in self.participants:
            return f"an answer from {node!r}, who is not a lockstep participant {list(self.participants)}"
        if self.stamp_ns is not None and int(stamp_ns) < self.stamp_ns:
            return ""      # an earlier step's again (a repeated step 0's): it was counted then
        if self.stamp_ns is None or int(stamp_ns) != self.stamp_ns:
            return (f"{node} answered the step stamped {int(stamp_ns)} ns, the current one is "
                    f"{self.stamp_ns} ns (step {self.step}): ignored")
        if node in self._answered:
            return ""      # the same answer again (to step 0, repeated until all have it): nothing new
        self._answered.add(node)
        return None

    @property
    def waiting_for(self) -> list[str]:
        return [n for n in self.participants if n not in self._answered]

    def complete(self) -> bool:
        return self.stamp_ns is not None and not self.waiting_for

    def may_advance(self) -> bool:
        return self.complete() and self.step < self.hold_step

    def held(self) -> bool:
        """At the hold with every answer in: nothing runs until `run`."""
        return self.complete() and self.step >= self.hold_step

    def advance(self) -> int:
        if not self.may_advance():
            raise LockstepError(f"step {self.step} may not advance: waiting for {self.waiting_for}, "
                                f"hold at {self.hold_step}")
        self.step += 1
        self.stamp_ns = None
        return self.step

    def run(self, steps: int | None) -> int:
        """Hold `steps` steps from the current one (None: run freely); returns the hold step."""
        self.hold_step = RUNS_FREELY if steps is None else self.step + max(0, int(steps))
        return self.hold_step

    def waited(self, wall_now: float) -> float:
        """Wall seconds the current step has waited for answers (0 when none is missing)."""
        return 0.0 if self.complete() or self.stamp_ns is None else max(0.0, wall_now - self._since)


class StepPacer:
    """When to advance a lockstep simulation at `real_time_factor` (0: at once). It only ever delays:
    a step whose answers come late goes at once, and a simulation more than `max_lag` simulated s
    behind its schedule starts a new one from there (it cannot catch up by running faster)."""

    def __init__(self, unit: float, real_time_factor: float, max_lag: float = 0.1) -> None:
        self.unit, self.rtf, self.max_lag = float(unit), float(real_time_factor), float(max_lag)
        self._anchor: tuple[float, int] | None = None   # (wall, step) of the schedule's start
        self.lag_events = 0

    def delay(self, wall_now: float, next_step: int) -> float:
        """Wall seconds to wait before publishing step `next_step` (0: now)."""
        if self.rtf <= 0.0:
            return 0.0
        if self._anchor is None:
            self._anchor = (wall_now, next_step - 1)
        wall0, step0 = self._anchor
        due = wall0 + (next_step - step0) * self.unit / self.rtf
        if wall_now - due > self.max_lag / self.rtf:
            self.lag_events += 1
            self._anchor = (wall_now, next_step)
            return 0.0
        return max(0.0, due - wall_now)

    def restart(self) -> None:
        """Forget the schedule (after a hold: the next step starts a new one)."""
        self._anchor = None


@dataclass(order=True)
class _Item:
    stamp_ns: int
    seq: int
    kind: str = field(compare=False)
    value: Any = field(compare=False)


class StampedInputs:
    """A node's inputs from several writers, handed over in stamp order per step (rclpy-free).

    `add(kind, stamp, value)` keeps a message as it arrives; `due(step_stamp, now_kinds)` hands back,
    in stamp order, every kept message stamped before the step, plus those of `now_kinds` stamped up
    to the step itself (the operator's Joy of this very step); later ones wait for their step. So a
    node sees the same inputs in every step whichever writer's message came first."""

    def __init__(self) -> None:
        self._items: list[_Item] = []
        self._seq = 0

    def add(self, kind: str, stamp_ns: int, value: Any) -> None:
        self._seq += 1
        self._items.append(_Item(int(stamp_ns), self._seq, kind, value))

    def has(self, kind: str, stamp_ns: int) -> bool:
        return any(i.kind == kind and i.stamp_ns == stamp_ns for i in self._items)

    def stamps(self, kind: str) -> list[int]:
        return sorted(i.stamp_ns for i in self._items if i.kind == kind)

    def due(self, step_ns: int, now_kinds: tuple[str, ...] = ()) -> list[tuple[str, int, Any]]:
        """Remove and return (kind, stamp, value) of every message due in the step stamped `step_ns`."""
        due, keep = [], []
        for item in self._items:
            limit_ok = item.stamp_ns < step_ns or (item.kind in now_kinds and item.stamp_ns <= step_ns)
            (due if limit_ok else keep).append(item)
        self._items = keep
        return [(i.kind, i.stamp_ns, i.value) for i in sorted(due)]

    def __len__(self) -> int:
        return len(self._items)

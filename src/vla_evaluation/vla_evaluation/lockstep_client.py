"""An orchestrator's handle on the bridge's lockstep simulation (vla_common.lockstep): run a fixed count
of steps, then wait until the simulation holds with every answer in, so that what the orchestrator does
next (a reset, a re-detection, an episode's start) happens at a step that depends on nothing but the
counts. A hang the bridge reports (a participant that never answered) fails at once, loudly; the
wall-clock bound here is only against a bridge that says nothing at all.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from vla_common.lockstep import EPOCH_NS

from vla_interfaces.msg import LockstepStatus
from vla_interfaces.srv import LockstepRun

BRIDGE = "panda_bridge"
# Wall-clock bound on a run: a base plus this per simulated second (a step takes ~2-5 ms of CPU at real
# time factor 0; two busy loops beside it make that ~3x). Only against a silent hang: the bridge
# reports a step unanswered for its lockstep_timeout itself.
RUN_BASE_S, RUN_PER_SIM_S = 120.0, 20.0


class LockstepError(RuntimeError):
    """The simulation could not move on: a participant did not answer (the bridge's report)."""


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def lockstep_says(log_text: str, lines: int = 3) -> str:
    """The last `lines` lines of a graph's output in which a node says what a lockstep step waits for
    ("lockstep: ... has waited N s for ..."): appended to a hang's error, whose graph and log are
    then gone (the last hangs said only which node, not what it waited for)."""
    said = [line.strip() for line in log_text.splitlines() if "lockstep:" in line and "waited" in line]
    return "".join(f"\n  {line}" for line in said[-lines:])


def steps_to_grid(now_ns: int, start_ns: int, unit_s: float, every: int) -> int:
    """Steps from the step stamped `now_ns` to the next one a whole number of `every` steps after
    `start_ns` (1 to `every`). An orchestrator that runs an episode in chunks anchors them at the
    episode's start: anchored where its loop first saw the episode running (a status that is not part
    of a step's answers, so it can come a step or two late under load), a stop on success fell on
    another step."""
    every = max(1, int(every))
    since = round((int(now_ns) - int(start_ns)) / max(1, round(unit_s * 1e9)))
    return every - since % every


class LockstepClient:
    """`run(steps)` runs that many steps and returns once the bridge holds, every answer in.

    Made with the orchestrator's node before it spins: `cond` is the condition its callbacks notify,
    `state_stamp()` the stamp (s) of the last joint state it has seen (so that it has everything the
    held step published). Set `alive` (raises when a process of the graph has ended), `unit` (simulated
    s per step) and `real_time_factor` before the first run."""

    def __init__(self, node, cond: threading.Condition, state_stamp: Callable[[], float],
                 error: type[Exception] = LockstepError) -> None:
        self.cond, self.state_stamp, self.error = cond, state_stamp, error
        self.alive: Callable[[], None] = lambda: None
        self.why_hung: Callable[[], str] = lambda: ""   # what the waited-for nodes said (their log)
        self.unit, self.real_time_factor = 0.01, 0.0
        self.status: LockstepStatus | None = None
        self.client = node.create_client(LockstepRun, f"{BRIDGE}/lockstep_run")
        node.create_subscription(LockstepStatus, f"{BRIDGE}/lockstep", self._on_status, 50)
        self.step = 0          # where it holds (after the last run)
        self.stamp = math.nan  # the simulated time (s) of that step
        self.stamp_ns = -1     # ... in ns (differences of times in s round by how long the graph ran)
        self._target: int | None = None   # the hold the current run waits for
        self._lowered: int | None = None  # a hold a participant set during the run (hold_after)

    def _on_status(self, msg: LockstepStatus) -> None:
        with self.cond:
            self.status = msg
            self.cond.notify_all()

    def run(self, steps: int, what: str = "") -> float:
        """Run `steps` steps from where it holds (0: just wait for the hold) and wait until it holds
        again; returns the held step's simulated time (s)."""
        if not self.client.wait_for_service(timeout_sec=30.0):
            raise self.error(f"service {self.client.srv_name} not available: is the bridge in lockstep?")
        done = threading.Event()
        with self.cond:
            self._target = self._lowered = None
        fut = self.client.call_async(LockstepRun.Request(steps=int(steps)))
        fut.add_done_callback(lambda _f: done.set())
        if not done.wait(30.0):
            raise self.error(f"{self.client.srv_name} did not answer within 30 s")
        with self.cond:   # a participant may have lowered the hold already (a trial that ends at once)
            asked = int(fut.result().hold_step)
            self._target = asked if self._lowered is None else min(asked, self._lowered)
        sim_s = max(0, int(steps)) * self.unit
        paced = sim_s / self.real_time_factor * 4 if self.real_time_factor > 0 else 0.0
        bound = RUN_BASE_S + RUN_PER_SIM_S * sim_s + paced
        self._wait_held(bound, what or f"{steps} steps")
        self.step, self.stamp, self.stamp_ns = self._target, stamp_s(self.status), stamp_ns(self.status)
        return self.stamp

    def hold_after(self, stamp_ns: int, steps: int) -> None:
        """From a participant's answer to the joint state stamped `stamp_ns` (its callback, before it
        answers): hold `steps` after that step instead. The bridge is at that step until the answer
        comes, so the hold is exact; the run under way returns there."""
        step = (int(stamp_ns) - EPOCH_NS) // max(1, round(self.unit * 1e9))
        with self.cond:
            self._lowered = step + int(steps)
            if self._target is not None:
                self._target = min(self._target, self._lowered)
        self.client.call_async(LockstepRun.Request(steps=int(steps)))

    def _wait_held(self, bound: float, what: str) -> None:
        deadline = time.monotonic() + bound
        with self.cond:
            while True:
                st, target = self.status, self._target
                if st is not None and st.hung:
                    raise self.error(f"{what}: {st.text}{self.why_hung()}")
                if st is not None and st.held and st.step == target and self.state_stamp() >= stamp_s(st):
                    return
                left = deadline - time.monotonic()
                if left <= 0:
                    waiting = f"; it last said: {st.text}" if st is not None else ""
                    raise self.error(f"{what}: the simulation did not reach step {target} within "
                                     f"{bound:.0f} s{waiting}")
                self.cond.wait(min(left, 0.5))
                self.cond.release()
                try:
                    self.alive()
                finally:
                    self.cond.acquire()


DETECTOR_TRIES = 5  # resets at the held step before a graph is called deaf (each waits 10 s longer)
DETECTOR_WAIT_S = 10.0


def await_detector(reset: Callable[[], None], detected: Callable[[float], bool], log: Callable[[str], None],
                   error: type[Exception] = LockstepError, tries: int = DETECTOR_TRIES,
                   wait_s: float = DETECTOR_WAIT_S) -> None:
    """Lockstep, once after the first steps: make sure the detector sees the camera. Those steps pass in
    well under a second of wall time, before the discovery of every pair of nodes is done, and a
    frame published before the detector's subscription matched is never seen; with the simulation held
    no other frame comes, and a wait for its detections would hang. `reset()` resets the scene at the
    held step (which renders a frame and moves no time); `detected(timeout)` says whether its
    detections came within `timeout` wall s (`wait_s` times the try's number). Only counts of steps
    pass, so no result depends on it. `tries` = 1 where a latent controller is in the loop: it counts
    every frame it is told of and waits for each one's detections, so a frame the detector missed,
    rendered again at the same stamp, left it waiting for the missed one's detections (a lockstep hang,
    twice at a graph's first hold): such a graph is an error, and its callers start a new one."""
    for attempt in range(1, tries + 1):
        reset()
        if detected(wait_s * attempt):
            return
        log(f"lockstep: no detections of the first frame yet (attempt {attempt}/{tries})")
    raise error(f"the detector did not answer a camera frame in {tries} tries: is it subscribed?")

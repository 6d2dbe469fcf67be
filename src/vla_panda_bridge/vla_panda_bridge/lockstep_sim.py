"""The MuJoCo backend's lockstep mode (`lockstep: true`): time moves one state period at a time, once
every node in `lockstep_participants` has answered the current joint state (vla_common.lockstep).

Event-driven: the last answer of a step advances the simulation in its own callback; at a
`real_time_factor` > 0 a steady-clock timer only delays that (StepPacer). Answers come as
vla_interfaces/StepAnswer on `lockstep/answer`; a commander's command in its answer goes through the
node's one safety filter like any joint_velocity_cmd. `~/lockstep_run` (LockstepRun) runs n steps and
holds; `~/lockstep` (LockstepStatus) says when it holds and when a step has waited past
`lockstep_timeout` wall seconds (a hang: reported and logged, never skipped). No rclpy: ROS goes
through the host (the node).
"""
from __future__ import annotations

import time
from collections.abc import Callable

from vla_common.lockstep import RUNS_FREELY, StepBarrier, StepPacer
from vla_common.ros.convert import ns_from_stamp, stamp_from_ns

from vla_interfaces.msg import LockstepStatus, StepAnswer
from vla_interfaces.srv import LockstepRun

ANSWER_DEPTH = 100                   # reliable (a depth is a reliable keep-last): a lost answer is a hang
WATCH_PERIOD_S = 1.0                 # how often a waiting step is checked against lockstep_timeout
REPEAT_FIRST_S = 0.25                # step 0's joint state again this often until all have answered it


class Lockstep:
    """The barrier's ROS side. `period()` advances one state period and publishes it (the backend's);
    `stamp_ns()` is the current step's simulated time; `on_hold()` publishes what an orchestrator reads
    when it holds (the scene: a trial's end state is read there). Step 0's joint state is published
    again every REPEAT_FIRST_S until every participant has answered it: the bridge starts before the
    nodes that answer it, and a state they never received would be a hang (nothing moves meanwhile)."""

    def __init__(self, host, unit: float, period: Callable[[], None], stamp_ns: Callable[[], int],
                 on_hold: Callable[[], None]) -> None:
        p = host.params
        self._host, self._period, self._stamp_ns, self._on_hold = host, period, stamp_ns, on_hold
        self.barrier = StepBarrier(p["lockstep_participants"], hold=p["lockstep_hold"])
        self.pacer = StepPacer(unit, p["real_time_factor"])
        self.timeout = float(p["lockstep_timeout"])
        self._log = host.get_logger()
        self._status_pub = host.create_publisher(LockstepStatus, "~/lockstep", 10)
        host.create_subscription(StepAnswer, "lockstep/answer", self._on_answer, ANSWER_DEPTH)
        host.create_service(LockstepRun, "~/lockstep_run", self._on_run)
        self._pace_timer = host.create_wall_timer(1.0, self._on_pace)
        self._pace_timer.cancel()
        host.create_wall_timer(WATCH_PERIOD_S, self._watch)
        self._first = host.create_wall_timer(REPEAT_FIRST_S, self._repeat_first)
        self._held_reported = False
        self.hangs = 0

    def begin(self) -> None:
        """The current step's joint state is out: wait for its answers from now."""
        self.barrier.begin(self._stamp_ns(), time.monotonic())
        self._held_reported = False

    # ------------------------------------------------------------------------------- answers
    def _on_answer(self, msg: StepAnswer) -> None:
        why = self.barrier.answer(msg.node, ns_from_stamp(msg.header.stamp))
        if why:
            self._log.warn(f"lockstep: {why}", throttle_duration_sec=1.0)
        if why is not None:
            return
        if len(msg.command):
            self._host.submit_command(msg.command)
        self._proceed()

    def _proceed(self) -> None:
        """Advance if every answer is in and the hold is ahead (paced); say so once it holds."""
        b = self.barrier
        if b.held():
            if not self._held_reported:
                self._held_reported = True
                self.pacer.restart()
                self._on_hold()
                self.publish_status("held: every participant answered; ~/lockstep_run moves on")
            return
        if not b.may_advance() or not self._pace_timer.is_canceled():
            return
        delay = self.pacer.delay(time.monotonic(), b.step + 1)
        if delay > 0.0:
            self._pace_timer.timer_period_ns = max(1, int(delay * 1e9))
            self._pace_timer.reset()
            return
        b.advance()
        self._period()
        self.begin()

    def _repeat_first(self) -> None:
        if self.barrier.step == 0 and not self.barrier.complete():
            self._host.publish_state()
        else:
            self._first.cancel()

    def _on_pace(self) -> None:
        self._pace_timer.cancel()
        self._proceed()

    # ------------------------------------------------------------------------------- control
    def _on_run(self, request: LockstepRun.Request, response: LockstepRun.Response):
        b = self.barrier
        hold = b.run(None if request.free else int(request.steps))
        response.success, response.step, response.hold_step = True, b.step, hold
        response.message = ("running freely" if hold == RUNS_FREELY else
                            f"at step {b.step}: holding at step {hold}")
        self._held_reported = False
        self._proceed()
        return response

    def _watch(self) -> None:
        """Steady clock: a step unanswered past lockstep_timeout is a hang (the trial fails; the
        simulation never moves on without the answers)."""
        b = self.barrier
        waited = b.waited(time.monotonic())
        if waited > self.timeout and not b.hang_reported:
            b.hang_reported = True
            self.hangs += 1
            text = (f"lockstep hang: step {b.step} (t = {b.stamp_ns} ns) has waited {waited:.0f} s "
                    f"(lockstep_timeout) for {', '.join(b.waiting_for)}; it will not move on without them")
            self._log.error(text)
            self.publish_status(text, hung=True)

    def publish_status(self, text: str, hung: bool = False) -> None:
        b = self.barrier
        msg = LockstepStatus(step=b.step, hold_step=b.hold_step, held=b.held(), hung=hung,
                             waiting_for=b.waiting_for, waited=b.waited(time.monotonic()), text=text)
        msg.header.stamp = stamp_from_ns(self._stamp_ns())
        self._status_pub.publish(msg)

    def describe(self) -> str:
        b = self.barrier
        hold = "held at step 0 until ~/lockstep_run" if b.hold_step == 0 else "running freely"
        return f"lockstep with {', '.join(b.participants)} ({hold})"

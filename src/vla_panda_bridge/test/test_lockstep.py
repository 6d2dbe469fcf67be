"""The bridge's lockstep mode, in-process: the simulation moves one joint state at a time, once every
participant answered it, whatever the pacing; it holds where ~/lockstep_run says; a participant that never
answers is a reported hang. The probe node here is the participant (the controller's role)."""
import math
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from vla_common.lockstep import EPOCH_NS
from vla_common.ros.context import end_context
from vla_panda_bridge.bridge_node import ConfigError, PandaBridge

from vla_interfaces.msg import LockstepStatus, SafetyStatus, StepAnswer
from vla_interfaces.srv import LockstepRun

pytestmark = pytest.mark.ros
HANG_BOUND_S = 120.0   # wall s: only against a hang; every wait below is for simulated steps


def _ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class Stepper:
    """The bridge in lockstep and a probe that answers each joint state with `command(k)`."""

    def __init__(self, command=lambda k: [0.0] * 7, answer: bool = True, **params):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        defaults = {"camera_rate": 0.0, "real_time_factor": 0.0, "state_rate": 100.0, "lockstep": True,
                    "lockstep_participants": ["probe"], "lockstep_hold": True, "command_timeout": 0.05}
        defaults.update(params)
        self.bridge = PandaBridge(context=self.ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in defaults.items()])
        self.probe = rclpy.create_node("probe", context=self.ctx)
        self.executor.add_node(self.bridge)
        self.executor.add_node(self.probe)
        self.states: list[JointState] = []
        self.lockstep: list[LockstepStatus] = []
        self.safety: list[SafetyStatus] = []
        self.command, self.answering = command, answer
        self.answers = self.probe.create_publisher(StepAnswer, "lockstep/answer", 100)
        self.probe.create_subscription(JointState, "joint_states", self._on_state, 1000)
        self.probe.create_subscription(LockstepStatus, "panda_bridge/lockstep", self.lockstep.append, 100)
        self.probe.create_subscription(SafetyStatus, "panda_bridge/status", self.safety.append, 100)
        self.run_cli = self.probe.create_client(LockstepRun, "panda_bridge/lockstep_run")

    def _on_state(self, msg: JointState) -> None:
        if self.states and _ns(msg) == _ns(self.states[-1]):
            return                                   # step 0 again (until answered)
        self.states.append(msg)
        if self.answering:
            k = (_ns(msg) - EPOCH_NS) // 10_000_000
            self.answers.publish(StepAnswer(header=msg.header, node="probe",
                                            command=[float(v) for v in self.command(k)]))

    def wait(self, pred, timeout: float = HANG_BOUND_S) -> bool:
        end = time.monotonic() + timeout
        while not pred():
            if time.monotonic() > end:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def run(self, steps: int) -> LockstepRun.Response:
        assert self.run_cli.wait_for_service(timeout_sec=10.0)
        fut = self.run_cli.call_async(LockstepRun.Request(steps=steps))
        assert self.wait(fut.done, 10.0)
        res = fut.result()
        assert self.wait(lambda: any(s.held and s.step == res.hold_step for s in self.lockstep)), \
            f"no hold at step {res.hold_step}: {self.lockstep[-1:]}"
        return res

    def close(self) -> None:
        self.bridge.destroy_node()
        self.probe.destroy_node()
        self.executor.shutdown()
        end_context(self.ctx)


@pytest.fixture
def stepper():
    made = []

    def make(**kw):
        made.append(Stepper(**kw))
        return made[-1]

    yield make
    for s in made:
        s.close()


def _sweep(k: int) -> list[float]:
    """A command that changes every step: any step taken with another step's command would show."""
    return [0.0, 0.0, 0.0, 0.0, 0.0, 0.3 * math.sin(0.05 * k), 0.4 * math.cos(0.03 * k)]


def test_it_holds_at_step_0_then_runs_exactly_the_steps_asked(stepper):
    s = stepper(command=_sweep)
    assert s.wait(lambda: s.states)
    assert _ns(s.states[0]) == EPOCH_NS                       # the lockstep clock's fixed start
    res = s.run(0)
    assert res.step == 0 and res.hold_step == 0
    res = s.run(150)
    assert res.hold_step == 150
    assert [_ns(m) for m in s.states] == [EPOCH_NS + k * 10_000_000 for k in range(151)]
    assert s.states[-1].velocity[6] == pytest.approx(0.4 * math.cos(0.03 * 149), abs=0.05)


def test_the_motion_is_the_same_however_fast_it_runs(stepper):
    """As fast as the answers come, and paced at 2x real time: the same joint states, bit for bit."""
    runs = []
    for rtf in (0.0, 2.0):
        s = stepper(command=_sweep, real_time_factor=rtf)
        assert s.wait(lambda s=s: s.states)
        s.run(0)
        t0 = time.monotonic()
        s.run(100)
        runs.append(([list(m.position) for m in s.states], time.monotonic() - t0))
    assert runs[0][0] == runs[1][0]
    assert runs[1][1] >= 0.5 * 100 * 0.01 / 2.0            # paced: it did wait (a lower bound only)


def test_a_participant_that_never_answers_is_a_reported_hang(stepper):
    s = stepper(lockstep_participants=["probe", "ghost"], lockstep_timeout=0.3)
    assert s.wait(lambda: any(m.hung for m in s.lockstep))
    hang = next(m for m in s.lockstep if m.hung)
    assert hang.step == 0 and list(hang.waiting_for) == ["ghost"] and "ghost" in hang.text
    assert all(_ns(m) == EPOCH_NS for m in s.states)        # nothing moved on without it


def test_a_command_comes_through_the_safety_filter(stepper):
    """An implausible command in an answer is rejected like one on joint_velocity_cmd."""
    s = stepper(command=lambda k: [0.0] * 6 + [50.0])
    assert s.wait(lambda: s.states)
    s.run(20)
    assert np.abs(np.array(s.states[-1].velocity[:7])).max() < 1e-9
    assert s.wait(lambda: any(m.code == SafetyStatus.IMPLAUSIBLE_COMMAND for m in s.safety))


@pytest.mark.parametrize("params, needle", [
    ({"backend": "ros2_control"}, "keeps real time"),
    ({"lockstep_participants": []}, "lockstep_participants"),
    ({"lockstep_participants": ["a", "a"]}, "lockstep_participants"),
])
def test_lockstep_is_refused_where_it_cannot_work(params, needle):
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        overrides = {"lockstep": True, "camera_rate": 0.0, **params}
        with pytest.raises(ConfigError, match=needle):
            PandaBridge(context=ctx,
                        parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    finally:
        end_context(ctx)

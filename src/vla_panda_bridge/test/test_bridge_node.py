"""The bridge node with the MuJoCo backend, in-process (private rclpy Context and executor).

Small cameras and real_time_factor > 1 keep it quick; the node steps physics and the safety filter
at 1 kHz either way. The simulation runs at whatever pace the machine gives it (0.1x real time on a
loaded one), so every wait here is for a simulated event (a state, a stamp, a status) with a wall
bound only against a hang (HANG_S), and a held stick is a command on every few joint states, not on a
wall-clock timer (Harness.stream).
"""
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from require import missing
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from vla_common.robot import READY_POSE
from vla_common.ros.context import end_context
from vla_common.ros.qos import IMAGE_QOS
from vla_launch.run import RunError, find_executable
from vla_panda_bridge.bridge_node import ConfigError, PandaBridge
from vla_sim.sim import PandaSim

from vla_interfaces.msg import SafetyStatus, SceneObject, SceneObjectArray
from vla_interfaces.srv import ResetScene

pytestmark = pytest.mark.ros
HANG_S = 120.0   # wall s: the bound on any wait for the simulation, only against a hang
STREAM_EVERY = 4  # a held stick: a command on every 4th joint state (20 ms of simulated time at 200 Hz)


class Harness:
    """A private ROS context with the bridge and a probe node on one executor."""

    def __init__(self, **params):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        defaults = {"camera_rate": 0.0, "real_time_factor": 2.0, "scene_rate": 10.0}
        defaults.update(params)
        self.bridge = PandaBridge(context=self.ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in defaults.items()])
        self.probe = rclpy.create_node("probe", context=self.ctx)
        self.executor.add_node(self.bridge)
        self.executor.add_node(self.probe)
        self.states: list[JointState] = []
        self.status: list[SafetyStatus] = []
        self.scenes: list[SceneObjectArray] = []
        self.clock: list[Clock] = []
        self._stream = None
        self.probe.create_subscription(JointState, "joint_states", self._on_state, 200)
        self.probe.create_subscription(SafetyStatus, "panda_bridge/status", self.status.append, 50)
        self.probe.create_subscription(SceneObjectArray, "scene/objects", self.scenes.append, 10)
        self.probe.create_subscription(Clock, "/clock", self.clock.append, 10)
        self.cmd_pub = self.probe.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
        self.wait(lambda: self.cmd_pub.get_subscription_count() > 0 and self.states, 10.0)

    def _on_state(self, msg: JointState) -> None:
        self.states.append(msg)
        if self._stream is not None and len(self.states) % STREAM_EVERY == 0:
            self.command(self._stream())

    def stream(self, values) -> None:
        """Hold the stick: the command `values()` on every STREAM_EVERY-th joint state (simulated time)."""
        self._stream = values

    def wait(self, pred, timeout: float = HANG_S) -> bool:
        """Spin until `pred()` (a simulated event); `timeout` wall s, never less than HANG_S."""
        end = time.monotonic() + max(timeout, HANG_S)
        while time.monotonic() < end:
            if pred():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return bool(pred())

    def run_for(self, seconds: float) -> None:
        """Let `seconds` of simulated time pass (joint states stamped that much later)."""
        t0 = _stamp(self.states[-1])
        assert self.wait(lambda: _stamp(self.states[-1]) >= t0 + seconds)

    def command(self, values) -> None:
        self.cmd_pub.publish(Float64MultiArray(data=[float(v) for v in values]))

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        client = self.probe.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=5.0)
        future = client.call_async(request)
        assert self.wait(future.done, timeout), f"{name} did not answer"
        return future.result()

    def close(self) -> None:
        self.bridge.destroy_node()
        self.probe.destroy_node()
        self.executor.shutdown()
        end_context(self.ctx)


@pytest.fixture
def harness(request):
    created = []

    def make(**params):
        h = Harness(**params)
        created.append(h)
        return h

    yield make
    for h in created:
        h.close()


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def test_constant_command_moves_joints_as_integrated(harness):
    """Tolerance: after the jerk-limited ramp (< 0.05 s at these speeds) the measured motion over 0.5 s
    of simulated time equals cmd * 0.5 s within 2e-3 rad per joint, and joint_states velocity equals
    the command within 0.02 rad/s (servo tracking error)."""
    h = harness(real_time_factor=0.0, command_timeout=1.0)   # as fast as possible; commands every 20 ms wall
    cmd = np.array([0.2, -0.1, 0.15, 0.1, -0.2, 0.2, 0.3])
    h.command(cmd)
    h.stream(lambda: cmd)  # keep the watchdog fed
    t_cmd = _stamp(h.states[-1])
    window = []

    def collect():
        window[:] = [s for s in h.states if _stamp(s) > t_cmd + 0.2]
        return window and _stamp(window[-1]) - _stamp(window[0]) >= 0.5

    assert h.wait(collect, 30.0)
    first = window[0]
    last = next(s for s in window if _stamp(s) - _stamp(first) >= 0.5 - 1e-6)
    dt = _stamp(last) - _stamp(first)
    moved = np.array(last.position[:7]) - np.array(first.position[:7])
    np.testing.assert_allclose(moved, cmd * dt, atol=2e-3)
    np.testing.assert_allclose(last.velocity[:7], cmd, atol=0.02)
    assert list(last.name) == [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1",
                                                                           "panda_finger_joint2"]
    assert len(last.effort) == 9
    # joint_states at 200 Hz of simulated time, stamped with the simulation clock that /clock publishes.
    # (A loaded machine may drop a message in transport; the stamps stay on the 5 ms grid.)
    steps = np.diff([_stamp(s) for s in window]) / 0.005
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)
    assert np.all(np.round(steps) >= 1) and np.mean(np.round(steps) == 1) > 0.8
    assert h.clock and _stamp_clock(h.clock[-1]) >= _stamp(window[-1]) - 1e-9


def _stamp_clock(msg: Clock) -> float:
    return msg.clock.sec + msg.clock.nanosec * 1e-9


def test_command_stream_stops_by_watchdog_and_bad_commands_are_reported(harness):
    h = harness(real_time_factor=2.0, command_timeout=0.1)
    h.command([0.3] * 7)
    assert h.wait(lambda: abs(h.states[-1].velocity[0]) > 0.25, 5.0)
    # No more commands: braked to rest (status COMMAND_TIMEOUT on the way).
    assert h.wait(lambda: max(abs(v) for v in h.states[-1].velocity) < 1e-3, 5.0)
    assert any(s.code == SafetyStatus.COMMAND_TIMEOUT for s in h.status)
    h.command([float("nan")] * 7)
    h.command([0.1] * 3)
    assert h.wait(lambda: h.status and h.status[-1].commands_rejected >= 2, 5.0)
    codes = {s.code for s in h.status}
    assert {SafetyStatus.NON_FINITE_COMMAND, SafetyStatus.WRONG_LENGTH} <= codes
    assert h.status[-1].last_intervention in (SafetyStatus.NON_FINITE_COMMAND, SafetyStatus.WRONG_LENGTH)


def test_estop_latches_until_released(harness):
    h = harness(real_time_factor=2.0, command_timeout=1.0)
    cmd = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4]
    h.command(cmd)
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.35, 5.0)
    res = h.call(SetBool, "panda_bridge/estop", SetBool.Request(data=True))
    assert res.success and "latched" in res.message
    assert h.wait(lambda: abs(h.states[-1].velocity[6]) < 1e-3, 5.0)
    q_stop = h.states[-1].position[6]
    for _ in range(10):                                  # commands are ignored while latched
        h.command(cmd)
        h.run_for(0.04)
    assert abs(h.states[-1].position[6] - q_stop) < 1e-3
    assert h.status[-1].estop_active and h.status[-1].code == SafetyStatus.ESTOP
    res = h.call(SetBool, "panda_bridge/estop", SetBool.Request(data=False))
    assert res.success
    h.run_for(0.2)
    assert abs(h.states[-1].position[6] - q_stop) < 1e-3   # release alone does not move it
    h.command(cmd)                                       # nor the stick still held: a zero first
    h.run_for(0.4)
    assert abs(h.states[-1].position[6] - q_stop) < 1e-3
    assert h.status[-1].code == SafetyStatus.AWAITING_ZERO and not h.status[-1].estop_active
    h.command([0.0] * 7)
    h.command(cmd)
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.35, 5.0)


def test_estop_release_with_the_stick_held_starts_no_motion(harness):
    """The stick stays held (a command every 20 ms) through latch and release: nothing moves until the
    stream has passed through zero."""
    h = harness(real_time_factor=2.0, command_timeout=0.2)
    stream = {"cmd": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4]}
    h.stream(lambda: stream["cmd"])
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.35, 5.0)
    assert h.call(SetBool, "panda_bridge/estop", SetBool.Request(data=True)).success
    assert h.wait(lambda: abs(h.states[-1].velocity[6]) < 1e-6, 5.0)
    assert h.call(SetBool, "panda_bridge/estop", SetBool.Request(data=False)).success
    t_release = _stamp(h.states[-1])
    q_stop = h.states[-1].position[6]
    assert h.wait(lambda: _stamp(h.states[-1]) > t_release + 1.0, 5.0)    # 1 s of simulated time
    assert max(abs(s.velocity[6]) for s in h.states if _stamp(s) > t_release) < 1e-9
    assert abs(h.states[-1].position[6] - q_stop) < 1e-6
    assert h.status[-1].code == SafetyStatus.AWAITING_ZERO
    stream["cmd"] = [0.0] * 7                            # the stick passes through zero ...
    n = len(h.states)
    assert h.wait(lambda: len(h.states) > n + 10, 5.0)
    stream["cmd"] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4]  # ... and moves again
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.35, 5.0)


def test_a_reflex_holds_the_arm_until_recover_and_recovery_needs_a_zero_command(harness):
    """Full speed into the table: the simulated Panda stops itself with a libfranka-like reflex; the
    stream (still held) moves nothing, neither after ~/recover until the stick passes through zero."""
    # the workspace floor off: with it the hand slows to a stop above the table (test_workspace.py)
    h = harness(real_time_factor=4.0, command_timeout=0.2, workspace_floor=-2.0)
    q0 = list(READY_POSE)
    q0[3] = -1.2
    assert h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(initial_positions=q0)).success
    down = [0.0, 2.175, 0.0, 0.0, 0.0, 0.0, 0.0]
    stream = {"cmd": down}
    h.stream(lambda: stream["cmd"])
    assert h.wait(lambda: any(s.code == SafetyStatus.REFLEX for s in h.status), 20.0)
    reflex = next(s for s in h.status if s.code == SafetyStatus.REFLEX)
    assert "joint_reflex" in reflex.text or "violation" in reflex.text, reflex.text
    stream["cmd"] = [0.0, -0.3, 0.0, 0.0, 0.0, 0.0, 0.0]      # back up: ignored while held
    t_reflex = _stamp(reflex)
    assert h.wait(lambda: _stamp(h.states[-1]) > t_reflex + 1.5, 10.0)   # it bounced off the table
    # held: it comes to rest (the hold servo damps the bounce) however the machine's load paced it
    assert h.wait(lambda: np.abs(h.states[-1].velocity).max() < 1e-3, 20.0), _recent(h)
    t0 = _stamp(h.states[-1])
    q_held = np.array(h.states[-1].position[:7])
    assert h.wait(lambda: _stamp(h.states[-1]) > t0 + 0.5, 5.0)
    assert np.abs(np.array(h.states[-1].position[:7]) - q_held).max() < 2e-3, _recent(h)
    assert h.status[-1].code == SafetyStatus.REFLEX, _recent(h)
    assert h.status[-1].last_intervention == SafetyStatus.REFLEX
    res = h.call(Trigger, "panda_bridge/recover", Trigger.Request())
    assert res.success and "recovered from" in res.message and "zero" in res.message
    t0 = _stamp(h.states[-1])
    assert h.wait(lambda: _stamp(h.states[-1]) > t0 + 0.5, 5.0)
    assert np.abs(np.array(h.states[-1].position[:7]) - q_held).max() < 2e-3, _recent(h)   # starts nothing
    assert h.status[-1].code == SafetyStatus.AWAITING_ZERO, _recent(h)
    stream["cmd"] = [0.0] * 7
    n = len(h.states)
    assert h.wait(lambda: len(h.states) > n + 10, 5.0)
    stream["cmd"] = [0.0, -0.3, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert h.wait(lambda: h.states[-1].velocity[1] < -0.25, 5.0), _recent(h)
    # Issue 20 item 4: ~/recover while moving without a reflex is a stop too: the arm brakes, the
    # status says it waits for a zero command, and the held stick does not restart it.
    again = h.call(Trigger, "panda_bridge/recover", Trigger.Request())
    assert again.success and "no reflex" in again.message and "zero" in again.message
    assert h.wait(lambda: h.status[-1].code == SafetyStatus.AWAITING_ZERO and "zero" in h.status[-1].text,
                  5.0), _recent(h)
    assert h.wait(lambda: abs(h.states[-1].velocity[1]) < 1e-3, 5.0), _recent(h)
    t0 = _stamp(h.states[-1])
    assert h.wait(lambda: _stamp(h.states[-1]) > t0 + 0.5, 5.0)
    assert abs(h.states[-1].velocity[1]) < 1e-3 and h.status[-1].code == SafetyStatus.AWAITING_ZERO


def _travel_after(h, t_from: float, seconds: float) -> float:
    """Largest distance (m) of the hand, in the joint_states stamped from t_from (simulated time; the
    subscriber may lag the simulation) for `seconds`, from where it was at t_from."""
    assert h.wait(lambda: _stamp(h.states[-1]) > t_from + seconds, 10.0)
    window = [s for s in h.states if t_from <= _stamp(s) <= t_from + seconds]
    hand = [np.array(h.bridge._fk(np.array(s.position[:7]))[0]) for s in window]
    return max(float(np.linalg.norm(p - hand[0])) for p in hand)


def test_teaching_mode_follows_a_pushed_hand_records_it_and_leaves_holding_the_pose(harness, tmp_path):
    """~/set_teaching: servos off, the arm follows a force on the hand (xfrc_applied), commands are
    ignored, joint_states keep flowing at full rate (recorded to a bag with the recorder's BagWriter);
    entering and leaving move the hand by at most 1 mm; motion afterwards needs a zero command."""
    from rclpy.serialization import serialize_message
    from rosbags.highlevel import AnyReader
    from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo

    h = harness(real_time_factor=2.0, command_timeout=0.2)
    bag = BagWriter(tmp_path / "teaching", EpisodeInfo(task="teaching/demo")).open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    recording = {"on": False}

    def record(msg: JointState) -> None:
        if recording["on"]:
            bag.write("/joint_states", _stamp_ns(msg), serialize_message(msg))

    h.probe.create_subscription(JointState, "joint_states", record, 1000)
    sim = h.bridge.backend.sim

    def now() -> float:                                  # the simulation's clock, as in the stamps
        return h.bridge.backend.now_ns() * 1e-9

    recording["on"] = True
    t_on = now()
    res = h.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=True))
    assert res.success and "teaching" in res.message, res.message
    assert _travel_after(h, t_on, 0.5) <= 1e-3           # entering moves nothing
    assert h.status[-1].code == SafetyStatus.TEACHING
    hand = sim.model.body("panda_hand").id
    q0 = sim.q
    stream = {"cmd": [0.3] * 7}
    h.stream(lambda: stream["cmd"])                   # ignored while teaching
    sim.data.xfrc_applied[hand, :3] = [0.0, 8.0, 0.0]    # a hand pulls sideways ...
    t_push = now()
    assert h.wait(lambda: now() > t_push + 0.4, 10.0)
    sim.data.xfrc_applied[hand, :3] = 0.0                # ... and lets go
    moved = sim.q - q0
    assert abs(moved[0]) > 0.02, moved                   # joint 1 followed the push
    assert h.bridge.filter.code == SafetyStatus.TEACHING and h.bridge.backend.fault == ""
    assert h.wait(lambda: np.abs(sim.dq).max() < 2e-3, 20.0)    # the damping stops it
    stream["cmd"] = [0.0] * 7
    t_off = now()
    res = h.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=False))
    assert res.success and "holding" in res.message, res.message
    assert _travel_after(h, t_off, 0.5) <= 1e-3          # leaving moves nothing either
    recording["on"] = False
    stream["cmd"] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3]  # zeros went out: velocity control again
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.25, 5.0)
    path = bag.close()
    with AnyReader([path]) as reader:
        stamps = [t for _, t, _ in reader.messages()]
        last = reader.deserialize(list(reader.messages())[-1][2], "sensor_msgs/msg/JointState")
    assert len(stamps) > 150 and list(last.name)[0] == "panda_joint1"
    steps = np.diff(stamps) / 5e6                          # 200 Hz of simulated time, none missing
    assert np.all(np.round(steps) == 1), np.unique(np.round(steps))


def test_teaching_mode_is_refused_while_moving_and_reset_is_refused_while_teaching(harness):
    h = harness(real_time_factor=2.0, command_timeout=1.0)
    h.command([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4])
    assert h.wait(lambda: h.states[-1].velocity[6] > 0.35, 5.0)
    res = h.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=True))
    assert not res.success and "moving" in res.message
    h.command([0.0] * 7)
    assert h.wait(lambda: h.bridge.filter.is_stopped, 5.0)
    assert h.call(SetBool, "panda_bridge/set_teaching", SetBool.Request(data=True)).success
    res = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(seed=1, use_seed=True))
    assert not res.success and "teaching" in res.message
    assert h.call(SetBool, "panda_bridge/estop", SetBool.Request(data=True)).success   # e-stop: servos on
    assert not h.bridge.backend.sim.teaching and not h.bridge.filter.teaching


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _recent(h) -> list:
    """The last status codes and texts (for a failure message)."""
    return [(s.code, s.text) for s in h.status[-6:]]


def _layout(objs):
    return [(o.class_id, round(o.x, 9), round(o.y, 9), round(o.yaw, 9)) for o in objs]


def _same_scene(a, b, tol: float = 1e-3) -> bool:
    """Same classes at the same poses (objects at rest still settle by ~1e-8 m)."""
    return ([o.class_id for o in a] == [o.class_id for o in b]
            and all(abs(p.x - q.x) < tol and abs(p.y - q.y) < tol and abs(p.yaw - q.yaw) < tol
                    for p, q in zip(a, b)))


def test_reset_with_the_same_seed_reproduces_the_layout(harness):
    h = harness(real_time_factor=4.0)
    req = ResetScene.Request(seed=7, use_seed=True)
    first = h.call(ResetScene, "panda_bridge/reset", req)
    assert first.success, first.message
    assert h.wait(lambda: h.scenes and _layout(h.scenes[-1].objects) == _layout(first.objects), 5.0)
    other = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(seed=8, use_seed=True))
    assert _layout(other.objects) != _layout(first.objects)
    again = h.call(ResetScene, "panda_bridge/reset", req)
    assert _layout(again.objects) == _layout(first.objects) and len(first.objects) >= 1
    assert h.scenes[-1].header.frame_id == "panda_link0"
    # Explicit layout and initial joint positions.
    q0 = list(READY_POSE + 0.1)
    res = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(
        objects=[SceneObject(class_id="soda_can", x=0.5, y=0.1, yaw=0.3)], initial_positions=q0))
    assert res.success, res.message
    assert [o.class_id for o in res.objects] == ["soda_can"]
    assert res.objects[0].x == pytest.approx(0.5, abs=1e-6) and res.objects[0].pose.position.z > 0
    assert h.wait(lambda: np.allclose(h.states[-1].position[:7], q0, atol=2e-3), 5.0)


@pytest.mark.parametrize("objects,q0,why", [
    ([SceneObject(class_id="pizza", x=0.5, y=0.0)], [], "pizza"),
    ([SceneObject(class_id="bread", x=float("nan"), y=0.0)], [], "bread"),
    ([SceneObject(class_id="bread", x=0.5, y=0.0), SceneObject(class_id="bread", x=0.6, y=0.2)], [], "bread"),
    ([SceneObject(class_id="bread", x=0.5, y=0.0), SceneObject(class_id="soda_can", x=0.5, y=0.0)], [], ""),
    ([SceneObject(class_id="bread", x=5.0, y=0.0)], [], ""),
    ([], [0.0, 0.1], "q0"),
    ([], [0.0, 1.4, 0.0, -1.0, 0.0, 1.5708, 0.7854], "collision: panda_link6 with table_top"),
    ([], [0.959, -0.236, 0.861, -3.05, 0.907, 0.645, -0.47], "panda_link2 with panda_link7"),
])
def test_bad_reset_is_refused_with_a_clear_error_and_the_scene_unchanged(harness, objects, q0, why):
    h = harness(real_time_factor=4.0)
    before = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(seed=3, use_seed=True))
    q_before = np.array(h.states[-1].position[:7])
    res = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(objects=objects, initial_positions=q0))
    assert not res.success
    assert "scene unchanged" in res.message and why in res.message
    assert _same_scene(res.objects, before.objects)
    n = len(h.scenes)
    assert h.wait(lambda: len(h.scenes) > n, 5.0)
    assert _same_scene(h.scenes[-1].objects, before.objects)
    np.testing.assert_allclose(h.states[-1].position[:7], q_before, atol=1e-3)


def test_camera_publishes_the_configured_size_and_encoding(harness):
    h = harness(camera_rate=30.0, camera_width=96, camera_height=64, real_time_factor=1.0)
    images, infos = [], []
    h.probe.create_subscription(Image, "camera/image_raw", images.append, IMAGE_QOS)
    h.probe.create_subscription(CameraInfo, "camera/camera_info", infos.append, IMAGE_QOS)
    assert h.wait(lambda: len(images) >= 3 and infos, 20.0)
    img, info = images[-1], infos[-1]
    assert (img.width, img.height, img.encoding, img.step) == (96, 64, "rgb8", 96 * 3)
    assert len(img.data) == 96 * 64 * 3
    pixels = np.frombuffer(bytes(img.data), np.uint8).reshape(64, 96, 3)
    assert pixels.std() > 5                              # a rendered scene, not a blank buffer
    assert (info.width, info.height) == (96, 64)
    assert img.header.frame_id == info.header.frame_id == "camera_optical_frame"
    fx, cx, fy, cy = info.k[0], info.k[2], info.k[4], info.k[5]
    assert fx == pytest.approx(fy) and cx == pytest.approx(47.5) and cy == pytest.approx(31.5)
    expected = PandaSim(camera_width=96, camera_height=64, render=False).camera_intrinsics()
    assert (fx, fy, cx, cy) == pytest.approx(expected, rel=1e-9)       # the rendered camera's intrinsics
    stamps = [_stamp(i) for i in images]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_bad_parameters_are_refused_in_process():
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        for name, value, needle in [("state_rate", 5000.0, "state_rate"), ("backend", "gazebo", "backend"),
                                    ("initial_positions", [0.0, 1.0], "initial_positions"),
                                    ("initial_positions", [0.0, 1.4, 0.0, -1.0, 0.0, 1.5708, 0.7854],
                                     "initial_positions.*collision"),
                                    ("plausibility_factor", 0.5, "plausibility_factor"),
                                    ("robot_model", "fr3", "robot_model.*Panda"),
                                    ("robot_model", "ur5", "robot_model"),
                                    ("teaching_damping", [1.0, -1.0] + [1.0] * 5, "teaching_damping"),
                                    ("upper_torque_thresholds", [20.0] * 6 + [0.0], "upper_torque"),
                                    ("camera_width", 4, "camera_width"),
                                    ("real_time_factor", -1.0, "real_time_factor"),
                                    ("ee_frame", "elbow", "ee_frame")]:
            with pytest.raises(ConfigError, match=needle):
                PandaBridge(context=ctx, parameter_overrides=[Parameter(name, value=value)])
    finally:
        end_context(ctx)


def test_integer_value_for_a_rate_is_accepted(harness):
    h = harness(state_rate=500, real_time_factor=1.0)
    assert h.bridge.params["state_rate"] == 500.0


def _installed(exe: str) -> str:
    try:
        return find_executable("vla_panda_bridge", exe)
    except RunError as err:
        missing("SETUP", f"{exe}: {err} (run make setup)")


@pytest.mark.slow
def test_installed_executable_exits_nonzero_with_a_message_on_a_bad_parameter():
    out = subprocess.run([sys.executable, _installed("panda_bridge"), "--ros-args", "-p", "state_rate:=0.0"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "state_rate" in out.stderr and "range" in out.stderr


@pytest.mark.parametrize("backend,signals", [
    ("mujoco", (signal.SIGINT,)),
    pytest.param("ros2_control", (signal.SIGTERM,), marks=pytest.mark.slow),
    pytest.param("mujoco", (signal.SIGINT, signal.SIGINT), marks=pytest.mark.slow),
])
def test_the_bridge_stops_within_2_s_of_a_signal_with_use_sim_time_and_no_clock(tmp_path, backend, signals):
    """use_sim_time:=true and nobody else publishing /clock: timers on the node clock never fire, yet
    a signal stops the node within 2 s, exit code 0, and a second signal during cleanup prints no
    traceback."""
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, _installed("panda_bridge"), "--ros-args",
                                 "-p", "use_sim_time:=true", "-p", f"backend:={backend}",
                                 "-p", "camera_rate:=0.0"], stdout=subprocess.DEVNULL, stderr=err)
    try:
        end = time.monotonic() + 60.0
        while f"{backend}" not in log.read_text() or "Hz" not in log.read_text():
            assert proc.poll() is None and time.monotonic() < end, log.read_text()
            time.sleep(0.05)
        time.sleep(0.5)
        t0 = time.monotonic()
        for sig in signals:
            proc.send_signal(sig)
            time.sleep(0.05)
        rc = proc.wait(timeout=10.0)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text()
    # The rule's 2 s: 4.3x the 0.32-0.47 s measured at load 1.7 (2026-12-03).
    assert rc == 0 and took < 2.0, (rc, took, text)
    assert "Traceback" not in text, text


def _bringup_yaml() -> str:
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.normpath(os.path.join(here, "..", "..", "vla_bringup", "config", "panda_bridge.yaml"))


def test_the_shipped_parameter_file_names_every_parameter_and_starts_the_node():
    import yaml
    from vla_panda_bridge.bridge_node import PARAMETERS

    path = _bringup_yaml()
    with open(path) as f:
        values = yaml.safe_load(f)["/**"]["ros__parameters"]
    assert set(values) == {p.name for p in PARAMETERS}
    for name, value in values.items():                    # the file restates the defaults
        assert value == pytest.approx(PARAMETERS.params[name].default), name
    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", path, "-p", "camera_rate:=0.0"])
    try:
        node = PandaBridge(context=ctx)
        assert node.params["state_rate"] == 200.0 and node.params["backend"] == "mujoco"
        node.destroy_node()
    finally:
        end_context(ctx)


def test_the_readme_documents_every_parameter_and_service():
    from vla_panda_bridge.bridge_node import PARAMETERS

    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "..", "README.md")) as f:
        text = f.read()
    params = text[text.index("| Parameter | Default |"):text.index("## Backends")]
    missing = [p.name for p in PARAMETERS if f"`{p.name}`" not in params]
    assert not missing, missing
    services = text[text.index("| Service | Type |"):text.index("**Parameters**")]
    for name in ("~/estop", "~/recover", "~/set_teaching", "~/reset"):
        assert f"| `{name}` |" in services, name


def test_pacer_advances_one_state_period_per_tick_despite_jitter_and_slips_when_behind():
    from vla_sim.sim_clock import SimPacer

    pacer = SimPacer(unit=0.005, real_time_factor=1.0)
    assert pacer.timer_period() == pytest.approx(0.005)
    pacer.start(100.0, 0.0)
    rng = np.random.default_rng(0)
    sim = 0.0
    for k in range(1, 400):                               # ticks late or early by up to 40 % of a period
        units = pacer.units_due(100.0 + k * 0.005 + rng.uniform(-0.002, 0.002), sim)
        assert units == 1
        sim += units * 0.005
    # A stall of 50 ms catches up in bounded bursts; one of 1 s re-anchors instead.
    assert pacer.units_due(100.0 + 400 * 0.005 + 0.05, sim) == pacer.max_burst == 3
    assert pacer.units_due(100.0 + 400 * 0.005 + 1.0, sim) == 1 and pacer.lag_events == 1
    fast = SimPacer(unit=0.005, real_time_factor=4.0)
    assert fast.timer_period() == pytest.approx(0.00125)
    turbo = SimPacer(unit=0.001, real_time_factor=10.0)    # 0.1 ms ticks would be too short: 1 ms, 10 units
    assert turbo.timer_period() == pytest.approx(0.001) and turbo.max_burst == 21
    asap = SimPacer(unit=0.005, real_time_factor=0.0)
    assert asap.timer_period() == 0.0 and asap.units_due(0.0, 123.0) == 2
    with pytest.raises(ValueError):
        SimPacer(unit=0.005, real_time_factor=-1.0)


@pytest.mark.slow
def test_scripted_push_through_joint_velocity_cmd_moves_the_object(harness):
    """Pinocchio IK plan from the object's pose (vla_sim.planner), executed by a client that
    turns each joint state into a joint_velocity_cmd: the object moves >= 5 cm within 30 deg."""
    from vla_common.kinematics import PandaKinematics
    from vla_common.objects import ObjectPose
    from vla_common.tasks import TASKS, task_layout
    from vla_sim.planner import plan_task

    h = harness(real_time_factor=2.0, scene_rate=20.0)
    task = TASKS["soda_can/push_south"]
    rng = np.random.default_rng(5)
    layout = task_layout(task, rng, n_objects=1)
    res = h.call(ResetScene, "panda_bridge/reset", ResetScene.Request(
        objects=[SceneObject(class_id=o.class_id, x=o.x, y=o.y, yaw=o.yaw) for o in layout]))
    assert res.success, res.message
    start = res.objects[0]
    n = len(h.states)
    assert h.wait(lambda: len(h.states) > n + 2, 10.0)
    q_start = np.array(h.states[-1].position[:7])
    plan = plan_task(PandaKinematics(), task, ObjectPose(start.class_id, start.x, start.y, start.yaw),
                     q_start, rng)
    t0 = _stamp(h.states[-1])
    done = []

    def on_state(msg: JointState) -> None:
        t = _stamp(msg) - t0
        h.command(plan.command(t, np.array(msg.position[:7])))
        if t > plan.duration + 0.5:
            done.append(True)

    h.probe.create_subscription(JointState, "joint_states", on_state, 10)
    assert h.wait(lambda: bool(done), 120.0)
    n = len(h.scenes)
    assert h.wait(lambda: len(h.scenes) > n, 5.0)
    end = h.scenes[-1].objects[0]
    delta = np.array([end.x - start.x, end.y - start.y])
    moved = float(np.linalg.norm(delta))
    angle = math.degrees(math.acos(np.clip(delta @ task.direction_vector / max(moved, 1e-9), -1, 1)))
    assert moved >= 0.05 and angle <= 30.0, (moved, angle)


def test_the_scene_holds_the_objects_of_a_given_catalogue(tmp_path):
    """A lab's catalogue (a sixth object, no code change) reaches the scene; a bad one is refused."""
    spam = Path(__file__).resolve().parents[3] / "test" / "data" / "spam_catalogue.yaml"
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = PandaBridge(context=ctx, parameter_overrides=[
            Parameter("catalogue", value=str(spam)), Parameter("camera_rate", value=0.0)])
        try:
            assert "spam" in node.backend.sim.catalogue.classes
            layout = node.backend.sim.reset(objects=[("spam", 0.5, 0.0, 0.0)])
            assert [o.class_id for o in layout] == ["spam"]
        finally:
            node.destroy_node()
        bad = tmp_path / "bad.yaml"
        bad.write_text("objects: [\n")
        with pytest.raises(ConfigError, match="catalogue"):
            PandaBridge(context=ctx, parameter_overrides=[Parameter("catalogue", value=str(bad))])
    finally:
        end_context(ctx)

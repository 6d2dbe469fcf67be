"""Must-show: the shipped launch files, started with `vla launch` as a user starts them, move the arm.

- teleop.launch.yaml (bridge, detector, controller) with the joystick replaced by published
  sensor_msgs/Joy: the arm moves the way the controller commands, back when the stick reverses, and
  stops when it is released;
- demo.launch.yaml (the same plus the simulated user): the teleoperator drives the arm towards its
  waypoint.
Both with use_sim_time (the bridge's /clock); the scene is reset to one object through the bridge's
~/reset and the controller latches its detection through ~/redetect, as an operator would. The bridge
must report no e-stop, no rejected command and no other code than OK or its limit shaping.
"""
from __future__ import annotations

import os

import numpy as np
import pytest
from launch_process import LaunchProcess, Observer, cosine, thread_nices, thread_policies
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Joy
from std_srvs.srv import Trigger
from vla_common.kinematics import PandaKinematics
from vla_common.priority import BACKGROUND_NICE, MAX_NICE, thread_nice
from vla_common.robot import READY_POSE
from vla_common.ros.testing import RosHarness
from vla_evaluation.kinematic import plannable_layout

from vla_interfaces.msg import ControllerStatus, SafetyStatus, SceneObject, TeleopStatus
from vla_interfaces.srv import ResetScene, StartEpisode

pytestmark = [pytest.mark.slow, pytest.mark.ros]

TASK = "bread/push_east"
LAYOUT_SEED = 100_000  # a fresh (validation) layout, never a demonstration's
# What the safety layer may report while a sound command moves the arm: nothing, its own shaping, or
# the watchdog braking when the command stream pauses for 0.1 s (on a loaded 2-core machine a
# starved controller process does; braking is the safe answer, not a fault of the graph), and the
# wait for a zero command that follows it (the arming rule: the operator lets go, then moves again).
# CONTACT too: the hand meeting the object it pushes slows the joints pressing into it (contact slowing).
SHAPING = {SafetyStatus.OK, SafetyStatus.VELOCITY_SCALED, SafetyStatus.ACCELERATION_LIMITED,
           SafetyStatus.COMMAND_TIMEOUT, SafetyStatus.AWAITING_ZERO, SafetyStatus.CONTACT}


@pytest.fixture
def ros():
    h = RosHarness(other_processes=True)
    yield h
    h.shutdown()


def reset_to_one_object(h: RosHarness, obs: Observer) -> None:
    """The bridge's ~/reset to a single bread, then the controller latches its detection."""
    objects, *_ = plannable_layout(PandaKinematics(), TASK, "bread", LAYOUT_SEED, np.asarray(READY_POSE), 1)
    reset = obs.create_client(ResetScene, "panda_bridge/reset")
    req = ResetScene.Request(objects=[SceneObject(class_id=o.class_id, x=o.x, y=o.y, yaw=o.yaw)
                                      for o in objects], initial_positions=[float(v) for v in READY_POSE])
    assert h.call(reset, req, 60.0).success
    sim_seconds(h, obs, 1.0)  # objects settle and the detector sees the new scene
    redetect = obs.create_client(Trigger, "controller_node/redetect")
    assert h.call(redetect, Trigger.Request(), 30.0).success
    assert h.spin_until(lambda: obs.ctrl is not None and obs.ctrl.latched_class == "bread", 30.0), obs.ctrl


def check_safety(obs: Observer) -> None:
    codes = {int(s.code) for s in obs.safety}
    assert obs.safety, "no status from the bridge"
    assert codes <= SHAPING, codes
    assert not any(s.estop_active for s in obs.safety)
    assert obs.safety[-1].commands_rejected == 0


def sim_seconds(h: RosHarness, obs: Observer, seconds: float, step=None, bound: float = 120.0) -> None:
    """Spin until `seconds` of simulated time have passed by the joint states' stamps, calling `step`
    every 20 ms of wall time: a loaded machine runs the simulation slower than real time (CI: a 2 s
    push in wall time gave the arm 0.05 rad). `bound`: wall seconds, only against a hang."""
    start = obs.stamp

    def done() -> bool:
        if step is not None:
            step()
        h.spin_for(0.02)
        return obs.stamp - start >= seconds

    assert h.spin_until(done, bound), f"{seconds} s of simulated time did not pass in {bound} s"


def hold_stick(h: RosHarness, obs: Observer, pub, value: float,
               seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The stick at neutral until the arm has braked, then at `value` (50 Hz) for `seconds` of
    simulated time; (the arm's motion, the mean command while ACTIVE)."""
    def neutral() -> None:
        pub.publish(Joy(axes=[0.0, 0.0], buttons=[0] * 4))

    def at_neutral() -> bool:                    # a person lets the stick go when the controller asks
        neutral()
        h.spin_for(0.02)
        return obs.ctrl is not None and obs.ctrl.code == ControllerStatus.ZERO_DEADBAND

    assert h.spin_until(at_neutral, 10.0), obs.ctrl
    sim_seconds(h, obs, 0.5, neutral)            # the arm brakes from the last push
    first = len(obs.ctrl_log)
    q0 = obs.q.copy()
    sim_seconds(h, obs, seconds, lambda: pub.publish(Joy(axes=[float(value), 0.0], buttons=[0] * 4)))
    commands = [np.array(s.command) for s in obs.ctrl_log[first:]
                if s.code == ControllerStatus.ACTIVE and len(s.command) == 7]
    assert commands, f"the controller never was ACTIVE: {obs.ctrl}"
    return obs.q - q0, np.mean(commands, axis=0)


def push(h: RosHarness, obs: Observer, pub, value: float, tries: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """hold_stick for 2 simulated s; again (from neutral) while a loaded machine's late command stopped
    the arm (the arming rule: motion after that stop needs the operator's neutral), as a person would."""
    for _ in range(tries):
        moved, command = hold_stick(h, obs, pub, value, 2.0)
        if np.linalg.norm(moved) > 0.05:
            break
    return moved, command


def test_teleop_launch_moves_the_arm_the_way_the_stick_commands(ros, tmp_path):
    with LaunchProcess("vla_bringup", "teleop.launch.yaml", "use_sim_time:=true",
                       log_path=tmp_path / "launch.log") as run:
        obs = ros.add(Observer(ros.context))
        joy = obs.create_publisher(Joy, "joy", qos_profile_sensor_data)
        assert ros.spin_until(obs.graph_up, 90.0), run.text()[-3000:]
        # perception yields the CPU to input and control (vla_common.priority): every detector thread
        # runs at background priority, the controller's and the bridge's main threads do not
        base = thread_nice()
        detector = thread_nices("detector_node", run.proc.pid)
        assert set(detector.values()) == {min(MAX_NICE, base + BACKGROUND_NICE)}
        for node in ("controller_node", "panda_bridge"):
            nices = thread_nices(node, run.proc.pid)
            assert nices[min(nices)] == base, (node, nices)   # its first thread: the executor's
        # and the operator's path runs real time only where asked (thread_priority:=N), by default
        # nothing in the graph does
        for node in ("controller_node", "panda_bridge", "detector_node"):
            assert os.SCHED_FIFO not in thread_policies(node, run.proc.pid).values(), node
        reset_to_one_object(ros, obs)
        obs.safety.clear()
        forward, cmd_forward = push(ros, obs, joy, 0.8)
        back, cmd_back = push(ros, obs, joy, -0.8)
        assert np.linalg.norm(forward) > 0.05 and np.linalg.norm(back) > 0.05, (forward, back)
        assert cosine(forward, cmd_forward) > 0.9, (forward, cmd_forward)
        assert cosine(back, cmd_back) > 0.9, (back, cmd_back)
        check_safety(obs)
        sim_seconds(ros, obs, 1.0)  # stick released: joy_timeout, zero command, the arm brakes
        q_rest = obs.q.copy()
        sim_seconds(ros, obs, 1.0)
        assert obs.ctrl.code != ControllerStatus.ACTIVE and np.allclose(obs.q, q_rest, atol=1e-3)
        assert run.stop() == 0, run.text()[-3000:]


def test_demo_launch_teleoperator_drives_towards_its_waypoint(ros, tmp_path):
    with LaunchProcess("vla_evaluation", "demo.launch.yaml", "real_time_factor:=2.0", "camera_rate:=5.0",
                       log_path=tmp_path / "launch.log") as run:
        obs = ros.add(Observer(ros.context))
        assert ros.spin_until(lambda: obs.graph_up() and obs.teleop is not None, 90.0), run.text()[-3000:]
        reset_to_one_object(ros, obs)
        obs.safety.clear()
        start = obs.create_client(StartEpisode, "sim_teleoperator/start_episode")
        assert ros.call(start, StartEpisode.Request(task=TASK)).success
        running = lambda: obs.teleop.state == TeleopStatus.RUNNING and len(obs.teleop.waypoint) == 7  # noqa: E731
        assert ros.spin_until(running, 30.0), obs.teleop
        q0, waypoint = obs.q.copy(), np.array(obs.teleop.waypoint)
        sim_seconds(ros, obs, 6.0)
        moved = obs.q - q0
        assert np.linalg.norm(waypoint - obs.q) < np.linalg.norm(waypoint - q0) - 0.1, (q0, obs.q, waypoint)
        assert cosine(moved, waypoint - q0) > 0.5
        assert any(s.code == ControllerStatus.ACTIVE for s in obs.ctrl_log)
        check_safety(obs)
        assert run.stop() == 0, run.text()[-3000:]

"""The teleop graph on a simulated FR3: controller_node with a shipped (Panda-trained) model, a fixed
detection and joystick messages from the test, and panda_bridge with backend:=libfranka
driver:=pylibfranka against franka-sim in a private network namespace. The stick moves the arm.
Skipped, with the reason, where franka-sim, pylibfranka or network namespaces are missing."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy
from franka_sim_server import running
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, Joy
from vla_common.ros.testing import RosHarness
from vla_common.safety_status import SafetyCode

from vla_interfaces.msg import ControllerStatus, Detection, DetectionArray

pytestmark = [pytest.mark.slow, pytest.mark.ros]
RT_PRIORITY = 50   # franka-sim and the loop under SCHED_FIFO, as on a real-time PC (test_franka_sim_bridge)


@pytest.fixture
def sim():
    with running(priority=RT_PRIORITY) as server:
        yield server


def test_the_stick_moves_the_simulated_fr3_through_the_latent_controller(sim):
    from vla_latent_controller.controller_node import ControllerNode
    from vla_panda_bridge.bridge_node import PARAMETERS, PandaBridge

    h = RosHarness()
    try:
        bridge_params = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
                         "realtime_config": "ignore", "loop_prefix": " ".join(sim.netns.prefix()),
                         "loop_priority": RT_PRIORITY, "control_rate": 250,
                         "gripper": False,                     # the server runs --no-gripper
                         # the FCI's FR3 table (10 rad/s^2, 5000 rad/s^3) inside the Panda's
                         "acceleration_scale": 0.4999, "jerk_scale": 0.4999}
        controller_params = {"joy_timeout": 0.5}        # this test's publisher may lag on a loaded machine
        fr3 = "robot_model" in PARAMETERS.params
        if fr3:
            bridge_params["robot_model"] = "fr3"
            controller_params["joint_map"] = [f"fr3_joint{i}:panda_joint{i}" for i in range(1, 8)]
        def overrides(values: dict) -> list[Parameter]:
            return [Parameter(k, value=v) for k, v in values.items()]
        bridge = h.add(PandaBridge(context=h.context, parameter_overrides=overrides(bridge_params)))
        h.add(ControllerNode(context=h.context, parameter_overrides=overrides(controller_params)))
        io = h.add(rclpy.create_node("teleop_test_io", context=h.context))
        states: list[JointState] = []
        status: list[ControllerStatus] = []
        io.create_subscription(JointState, "joint_states", states.append, 2000)
        io.create_subscription(ControllerStatus, "controller_node/status", status.append, 100)
        joy = io.create_publisher(Joy, "joy", 10)
        det = io.create_publisher(DetectionArray, "detections", 10)
        assert h.spin_until(lambda: bridge.backend.status.code == 0 and bool(states), 20.0)
        assert states[-1].name[0] == ("fr3_joint1" if fr3 else "panda_joint1")

        def stopped() -> bool:
            """A stop the graph reports (a watchdog on a loaded machine, say): it waits for neutral."""
            return (bridge.backend.status.filter_code == SafetyCode.AWAITING_ZERO
                    or bool(status) and status[-1].code == ControllerStatus.AWAITING_NEUTRAL)

        def drive(axis: float, seconds: float, until=lambda: False) -> None:
            """Hold the stick at `axis` as an operator does: back to neutral after a stop, then on."""
            end = time.monotonic() + seconds
            while time.monotonic() < end and not until():
                msg = DetectionArray(image_width=640, image_height=480)
                msg.detections = [Detection(class_id="bread", score=0.9, center_x=320.0, center_y=300.0)]
                det.publish(msg)
                joy.publish(Joy(axes=[0.0 if stopped() else axis, 0.0], buttons=[0, 0, 0, 0]))
                h.spin_for(0.02)

        centred = lambda: bool(status) and status[-1].code == ControllerStatus.ZERO_DEADBAND   # noqa: E731
        drive(0.0, 20.0, until=centred)                   # inputs in, stick centred: zero command
        assert status and status[-1].code == ControllerStatus.ZERO_DEADBAND, status[-1:] or "no status"
        q0, n = np.array(states[-1].position), len(status)
        moved = lambda: np.linalg.norm(np.array(states[-1].position) - q0) > 0.05   # noqa: E731
        drive(0.8, 20.0, until=moved)
        assert any(s.code == ControllerStatus.ACTIVE for s in status[n:]), status[-1]
        assert moved(), (np.array(states[-1].position) - q0, bridge.backend.status, status[-1])
        end = time.monotonic() + 5.0                      # stick centred: the arm comes to rest
        while time.monotonic() < end and max(abs(v) for v in states[-1].velocity) >= 0.05:
            drive(0.0, 0.1)
        assert max(abs(v) for v in states[-1].velocity) < 0.05
        assert bridge.backend.status.code == 0 and bridge.backend.status.errors == 0, bridge.backend.status
    finally:
        h.shutdown()

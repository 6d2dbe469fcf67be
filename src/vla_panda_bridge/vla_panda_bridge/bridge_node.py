"""`panda_bridge`: the robot side of the project as one ROS 2 node.

Takes joint-velocity commands on `joint_velocity_cmd` and, once per control period, runs the latest
one through the SafetyFilter against the measured state and writes the result to the backend — one
control path for every backend (backend.py; the table in backends.py). Publishes joint_states,
ee_pose and ~/status; serves ~/estop, ~/recover, ~/set_teaching and ~/reset (the last two where the
backend offers them). The robot model (`robot_model`: Panda or FR3) gives the joint names and the
limit table the filter enforces. A thin wrapper: the algorithms live in safety.py, the backends and
kinematics.py.

A managed (lifecycle) node, as ros2_control and franka_ros2 drivers are: configure connects (makes
the backend), activate starts the loop (first time) and takes commands, deactivate brakes and holds
(the loop goes on, commands are refused, and motion after it needs a zero command), cleanup brakes
and disconnects. `autostart` (default) runs configure and activate at start, so `ros2 run` just works.
"""

from __future__ import annotations

import array
import math
import sys
import time

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from vla_common.robot import PANDA, ROBOTS, robot_spec
from vla_common.ros.convert import quat_wxyz_from_matrix, stamp_from_ns
from vla_common.ros.description import publish_robot_description
from vla_common.ros.diagnostics import Diagnostics
from vla_common.ros.node_main import ConfigError, run_node
from vla_common.ros.parameters import THREAD_PRIORITY, Param, ParameterTable
from vla_common.ros.qos import IMAGE_QOS
from vla_common.safety_status import SafetyCode, code_name

from vla_interfaces.msg import SafetyStatus
from vla_interfaces.srv import ResetScene
from vla_panda_bridge.backend import TEACHING, BackendError, UnsupportedError
from vla_panda_bridge.backends import BACKENDS, reflex_torque
from vla_panda_bridge.gripper_ros import GripperInterface
from vla_panda_bridge.libfranka_driver import DRIVERS, REALTIME, DriverSettings
from vla_panda_bridge.safety import SafetyConfig, SafetyFilter
from vla_panda_bridge.workspace import DEFAULT_FLOOR, WorkspaceFloor, tcp_height

EE_FRAMES = ("tcp", "flange")
MAX_CAMERA_SIZE = (1920, 1440)  # scene.MAX_OFFSCREEN (the offscreen buffer)
STATE_QOS_DEPTH = 2000  # joint_states / ee_pose history (see where the publishers are made)
SHUTDOWN_BRAKE_S = 1.5  # wall-clock bound on braking at shutdown (the node must stop within 2 s)


def _not_empty(value: str) -> str | None:
    return None if value else "must not be empty"


def _seven_finite(value) -> str | None:
    q = np.asarray(value, dtype=float)
    if q.shape != (7,) or not np.all(np.isfinite(q)):
        return f"must be 7 finite joint positions (rad), got {list(value)}"
    return None


def _seven_positive(value) -> str | None:
    t = np.asarray(value, dtype=float)
    if t.shape != (7,) or not np.all(np.isfinite(t)) or not np.all(t > 0.0):
        return f"must be 7 finite torques > 0 (Nm), got {list(value)}"
    return None


PARAMETERS = ParameterTable([
    THREAD_PRIORITY,   # on the operator's path: SCHED_FIFO where allowed (vla_common.priority)
    Param("autostart", True, "Configure and activate at start; false: wait in 'unconfigured' for a "
          "lifecycle manager's transitions (configure connects, activate moves)"),
    Param("backend", "mujoco", "Robot behind the safety layer: " + "; ".join(
          f"'{row.name}' ({row.summary})" for row in BACKENDS.values()), choices=tuple(BACKENDS)),
    Param("robot_model", "panda", "The arm: 'panda' (Franka Emika FER) or 'fr3' (Franka Research 3): joint "
          "names <model>_joint1..7 and the limit table the safety layer enforces", choices=tuple(ROBOTS)),
    Param("control_rate", 1000, "Safety filter + command updates per second; with mujoco also the "
          "physics rate (one filter update per physics step)", range=(100, 4000)),
    Param("state_rate", 200.0, "joint_states and ee_pose publish rate (Hz; simulated time with mujoco)",
          range=(1.0, 1000.0)),
    Param("real_time_factor", 1.0, "mujoco: simulated seconds per wall second; 0 = as fast as possible",
          range=(0.0, 100.0)),
    Param("publish_clock", True, "mujoco: publish /clock so nodes with use_sim_time follow the simulation"),
    Param("lockstep", False, "mujoco: the simulation owns time: it moves one state period at a time, once "
          "every lockstep_participant has answered the current joint state (vla_interfaces/StepAnswer on "
          "lockstep/answer); real_time_factor only delays it (0: as fast as the answers come); the clock "
          "starts at 1 s; ~/lockstep_run, ~/lockstep (README 'Lockstep')"),
    Param("lockstep_participants", ["controller_node"], "mujoco, lockstep: the nodes that answer every "
          "step (their StepAnswer.node)", array="string_array"),
    Param("lockstep_hold", False, "mujoco, lockstep: start held at step 0 (an orchestrator moves it with "
          "~/lockstep_run); false: run freely"),
    Param("lockstep_timeout", 60.0, "mujoco, lockstep: wall seconds a step may wait for its answers before "
          "it is reported as a hang (on ~/lockstep and the log; it is never skipped)", range=(0.1, 3600.0)),
    Param("camera_rate", 30.0, "mujoco: camera/image_raw rate in simulated Hz (0 = camera off)",
          range=(0.0, 120.0)),
    Param("camera_width", 640, "mujoco: image width (px)", range=(16, MAX_CAMERA_SIZE[0])),
    Param("camera_height", 480, "mujoco: image height (px)", range=(16, MAX_CAMERA_SIZE[1])),
    Param("scene_rate", 10.0, "mujoco: scene/objects (ground truth) rate in simulated Hz "
          "(0 = only after a reset)", range=(0.0, 100.0)),
    Param("catalogue", "", "mujoco: object catalogue YAML (vla_common.catalogue) whose objects the scene "
          "holds; empty = the default (the paper's five)"),
    Param("seed", 0, "mujoco: seed of the initial random object layout", range=(0, 2**31 - 1)),
    Param("initial_positions", [float(v) for v in PANDA.ready_pose], "mujoco: initial joint positions "
          "(7, rad): inside the joint limits and free of collisions", check=_seven_finite),
    Param("base_frame_id", "", "frame_id of ee_pose and scene/objects; empty = the robot's base link "
          "(panda_link0, fr3_link0)"),
    Param("ee_frame", "tcp", "ee_pose of the 'tcp' (between the closed finger tips) or the 'flange'",
          choices=EE_FRAMES),
    Param("command_timeout", 0.1, "Watchdog: brake to zero after this long without a valid command (s)",
          range=(0.001, 10.0)),
    Param("workspace_floor", DEFAULT_FLOOR, "Lowest height of the tool centre point in the base frame (m; "
          "the table the robot stands on is z = 0): the hand's descent slows to a stop above it. -2: off "
          "(beyond the arm's reach)", range=(-2.0, 1.0)),
    Param("position_margin", 0.1, "Distance kept from every joint position limit (rad)", range=(0.0, 0.5)),
    Param("velocity_scale", 1.0, "Fraction of the robot's dq_max allowed", range=(0.01, 1.0)),
    Param("acceleration_scale", 1.0, "Fraction of the robot's ddq_max allowed", range=(0.01, 1.0)),
    Param("jerk_scale", 1.0, "Fraction of the robot's dddq_max allowed", range=(0.01, 1.0)),
    Param("position_sync_tolerance", 0.05, "Re-sync the integrated reference to the measured position "
          "beyond this drift (rad)", range=(0.001, 1.0)),
    Param("plausibility_factor", 2.0, "A command beyond this times the joint's dq_max is a fault: "
          "rejected (zero, IMPLAUSIBLE_COMMAND), not scaled", range=(1.0, 100.0)),
    Param("status_rate", 1.0, "~/status rate when nothing happens (Hz); interventions publish at once",
          range=(0.1, 100.0)),
    Param("command_topic", "/joint_velocity_controller/commands",
          "ros2_control: JointGroupVelocityController command topic", check=_not_empty),
    Param("robot_joint_states_topic", "/joint_states", "ros2_control: the arm's sensor_msgs/JointState",
          check=_not_empty),
    Param("state_timeout", 0.25, "ros2_control, libfranka: brake when the arm's joint state is older than "
          "this (s)", range=(0.01, 10.0)),
    Param("robot_ip", "", "libfranka: the robot's FCI address (e.g. 172.16.0.2)"),
    Param("driver", "auto", "libfranka: 'pylibfranka' (FR3, server protocol 10), 'panda_py' (Panda, "
          "protocol 5) or 'auto' (chosen from the robot's answer)", choices=DRIVERS),
    Param("realtime_config", "enforce", "libfranka: 'enforce' needs a real-time kernel; 'ignore' is for "
          "franka-sim and tests (warns)", choices=REALTIME),
    Param("lower_torque_thresholds", list(DriverSettings.lower_torque_thresholds),
          "libfranka: contact torque thresholds (7, Nm; set_collision_behavior)"),
    Param("upper_torque_thresholds", list(DriverSettings.upper_torque_thresholds),
          "libfranka: collision (reflex) torque thresholds (7, Nm); the contact slowing acts at fractions "
          "of them", check=_seven_positive),
    Param("lower_force_thresholds", list(DriverSettings.lower_force_thresholds),
          "libfranka: contact force/torque thresholds at the end effector (6, N and Nm)"),
    Param("upper_force_thresholds", list(DriverSettings.upper_force_thresholds),
          "libfranka: collision (reflex) force/torque thresholds at the end effector (6, N and Nm)"),
    Param("joint_impedance", list(DriverSettings.joint_impedance),
          "libfranka: stiffness of the robot's joint impedance controller (7, Nm/rad)"),
    Param("teaching_damping", list(DriverSettings.teaching_damping),
          "libfranka, mujoco: teaching mode damping, tau = -d * dq (7, Nm s/rad)"),
    Param("loop_prefix", "", "libfranka: command words before the loop process and the hand's (e.g. "
          "'ip netns exec NS')"),
    Param("loop_priority", 0, "libfranka: SCHED_FIFO priority of the 1 kHz loop process (0 = normal; "
          "80 on a real-time kernel)", range=(0, 99)),
    Param("gripper", True, "libfranka: drive the Franka Hand (libfranka's Gripper at robot_ip) behind "
          "~/gripper, its finger joints in joint_states; false: an arm without a hand"),
])


_SHAPING = (SafetyCode.OK, SafetyCode.VELOCITY_SCALED, SafetyCode.ACCELERATION_LIMITED)  # diagnostics OK
_STOPPED = (SafetyCode.ESTOP, SafetyCode.REFLEX, SafetyCode.INVALID_STATE)               # diagnostics ERROR


class PandaBridge(LifecycleNode):
    """See the module docstring and README.md (topics, parameters, services, safety behaviour)."""

    def __init__(self, **kwargs):
        self._owning = False               # entities made now belong to the backend or the hand
        self.backend = None
        self.gripper = None
        self._active = False
        self._started = False
        self._backend_entities: list = []
        self._config_error = ""
        self._configured_before = False
        super().__init__("panda_bridge", **kwargs)
        self.params = p = PARAMETERS.declare(self)
        self._validate(p)
        self.spec = robot_spec(p["robot_model"])
        self.base_frame = p["base_frame_id"] or self.spec.base_frame
        self.image_qos = IMAGE_QOS
        self._dt = 1.0 / p["control_rate"]
        # Pinocchio: import only when needed. The FR3's kinematics are the Panda's (checked against
        # franka-sim's FR3 model to 2e-15 m).
        from vla_common.kinematics import PandaKinematics

        kin = PandaKinematics()
        self.filter = SafetyFilter(SafetyConfig(
            dt=self._dt, velocity_scale=p["velocity_scale"], acceleration_scale=p["acceleration_scale"],
            jerk_scale=p["jerk_scale"], position_margin=p["position_margin"],
            command_timeout=p["command_timeout"], position_sync_tolerance=p["position_sync_tolerance"],
            plausibility_factor=p["plausibility_factor"]), robot=self.spec,
            # its own Pinocchio data: the state publisher's FK below must not share the buffers
            floor=WorkspaceFloor(tcp_height(PandaKinematics()), p["workspace_floor"]),
            reflex_torque=reflex_torque(p, self.spec))   # contact slowing comes before the robot's reflex
        self._fk = kin.fk if p["ee_frame"] == "tcp" else kin.flange_fk
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._published_code = -1
        self._status_text = ""
        self._closed = False
        self.states_published = 0

        # A deep history: a reliable reader that stalls (a recorder behind a simulation running faster
        # than real time on a loaded machine) gets the states late instead of losing them. 200 lost
        # seconds of states with two training jobs on the same 2 cores; 2000 (~0.6 MB) is 10 s at 200 Hz.
        state_qos = QoSProfile(depth=STATE_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._js_pub = self.create_publisher(JointState, "joint_states", state_qos)
        self._ee_pub = self.create_publisher(PoseStamped, "ee_pose", state_qos)
        # One message of each, refilled for every state (publish serializes it at once): building new
        # ones and their field checks cost 10 of the 35 us a state took.
        self._js = JointState()
        self._js.name = list(self.spec.joint_names)
        self._pose = PoseStamped()
        self._pose.header.frame_id = self.base_frame
        self._status_pub = self.create_publisher(SafetyStatus, "~/status", 10)
        self.diagnostics = Diagnostics(self, hardware_id=self.spec.name)
        # The URDF is the Panda's (example-robot-data); an FR3's comes with franka_description.
        self._description_pub = publish_robot_description(self) if self.spec is PANDA else None
        self.create_subscription(Float64MultiArray, "joint_velocity_cmd", self._on_command, 10)
        self.create_service(SetBool, "~/estop", self._on_estop)
        self.create_service(Trigger, "~/recover", self._on_recover)
        self.create_service(SetBool, "~/set_teaching", self._on_set_teaching)
        self.create_service(ResetScene, "~/reset", self._on_reset)
        if not p["lockstep"]:   # in lockstep the backend calls publish_periodic in simulated time
            self.create_timer(1.0 / p["status_rate"], self._publish_status)
            self.create_timer(1.0 / p["status_rate"], self._publish_gripper)
        if p["autostart"]:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError(self._config_error or "configure failed")
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError("activate failed")
        else:
            self._publish_status(SafetyCode.AWAITING_ZERO, self._inactive_text())

    # ------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Connect: make the backend (and its hand); the filter starts from the measured pose."""
        self._backend_entities, self._owning = [], True
        try:
            self.backend = BACKENDS[self.params["backend"]].make(self)
            self.gripper = GripperInterface(self, self.backend.hand, self.backend.now,
                                            lambda: stamp_from_ns(self.backend.now_ns()))
        except BackendError as exc:
            self._config_error = str(exc)
            self.get_logger().error(f"configure failed: {exc}")
            self._release()
            return TransitionCallbackReturn.FAILURE
        finally:
            self._owning = False
        self._js.name = list(self.spec.joint_names) + list(self.gripper.finger_joints)
        self.filter.reset(self.backend.position())
        if self._configured_before:                   # a reconnection is a stop like any other
            self.filter.disarm("configured again")
        self._configured_before = True
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Start the loop (the first time) and take commands: motion after a zero command."""
        if not self._started:
            self._owning = True
            try:
                self.backend.start(self)
            finally:
                self._owning = False
            self._started = True
            self.get_logger().info(self.backend.describe())
        self._active = True
        self._publish_status()
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Brake and hold: the loop goes on at zero, commands are refused until activated again."""
        self._hold("deactivated")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Brake, then disconnect: the backend and the hand are gone until configured again."""
        self._hold("cleaned up")
        self._brake()
        self._release()
        self._publish_status(SafetyCode.AWAITING_ZERO, self._inactive_text())
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._hold("lifecycle error")
        self._brake()
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def _hold(self, why: str) -> None:
        """Inactive: commands refused, the filter braking to zero; teaching mode left (servos on, holding
        the pose), since deactivate holds the arm and a backdrivable arm is not held."""
        self._active = False
        if self.filter.teaching and self.backend is not None:
            try:
                self._leave_teaching()
            except (UnsupportedError, RuntimeError) as exc:
                self.get_logger().error(f"{why}: could not leave teaching mode: {exc}")
        self.filter.disarm(why)
        self._publish_status(self.filter.hold_code(), self._inactive_text(why))

    @staticmethod
    def _inactive_text(why: str = "not configured") -> str:
        return f"{why} (lifecycle): commands are refused until activated, then motion needs a zero command"

    def _release(self) -> None:
        """Close the backend and destroy what it and the hand made (timers, publishers, services)."""
        if self.backend is not None:
            try:
                self.backend.close()
            except Exception as exc:  # closing a broken connection: nothing more can be sent
                self.get_logger().warn(f"closing the backend: {exc}")
        kinds = ((Timer, self.destroy_timer), (Publisher, self.destroy_publisher),
                 (Subscription, self.destroy_subscription), (Service, self.destroy_service))
        for entity in self._backend_entities:
            next(destroy for kind, destroy in kinds if isinstance(entity, kind))(entity)
        self._backend_entities = []
        if self.gripper is not None:
            self.gripper.close()
        self.backend, self.gripper, self._started = None, None, False

    # Entities made while configuring or activating belong to the backend or the hand (see _release).
    def _own(self, entity):
        if self._owning:
            self._backend_entities.append(entity)
        return entity

    def create_timer(self, *args, **kwargs):
        return self._own(super().create_timer(*args, **kwargs))

    def create_publisher(self, *args, **kwargs):
        return self._own(super().create_publisher(*args, **kwargs))

    def create_subscription(self, *args, **kwargs):
        return self._own(super().create_subscription(*args, **kwargs))

    def create_service(self, *args, **kwargs):
        return self._own(super().create_service(*args, **kwargs))

    def publish_periodic(self) -> None:
        """~/status and the hand's status at status_rate, when the backend's clock says (lockstep)."""
        self._publish_status()
        self._publish_gripper()

    def _publish_gripper(self) -> None:
        """The hand's status at status_rate; followed here too, so a silent arm (no joint_states) does
        not hide a hand that was lost or came back."""
        if self.gripper is not None:
            self.gripper.update()
            self.gripper.publish()

    @staticmethod
    def _validate(p: dict) -> None:
        row = BACKENDS[p["backend"]]
        if p["robot_model"] not in row.robots:
            why = "; the simulated scene is a Panda" if row.name == "mujoco" else ""
            raise ConfigError(f"parameter 'robot_model': '{p['robot_model']}' is not available with backend "
                              f"'{row.name}' (it drives {', '.join(row.robots)}){why}")
        if p["state_rate"] > p["control_rate"]:
            raise ConfigError(f"parameter 'state_rate' ({p['state_rate']:g} Hz) must not exceed "
                              f"'control_rate' ({p['control_rate']} Hz)")
        if p["camera_rate"] > p["control_rate"]:
            raise ConfigError("parameter 'camera_rate' must not exceed 'control_rate'")
        if p["lockstep"] and row.name != "mujoco":
            raise ConfigError(f"parameter 'lockstep': only the simulated arm (backend 'mujoco') runs in "
                              f"lockstep; a {row.name} robot keeps real time")
        names = list(p["lockstep_participants"])
        if p["lockstep"] and (not names or "" in names or len(set(names)) != len(names)):
            raise ConfigError(f"parameter 'lockstep_participants': the names of the nodes that answer "
                              f"every step, at least one, each once; got {names}")

    # ------------------------------------------------------------------------- the control path
    def control_step(self) -> None:
        """One control period, for every backend: filter(command, measured state, now) -> write."""
        b = self.backend
        if b is None:
            return
        dq, code, text = self.filter.filter(None, b.filter_position(), b.now(), b.external_torque())
        b.write(dq)
        if code != self._published_code:
            self._publish_status(code, text)

    def create_wall_timer(self, period: float, callback):
        return self.create_timer(period, callback, clock=self._steady)

    def on_fault(self, text: str) -> None:
        """The robot stopped itself (a reflex): the filter holds zero from where it is until ~/recover
        (a reflex ends teaching mode: the backend holds the arm)."""
        self.filter.set_teaching(False)
        self.filter.reset(self.backend.position())
        self.filter.set_fault(text)
        self.get_logger().error(f"robot reflex: {text}; holding until ~/recover")
        self._publish_status(SafetyCode.REFLEX, f"robot reflex ({text}): holding until ~/recover")

    def on_stop(self, why: str) -> None:
        """A stop the backend saw and this filter did not (the libfranka loop's filter): brake, and
        motion needs a zero command; once only, the next control step publishes the status."""
        if self.filter.arming.armed:
            self.filter.disarm(why)
            self.get_logger().warn(f"{why}: return the stick to neutral to move again")

    def _on_command(self, msg: Float64MultiArray) -> None:
        self.submit_command(msg.data)

    def submit_command(self, values) -> None:
        """A joint-velocity command (joint_velocity_cmd, or a lockstep answer's) into the one filter."""
        if not self._active:
            self.get_logger().warn(self._status_text or self._inactive_text(), throttle_duration_sec=1.0)
            return
        code, text = self.filter.submit(values, self.backend.now())
        if code != SafetyCode.OK:
            self.get_logger().warn(text, throttle_duration_sec=1.0)
            self._publish_status(code, text)

    # ------------------------------------------------------------------------------ publishing
    def publish_state(self) -> None:
        sample = self.backend.latest()
        if sample is None:
            return
        stamp = stamp_from_ns(sample.stamp_ns)
        self.gripper.update()
        if self.backend.publishes_joint_states:
            js = self._js
            js.header.stamp = stamp
            fq, fv = self.gripper.finger_state()
            js.position = _doubles(sample.position, fq)
            js.velocity = _doubles(sample.velocity, fv)
            js.effort = _doubles(sample.effort, [0.0] * len(fq))
            self._js_pub.publish(js)
            self.states_published += 1
        pos, rot = self._fk(sample.position)
        pose = self._pose
        pose.header.stamp = stamp
        p, o = pose.pose.position, pose.pose.orientation
        p.x, p.y, p.z = float(pos[0]), float(pos[1]), float(pos[2])
        o.w, o.x, o.y, o.z = quat_wxyz_from_matrix(rot)
        self._ee_pub.publish(pose)

    def _publish_status(self, code: int | None = None, text: str | None = None) -> None:
        f = self.filter
        if code is None:
            code, text = f.code, self._status_text
        else:
            self._status_text = text or ""
        msg = SafetyStatus()
        msg.header.stamp = (stamp_from_ns(self.backend.now_ns()) if self.backend is not None
                            else self.get_clock().now().to_msg())
        msg.code = int(code)
        msg.text = text or code_name(code)
        msg.last_intervention = int(f.last_intervention)
        msg.commands_received = f.commands_received
        msg.commands_rejected = f.commands_rejected
        msg.interventions = f.interventions
        msg.estop_active = f.estop_active
        if self.gripper is not None:
            msg.gripper, msg.gripper_lost = self.gripper.summary()
        self._status_pub.publish(msg)
        self._published_code = code
        level = "ok" if code in _SHAPING else "error" if code in _STOPPED else "warn"
        self.diagnostics.update(level, msg.text, code=code_name(code),
                                commands_received=msg.commands_received, interventions=msg.interventions)

    # -------------------------------------------------------------------------------- services
    def _on_estop(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        if request.data and self.filter.teaching:          # an e-stop holds the arm: servos on
            try:
                self._leave_teaching()
            except (UnsupportedError, RuntimeError) as exc:
                self.get_logger().error(f"e-stop: could not leave teaching mode: {exc}")
        self.filter.set_estop(request.data)
        if self.gripper is not None:
            self.gripper.set_estop(request.data)          # stops a moving hand; never opens a closed one
        response.success = True
        response.message = ("e-stop latched: braking to zero, commands ignored until released"
                            if request.data else "e-stop released: send a zero command, then move")
        if request.data:
            self.get_logger().warn(response.message)
        else:
            self.get_logger().info(response.message)
        self._publish_status(self.filter.hold_code(), response.message)
        return response

    def _on_recover(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """After a reflex: the backend re-arms the robot, the filter waits for a zero command."""
        if self.backend is None:
            response.success, response.message = False, "recovery refused: " + self._inactive_text()
            return response
        try:
            text = self.backend.recover()
        except (UnsupportedError, RuntimeError) as exc:
            response.success, response.message = False, f"recovery refused: {exc}"
            self.get_logger().warn(response.message)
            return response
        if self.filter.clear_fault():
            self.filter.reset(self.backend.position())
        else:                                               # a recovery is a stop all the same
            self.filter.disarm("~/recover")
        text = f"{text}; the arm brakes and waits: send a zero command, then move"
        response.success, response.message = True, text
        self.get_logger().info(response.message)
        self._publish_status(self.filter.hold_code(), response.message)
        return response

    def _on_set_teaching(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """Teaching mode on (only at rest, without an e-stop or reflex) or off (holding the pose)."""
        on, f = bool(request.data), self.filter
        refusal = self._teaching_refusal(on)
        if refusal is None and on == f.teaching:
            response.success, response.message = True, f"teaching mode already {'on' if on else 'off'}"
            return response
        if refusal is None:
            try:
                text = self.backend.set_teaching(True) if on else self._leave_teaching()
                if on:
                    f.set_teaching(True)
            except (UnsupportedError, RuntimeError) as exc:
                refusal = f"teaching mode {'refused' if on else 'not left'}: {exc}"
        if refusal is not None:
            response.success, response.message = False, refusal
            self.get_logger().warn(refusal)
            return response
        response.success, response.message = True, text
        self.get_logger().info(text)
        self._publish_status(f.hold_code(), text)
        return response

    def _teaching_refusal(self, on: bool) -> str | None:
        f = self.filter
        if self.backend is None:
            return "teaching mode refused: " + self._inactive_text()
        if on and not self._active:
            return "teaching mode refused: " + self._inactive_text("deactivated")
        if TEACHING not in self.backend.capabilities:
            return f"teaching mode is not available with the {self.backend.kind} backend"
        if on and not f.teaching and (f.estop_active or f.fault):
            return "teaching mode refused: " + ("e-stop latched" if f.estop_active else f"reflex {f.fault}")
        if on and not f.teaching and not f.is_stopped:
            return "teaching mode refused: the arm is moving (it starts at rest: stop commanding first)"
        return None

    def _leave_teaching(self) -> str:
        """Servos on holding the measured pose; the filter restarts from there, awaiting a zero command."""
        text = self.backend.set_teaching(False)
        self.filter.set_teaching(False)
        self.filter.reset(self.backend.position())
        return f"{text}; send a zero command, then move"

    def _on_reset(self, request: ResetScene.Request, response: ResetScene.Response) -> ResetScene.Response:
        if self.backend is None:
            response.success, response.message = False, "reset refused: " + self._inactive_text()
            return response
        try:
            self.backend.reset(request, response)
        except UnsupportedError as exc:
            response.success, response.message = False, str(exc)
            return response
        if response.success:
            self.filter.reset(self.backend.position())
            self.gripper.reset("reset with the scene: closed, holding nothing")
            if self.filter.clear_fault():                  # a new scene is a recovered arm
                response.message += "; reflex cleared: send a zero command, then move"
            self.get_logger().info(response.message)
        else:
            self.get_logger().warn(response.message)
        return response

    # -------------------------------------------------------------------------------- shutdown
    def on_shutdown(self, state: LifecycleState | None = None) -> TransitionCallbackReturn:
        """From any state (the lifecycle's shutdown, run_node's, destroy_node): brake through the
        filter with the e-stop latched, stop the hand, disconnect."""
        if not self._closed:
            self._closed = True
            self._active = False
            self.filter.set_estop(True)
            try:
                self._brake()
                if self.gripper is not None and self.gripper.core is not None:
                    self.gripper.core.set_estop(True)      # a moving hand stops; a holding one holds
                self._release()
            except Exception as exc:  # context already gone: nothing more can be sent
                print(f"panda_bridge: could not send the final zero command: {exc}", file=sys.stderr)
        return TransitionCallbackReturn.SUCCESS

    def _brake(self) -> None:
        """Run the filter to rest (time advancing the backend's way), bounded by its stopping time and
        SHUTDOWN_BRAKE_S of wall time; its last output is zero, acknowledged by the backend's close."""
        if self.backend is None or not self._started:
            return
        steps = math.ceil(self.filter.stopping_time_bound() / self._dt) + 1
        deadline = time.monotonic() + SHUTDOWN_BRAKE_S
        for _ in range(steps):
            if self.filter.is_stopped or time.monotonic() > deadline:
                break
            self.control_step()
            self.backend.advance(self._dt)

    def destroy_node(self) -> None:
        self.on_shutdown()
        super().destroy_node()


def _doubles(values: np.ndarray, extra=()) -> array.array:
    """A float64 sequence field without the per-element checks a list gets (plus `extra` values)."""
    out = array.array("d", np.ascontiguousarray(values, dtype=float).tobytes())
    if extra:
        out.extend(extra)
    return out


def main(args=None) -> int:
    return run_node(PandaBridge, "panda_bridge", args)


if __name__ == "__main__":
    sys.exit(main())

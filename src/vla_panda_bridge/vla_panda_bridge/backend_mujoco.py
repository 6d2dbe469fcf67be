"""The simulated Panda as a bridge backend: PandaSim stepped by the bridge in fixed physics increments
that equal the filter's period, paced to `real_time_factor` by vla_sim.sim_clock.SimPacer on a
steady-clock timer (so it runs with use_sim_time too), with /clock, the camera (rendered by
vla_sim.camera_worker in a thread of its own) and the ground-truth scene. With `lockstep` the
simulation owns time instead: it moves one state period at a time, once every lockstep participant
has answered the current joint state (lockstep_sim; its clock starts at vla_common.lockstep.EPOCH_NS,
its frames, scene and status come at fixed counts of states, counted from the last reset).

The simulated arm behaves like a real Panda at its limits: where contact forces a joint past its
position, velocity or torque limit the arm stops itself (PandaSim.hold) and the backend reports the
reflex with libfranka's error name (host.on_fault); commands are ignored until ~/recover. ~/reset
refuses initial joint positions outside the limits or in collision with the robot itself or the table.
Teaching mode switches the servos off (gravity compensated, `teaching_damping` per joint): the arm
follows forces on it (MuJoCo's xfrc_applied stands in for a hand); leaving it holds the pose.

The only module of the runtime packages that imports the simulator. No rclpy: ROS goes through the
host (the node).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.lockstep import EPOCH_NS
from vla_common.objects import ObjectPose
from vla_common.ros.convert import pose_msg, stamp_from_ns
from vla_sim.camera_worker import CameraWorker
from vla_sim.sim import PandaSim
from vla_sim.sim_clock import SimPacer

from vla_interfaces.msg import SceneObject, SceneObjectArray
from vla_panda_bridge import gripper
from vla_panda_bridge.backend import RESET, TEACHING, BackendBase, BackendError, Host, JointSample
from vla_panda_bridge.lockstep_sim import Lockstep

# A simulated hand's motion ends when its fingers have stood still (under STILL_SPEED) this long with
# the servo's target at its goal or its force at the limit (squeezing what stopped them).
STILL_SPEED = 1e-3   # m/s
STILL_TIME = 0.03    # s of simulated time
MOVE_FORCE = 20.0    # N: what a move (not a grasp) may push with
FRAME_WAIT_S = 60.0  # wall s a lockstep step waits for the last frame to be rendered and published


class SimHandDriver:
    """PandaSim's hand behind gripper.HandDriver: motions are its servo's, finished by the fingers'
    standing still; what it holds is what both fingers touch."""

    def __init__(self, sim: PandaSim, max_width: float) -> None:
        self.sim, self.max_width = sim, max_width
        self._active = False
        self._still_since: float | None = None

    def start(self, op: gripper.HandOp) -> None:
        hand = self.sim.hand
        if op.kind == gripper.GRASP:
            hand.command(0.0, op.speed, op.force)       # close until the object stops the fingers
        else:
            hand.command(op.width, op.speed, MOVE_FORCE)
        self._active, self._still_since = True, None

    def stop(self) -> None:
        self.sim.hand.stop()
        self._active = False

    def reset(self) -> None:
        self._active, self._still_since = False, None

    def read(self) -> gripper.HandReading:
        sim, hand = self.sim, self.sim.hand
        if abs(hand.width_speed) < STILL_SPEED:
            if self._still_since is None:
                self._still_since = sim.time
        else:
            self._still_since = None
        if self._active and self._still_since is not None and sim.time - self._still_since >= STILL_TIME:
            squeezing = abs(hand.finger_forces[0]) >= 0.95 * hand.force
            if not hand.moving or squeezing:
                self._active = False
        held = sim.held_objects()
        return gripper.HandReading(width=hand.width, moving=self._active, grasped=bool(held),
                                   holding=", ".join(held), finger_velocity=hand.width_speed)


def scene_object_msg(o: ObjectPose) -> SceneObject:
    s = SceneObject(class_id=o.class_id, x=float(o.x), y=float(o.y), yaw=float(o.yaw))
    s.pose = pose_msg((o.x, o.y, o.z), quat_wxyz=o.quat)
    return s


class MujocoBackend(BackendBase):
    """PandaSim behind the Backend protocol. Each tick of the pacing timer advances whole state
    periods; each physics step is one control period (host.control_step(), then mj_step)."""

    kind = "mujoco"
    capabilities = frozenset({RESET, TEACHING})

    def __init__(self, host: Host):
        p = host.params
        self._host = host
        self._rtf = p["real_time_factor"]
        self._dt = 1.0 / p["control_rate"]
        self._base_frame = host.base_frame
        try:
            self.catalogue = load_catalogue(p["catalogue"])
        except CatalogueError as exc:
            raise BackendError(f"parameter 'catalogue': {exc}") from exc
        self.sim = PandaSim(render=False, physics_dt=self._dt, catalogue=self.catalogue)
        try:
            self.layout: list[ObjectPose] = self.sim.reset(seed=p["seed"], q0=p["initial_positions"],
                                                           refuse_collisions=True)
        except ValueError as exc:
            raise BackendError(f"parameter 'initial_positions': {exc}") from exc
        self.fault = ""                               # the reflex the arm stopped with, until recovered
        self.hand = SimHandDriver(self.sim, host.spec.hand.max_width)
        damping = np.asarray(p["teaching_damping"], dtype=float)
        if damping.shape != (7,) or not np.all(np.isfinite(damping) & (damping >= 0.0)):
            raise BackendError(f"parameter 'teaching_damping' must be 7 values >= 0 (Nm s/rad), "
                               f"got {list(p['teaching_damping'])}")
        self._teaching_damping = damping
        self._dt_ns = round(1e9 * self.sim.physics_dt)
        self._steps = 0                               # physics steps since start: the sim clock
        self._lockstep: Lockstep | None = None
        # sim time starts at the wall time of startup; in lockstep at a fixed epoch (every run alike)
        self._clock_origin_ns = EPOCH_NS if p["lockstep"] else time.time_ns()
        self._steps_per_state = max(1, round(p["control_rate"] / p["state_rate"]))
        self.state_rate = p["control_rate"] / self._steps_per_state
        if abs(self.state_rate - p["state_rate"]) > 1e-3 * p["state_rate"]:
            host.get_logger().warn(
                f"state_rate {p['state_rate']:g} Hz is not a divisor of control_rate; "
                f"publishing every {self._steps_per_state} steps = {self.state_rate:.4g} Hz")
        self._pacer = SimPacer(self._steps_per_state * self._dt, self._rtf)
        # lockstep: outputs every so many states, counted from the last reset (0: never)
        self._every = {what: max(1, round(self.state_rate / p[rate])) if p[rate] > 0 else 0
                       for what, rate in (("frame", "camera_rate"), ("scene", "scene_rate"),
                                          ("status", "status_rate"))}
        self._states_since_reset = 0
        self._frame_steps = p["control_rate"] / p["camera_rate"] if p["camera_rate"] > 0 else 0.0
        self._frame_index = 0
        self._scene_steps = p["control_rate"] / p["scene_rate"] if p["scene_rate"] > 0 else 0.0
        self._scene_index = 0
        self._measure = True                          # give the filter a position this period
        self._closed = False
        self._scene_pub = host.create_publisher(SceneObjectArray, "scene/objects", 10)
        self._clock_pub = host.create_publisher(Clock, "/clock", 10) if p["publish_clock"] else None
        self._camera: CameraWorker | None = None
        if p["camera_rate"] > 0:
            self._image_pub = host.create_publisher(Image, "camera/image_raw", host.image_qos)
            self._info_pub = host.create_publisher(CameraInfo, "camera/camera_info", host.image_qos)
            self._camera = CameraWorker(p["camera_width"], p["camera_height"], self.sim.physics_dt,
                                        self._publish_frame,
                                        lambda m: host.get_logger().error(m, throttle_duration_sec=2.0),
                                        catalogue=self.catalogue)
            self._camera_info = self._make_camera_info()

    # ---------------------------------------------------------------------------------- protocol
    def start(self, host: Host) -> None:
        self._wall_start = time.monotonic()
        if host.params["lockstep"]:
            self._lockstep = Lockstep(host, self._steps_per_state * self._dt, self._lockstep_period,
                                      self.now_ns, self._lockstep_hold)
            self._lockstep_outputs()
            host.publish_state()
            self._lockstep.begin()
            return
        self.publish_scene()
        host.publish_state()
        self._request_frame()
        self._pacer.start(self._wall_start, 0.0)
        self._timer = host.create_wall_timer(self._pacer.timer_period(), self._tick)

    def now(self) -> float:
        return self._steps * self._dt

    def now_ns(self) -> int:
        return self._clock_origin_ns + self._steps * self._dt_ns

    def filter_position(self) -> np.ndarray | None:
        # The servo targets integrate exactly what the filter integrates: measure once a state period.
        if self._measure:
            self._measure = False
            return self.position()
        return None

    def external_torque(self) -> np.ndarray:
        """What contact (and the joint limits) push on each arm joint: MuJoCo's constraint forces."""
        return self.sim.external_torque

    def position(self) -> np.ndarray:
        """The servo targets; in teaching mode (servos off) the measured position."""
        return self.sim.q if self.sim.teaching else self.sim.q_target

    def latest(self) -> JointSample:
        sim = self.sim
        return JointSample(sim.q, sim.dq, sim.effort, self.now_ns())

    def write(self, dq: np.ndarray) -> None:
        self.sim.set_velocity_command(dq)

    def advance(self, dt: float) -> None:
        self.sim.step(1)
        self._steps += 1

    def close(self) -> bool:
        if self._closed:
            return True
        self._closed = True
        if self._camera is not None:
            self._camera.close()
        self.sim.set_velocity_command(np.zeros(7))
        wall = time.monotonic() - getattr(self, "_wall_start", time.monotonic())
        cam = (f", camera {self._camera.frames} frames ({self._camera.dropped} dropped while rendering, "
               f"{1000 * self._camera.render_seconds / max(self._camera.frames, 1):.1f} ms a frame)"
               if self._camera is not None else "")
        sim_s = self.now()
        lag = self._lockstep.pacer.lag_events if self._lockstep else self._pacer.lag_events
        hangs = f", {self._lockstep.hangs} lockstep hangs" if self._lockstep else ""
        print(f"panda_bridge: {sim_s:.1f} s simulated in {wall:.1f} s (x{sim_s / max(wall, 1e-9):.2f}, "
              f"fell behind {lag} times{hangs}){cam}; command zeroed", file=sys.stderr)
        return True

    def describe(self) -> str:
        p = self._host.params
        cam = (f"camera {p['camera_width']}x{p['camera_height']} at {p['camera_rate']:g} Hz"
               if self._camera else "camera off")
        rtf = "as fast as possible" if self._rtf == 0 else f"x{self._rtf:g}"
        if self._lockstep is not None:
            rtf += f", {self._lockstep.describe()}"
        return (f"mujoco Panda: {p['control_rate']} Hz physics+safety, joint_states {self.state_rate:g} Hz, "
                f"real time {rtf}, {cam}; {len(self.layout)} objects "
                f"({', '.join(o.class_id for o in self.layout)})")

    def recover(self) -> str:
        """~/recover: hold where the arm is now and watch the limits again."""
        if not self.fault:
            return super().recover()
        text, self.fault = self.fault, ""
        self.sim.hold()
        self.sim.clear_reflex()
        self._measure = True
        return f"recovered from {text}"

    def set_teaching(self, active: bool) -> str:
        self.sim.set_teaching(active, self._teaching_damping)
        self._measure = True
        if active:
            return ("teaching mode: servos off, gravity compensated; the arm follows forces on it "
                    "(commands are ignored)")
        return "teaching mode off: holding the pose"

    def reset(self, request, response):
        """~/reset: a new layout and arm pose (not in collision); a refused one leaves the scene as it
        was. A reset arm has no reflex latched. Refused in teaching mode."""
        if self.sim.teaching:
            response.success = False
            response.message = "reset refused, scene unchanged: leave teaching mode first (~/set_teaching)"
            response.objects = [scene_object_msg(o) for o in self.sim.object_poses()]
            return response
        try:
            objects = [ObjectPose(o.class_id, float(o.x), float(o.y), float(o.yaw))
                       for o in request.objects] or None
            seed = int(request.seed) if request.use_seed and objects is None else None
            q0 = list(request.initial_positions) or None
            self.layout = self.sim.reset(seed=seed, objects=objects, q0=q0, refuse_collisions=True)
        except ValueError as exc:
            response.success = False
            response.message = f"reset refused, scene unchanged: {exc}"
            response.objects = [scene_object_msg(o) for o in self.sim.object_poses()]
            return response
        self._measure = True
        self.fault = ""
        self.hand.reset()
        self.publish_scene()
        if self._lockstep is None:
            self._host.publish_state()
        else:   # the new scene's state is the next step's; frames and scene count from here
            self._states_since_reset = 0
        self._request_frame()
        response.success = True
        response.objects = [scene_object_msg(o) for o in self.layout]
        response.message = f"reset: {', '.join(o.class_id for o in self.layout) or 'no objects'}"
        return response

    # ------------------------------------------------------------------------------------- time
    def _tick(self) -> None:
        """Timer: advance whole state periods of simulated time (see SimPacer), publishing as it goes."""
        if self._closed:
            return
        units = self._pacer.units_due(time.monotonic(), self.now())
        for _ in range(units):
            self._physics_period(scheduled=True)
            self._host.publish_state()
        if self._clock_pub is not None and units:
            self._clock_pub.publish(Clock(clock=stamp_from_ns(self.now_ns())))

    def _physics_period(self, scheduled: bool) -> None:
        """One state period of physics, a filter update per step; `scheduled`: frames and scene on
        their own schedule of physics steps (free running)."""
        host, sim = self._host, self.sim
        self._measure = True
        for _ in range(self._steps_per_state):
            host.control_step()
            sim.step(1)
            self._steps += 1
            if sim.reflex() is not None and not self.fault:
                self._reflex(sim.reflex())
            if not scheduled:
                continue
            if self._frame_steps and self._steps >= (self._frame_index + 1) * self._frame_steps - 1e-9:
                self._frame_index += 1
                self._request_frame()
            if self._scene_steps and self._steps >= (self._scene_index + 1) * self._scene_steps - 1e-9:
                self._scene_index += 1
                self.publish_scene()

    def _lockstep_period(self) -> None:
        """Lockstep: the last step's camera frame is out (it may only render while the nodes answer),
        then one state period; its outputs go before its joint state (vla_common.lockstep)."""
        self._frame_out("the next joint state")
        self._physics_period(scheduled=False)
        self._states_since_reset += 1
        self._lockstep_outputs()
        self._host.publish_state()

    def _lockstep_hold(self) -> None:
        """Lockstep, holding: the held step's camera frame is out (it renders while the nodes answer),
        then the scene an orchestrator reads there; the held status follows both."""
        self._frame_out("the held status")
        self.publish_scene()

    def _frame_out(self, before: str) -> None:
        """Lockstep: wait until the camera frame requested last is published (bounded, logged)."""
        if self._camera is not None and not self._camera.wait_idle(timeout=FRAME_WAIT_S):
            self._host.get_logger().error(f"lockstep: a camera frame took over {FRAME_WAIT_S:.0f} s to "
                                          f"render; {before} may overtake it")

    def _lockstep_outputs(self) -> None:
        """/clock, and at their counts of states the scene, a camera frame and the periodic status."""
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=stamp_from_ns(self.now_ns())))
        n, every = self._states_since_reset, self._every
        if every["scene"] and n % every["scene"] == 0:
            self.publish_scene()
        if every["frame"] and n % every["frame"] == 0:
            self._request_frame()
        if every["status"] and n % every["status"] == 0:
            self._host.publish_periodic()

    def _reflex(self, text: str) -> None:
        """The arm went past a limit: it stops itself where it is (servos on), the node holds the filter."""
        self.fault = text
        if self.sim.teaching:
            self.sim.set_teaching(False)              # holds
        else:
            self.sim.hold()
        self._measure = True
        self._host.on_fault(text)

    # ------------------------------------------------------------------------------ publishing
    def publish_scene(self) -> None:
        msg = SceneObjectArray()
        msg.header.stamp = stamp_from_ns(self.now_ns())
        msg.header.frame_id = self._base_frame
        msg.objects = [scene_object_msg(o) for o in self.sim.object_poses()]
        self._scene_pub.publish(msg)

    def _request_frame(self) -> None:
        if self._camera is None:
            return
        if self._rtf == 0.0 or self._lockstep is not None:
            self._camera.wait_idle(timeout=5.0)  # as fast as possible, but every frame
        self._camera.request(self.sim.data.qpos.copy(), self.now_ns())

    def _publish_frame(self, rgb: np.ndarray, stamp_ns: int) -> None:
        """Camera worker thread: publish one rendered frame and its camera info."""
        if self._closed:
            return
        h, w = rgb.shape[:2]
        img = Image()
        img.header.stamp = stamp_from_ns(stamp_ns)
        img.header.frame_id = self._camera.frame_id
        img.height, img.width = h, w
        img.encoding = "rgb8"
        img.is_bigendian = 0
        img.step = 3 * w
        img.data = rgb.tobytes()
        info = self._camera_info
        info.header.stamp = img.header.stamp
        # the info first: whatever a node makes of the image (a detection, and from that the end of a
        # recorded episode) then follows it, however long this thread is kept off the CPU in between
        self._info_pub.publish(info)
        self._image_pub.publish(img)

    def _make_camera_info(self) -> CameraInfo:
        fx, fy, cx, cy = self._camera.intrinsics
        w, h = self._camera.size
        info = CameraInfo()
        info.header.frame_id = self._camera.frame_id
        info.width, info.height = w, h
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        return info

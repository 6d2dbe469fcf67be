"""A real Franka arm through libfranka as a bridge backend (no rclpy: ROS goes through the host).

The robot's 1 kHz loop runs in a process of its own (libfranka_loop, started and supervised by
libfranka_process.LoopProcess): pylibfranka holds the GIL inside readOnce, so a thread beside rclpy
would miss robot cycles. The node keeps its one control path: a steady-clock timer at control_rate
runs host.control_step() (the node's SafetyFilter: validation, watchdog, e-stop, limits), and
`write()` hands the filtered velocity to the loop, which runs the same SafetyFilter again at the
robot's rate. So the robot gets a command every millisecond that is continuous in velocity and
acceleration even when the node is late, and the loop's own watchdog brakes the arm if the node
stops writing altogether.

Every few control ticks (state_rate) the latest robot state is published, and only a new one: a
silent robot (a lost network, a server restart) produces no joint_states, and its position counts as
invalid for the node's filter (it brakes). With the states comes the robot's external torque
estimate (tau_ext_hat_filtered) for the filter's contact slowing; none while the state is
invalid. Robot errors (a reflex, a lost connection) reach the node through host.on_fault with
libfranka's text; ~/recover and ~/set_teaching go to the loop.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from vla_common.safety_status import SafetyCode

from vla_panda_bridge.backend import TEACHING, BackendBase, BackendError, Host, JointSample
from vla_panda_bridge.libfranka_driver import DRIVERS, REALTIME, DriverSettings
from vla_panda_bridge.libfranka_hand import HandProcess
from vla_panda_bridge.libfranka_loop import LoopSettings, LoopStatus
from vla_panda_bridge.libfranka_process import LibfrankaStatus, LoopProcess

MAX_CATCH_UP = 20       # control periods run at once by a late timer (the rest are skipped)
RETRY_LOG_PERIOD = 5.0  # s between log lines about a connection that keeps failing
WATCH_RATE = 100.0      # Hz: the loop's status and its process are checked this often
REQUEST_TIMEOUT = 5.0   # s to wait for the loop to answer ~/recover or ~/set_teaching
SAFETY_PARAMS = ("velocity_scale", "acceleration_scale", "jerk_scale", "position_margin", "command_timeout",
                 "position_sync_tolerance", "plausibility_factor")
LENGTHS = {"lower_torque_thresholds": 7, "upper_torque_thresholds": 7, "lower_force_thresholds": 6,
           "upper_force_thresholds": 6, "joint_impedance": 7, "teaching_damping": 7}


def loop_settings(params, robot_model: str) -> LoopSettings:
    """The loop process' settings from the bridge's parameters; BackendError names a bad one."""
    if not params["robot_ip"]:
        raise BackendError("parameter 'robot_ip' must be set for backend libfranka (the robot's FCI address)")
    if params["driver"] not in DRIVERS:
        raise BackendError(f"parameter 'driver' must be one of {list(DRIVERS)}, got {params['driver']!r}")
    if params["realtime_config"] not in REALTIME:
        raise BackendError(f"parameter 'realtime_config' must be one of {list(REALTIME)}, "
                           f"got {params['realtime_config']!r}")
    robot = {"robot_ip": params["robot_ip"], "realtime": params["realtime_config"]}
    for name, n in LENGTHS.items():
        values = [float(v) for v in params[name]]
        if len(values) != n or not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise BackendError(f"parameter '{name}' must be {n} finite values >= 0, got {list(params[name])}")
        robot[name] = values
    DriverSettings(**robot)
    return LoopSettings(driver=params["driver"], robot=robot, robot_model=robot_model,
                        safety={k: params[k] for k in SAFETY_PARAMS}, priority=int(params["loop_priority"]))


class LibfrankaBackend(BackendBase):
    kind = "libfranka"
    capabilities = frozenset({TEACHING})

    def __init__(self, host: Host, clock: Callable[[], float] = time.monotonic):
        """`clock`: monotonic seconds, the control periods and the robot's silence are counted on (a
        test's clock: what is due then never depends on how fast the machine runs the test)."""
        p = host.params
        self._host = host
        self._clock = clock
        self._dt = 1.0 / p["control_rate"]
        # joint_states: every k-th robot state (1 kHz), published in batches at up to state_rate.
        self._states_every = max(1, round(1000.0 / p["state_rate"]))
        self._ticks_per_state = max(1, round(p["control_rate"] / p["state_rate"]))
        self._ticks_per_watch = max(1, round(p["control_rate"] / WATCH_RATE))
        self._state_timeout = p["state_timeout"]
        self._no_state = np.full(host.spec.num_joints, np.nan)  # invalid on purpose: the filter brakes
        self.settings = loop_settings(p, host.spec.name)
        if p["realtime_config"] == "ignore":
            host.get_logger().warn("realtime_config 'ignore': the loop runs without a real-time kernel "
                                   "(fine for franka-sim and tests; on a real arm expect lost cycles)")
        self.process = LoopProcess(self.settings, loop_prefix=p["loop_prefix"], clock=clock)
        # The Franka Hand: libfranka's Gripper in a process of its own (its calls block, holding the
        # GIL), behind the node's gripper layer; connects (and reconnects) by itself, LOST until then.
        self.hand = (HandProcess(p["robot_ip"], host.spec.hand.max_width, p["driver"], p["loop_prefix"])
                     if p["gripper"] else None)
        self._latest: JointSample | None = None
        self._tau_ext: np.ndarray | None = None         # tau_ext_hat_filtered of the latest state read
        self._written = np.zeros(host.spec.num_joints)  # the node's latest filtered command to the loop
        self._status = LibfrankaStatus(LoopStatus.CONNECTING, "", 0, "", -1, 0.0,
                                       math.inf, False, False, 0, 0, 0, 0, 0, math.nan)
        self._reported = -1                             # the loop status code last reported
        self._reported_text, self._reported_at = "", -math.inf
        self._ticks = 0                                 # control periods done (by the wall clock)
        self._state_tick = self._watch_tick = 0
        self._t0 = self._clock()

    # ---------------------------------------------------------------------------------- protocol
    def start(self, host: Host) -> None:
        self.process.start()
        self._t0 = self._clock()
        host.create_wall_timer(self._dt, self._tick)

    def _tick(self) -> None:
        """The control periods due by the wall clock (the node's filter integrates a fixed period
        per step: a timer that runs late on a loaded machine would slow its ramps and its braking
        down, so it catches up, at most MAX_CATCH_UP periods at once), then the robot states that
        arrived since (a batch when late) and, at 100 Hz, the loop's status."""
        due = int((self._clock() - self._t0) / self._dt) - self._ticks
        for _ in range(min(due, MAX_CATCH_UP)):
            self._host.control_step()
        self._ticks += max(due, 0)
        if self._ticks // self._ticks_per_state != self._state_tick:
            self._state_tick = self._ticks // self._ticks_per_state
            for sample in self.process.new_samples(self._states_every):
                self._latest = sample
                self._host.publish_state()
            self._tau_ext = self.process.external_torque()   # of the state new_samples just read
        if self._ticks // self._ticks_per_watch != self._watch_tick:
            self._watch_tick = self._ticks // self._ticks_per_watch
            note = self.process.poll()
            if note:
                self._host.get_logger().warn(note)
            self._watch_status()

    def _watch_status(self) -> None:
        """Report the loop's status when its code changes: a fault (reflex, lost connection, fatal)
        through host.on_fault with libfranka's text, the rest to the log; while it keeps trying to
        connect, why (libfranka's refusal) every RETRY_LOG_PERIOD."""
        st = self._status = self.process.status()
        self._mirror_loop_hold(st)
        if not st.text:
            return                                      # its text is not written yet
        text = f"libfranka {st.name}: {st.text}"
        now = self._clock()
        if st.code == self._reported:
            if st.code in (LoopStatus.CONNECTING, LoopStatus.DISCONNECTED) and text != self._reported_text \
                    and now - self._reported_at >= RETRY_LOG_PERIOD:
                self._reported_text, self._reported_at = text, now
                self._host.get_logger().warn(text)
            return
        # The first retry text after a change is logged at once, later ones every RETRY_LOG_PERIOD.
        self._reported, self._reported_text, self._reported_at = st.code, text, -math.inf
        if st.code in (LoopStatus.OK, LoopStatus.CONNECTING):
            self._host.get_logger().info(text)
        elif (on_fault := getattr(self._host, "on_fault", None)) is not None:
            on_fault(text)
        else:
            self._host.get_logger().error(text)

    def _mirror_loop_hold(self, st: LibfrankaStatus) -> None:
        """The loop's filter waits for a zero command after a stop the node's filter did not see (its
        watchdog, when this process was late by more than command_timeout on a loaded machine; a robot
        silence): it ignores the node's non-zero commands, which the node's filter, still armed, goes on
        sending. So the node's filter stops too, and says why: the operator's neutral then re-arms it,
        and its zeros re-arm the loop. Without this the station said "moving" while nothing moved,
        and a quick neutral did not help (the node's output, still braking, never reached zero)."""
        if st.filter_code == SafetyCode.AWAITING_ZERO and np.any(self._written):
            on_stop = getattr(self._host, "on_stop", None)
            if on_stop is not None:
                on_stop(f"the robot's loop stopped: {st.filter_text or 'it waits for a zero command'}")

    @property
    def status(self) -> LibfrankaStatus:
        return self._status

    def now(self) -> float:
        return self._clock()

    def now_ns(self) -> int:
        return self._host.get_clock().now().nanoseconds

    def _state_valid(self) -> bool:
        st = self._status
        return self._latest is not None and st.code == LoopStatus.OK and st.silent_for <= self._state_timeout

    def filter_position(self) -> np.ndarray:
        """The robot's latest position while it talks and is fine; invalid (brake) otherwise."""
        return self._latest.position if self._state_valid() else self._no_state

    def external_torque(self) -> np.ndarray | None:
        """The robot's external torque estimate (tau_ext_hat_filtered, Nm; updated with the joint
        states, at state_rate) while the state is valid, else None (the filter brakes anyway)."""
        return self._tau_ext if self._state_valid() else None

    def position(self) -> np.ndarray | None:
        sample = self.process.read()
        return None if sample is None else sample.position

    def latest(self) -> JointSample | None:
        return self._latest

    def write(self, dq: np.ndarray) -> None:
        self._written = dq
        self.process.submit(dq)

    def advance(self, dt: float) -> None:
        time.sleep(dt)                                  # the loop runs on the robot's clock by itself

    def close(self) -> bool:
        """The hand's threads end (a running motion stopped); the loop brakes to zero, ends the motion
        (motion_finished) and exits; killed after 1 s."""
        if self.hand is not None:
            self.hand.close(timeout=0.3)
        return self.process.close(timeout=1.0)

    def describe(self) -> str:
        p = self._host.params
        prio = f", SCHED_FIFO {p['loop_priority']}" if p["loop_priority"] else ""
        state_hz = 1000.0 / self._states_every
        hand = "the Franka Hand through libfranka's Gripper" if self.hand is not None else "no hand"
        return (f"libfranka: {p['driver']} driver -> {p['robot_ip']} ({self._host.spec.name}), 1 kHz loop in "
                f"process {self.process.pid}{prio} with the safety filter at the robot's rate; node filter "
                f"at {p['control_rate']} Hz, joint_states at {state_hz:g} Hz; {hand}")

    # ---------------------------------------------------------------------------------- services
    def recover(self) -> str:
        """Automatic error recovery (after a reflex) or an immediate reconnection; RuntimeError with
        libfranka's text if it fails."""
        token = self.process.request_recover()
        result = _wait(lambda: self.process.recover_result(token))
        if result is None:
            raise RuntimeError(f"the libfranka loop did not answer within {REQUEST_TIMEOUT:g} s")
        ok, text = result
        self._watch_status()
        if not ok:
            raise RuntimeError(f"recovery failed: {text}")
        return text

    def set_teaching(self, active: bool) -> str:
        """Torque control with tau = -teaching_damping * dq (the robot compensates gravity), or back to
        velocity control holding the pose; RuntimeError if the loop refused (an error, e-stop, no robot)."""
        token = self.process.request_teaching(active)
        result = _wait(lambda: self.process.teaching_result(token))
        if result is None:
            raise RuntimeError(f"the libfranka loop did not answer within {REQUEST_TIMEOUT:g} s")
        if result != bool(active):
            st = self.process.status()
            raise RuntimeError(f"teaching mode {'refused' if active else 'still on'}: {st.name} {st.text}")
        return ("teaching: the arm follows the hand (torque control, the robot compensates gravity)"
                if active else "teaching off: holding the pose; velocity commands move the arm again")


def _wait(poll, timeout: float = REQUEST_TIMEOUT):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        result = poll()
        if result is not None:
            return result
        time.sleep(0.002)
    return None

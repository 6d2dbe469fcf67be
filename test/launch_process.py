"""Helpers of the launch-file tests: `vla launch ...` started as a user starts it, and an observer node.

`LaunchProcess` runs the installed `vla` command in a process group of its own with its output in a
log file (no pipe that a silent reader could fill), stops it with SIGINT like Ctrl-C and, as a last
resort at teardown, kills its group. `Observer` keeps the latest messages of the graph's topics.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from vla_common.robot import JOINT_NAMES
from vla_launch.run import find_executable

from vla_interfaces.msg import ControllerStatus, DetectionArray, SafetyStatus, TeleopStatus


class LaunchProcess:
    """`vla launch <args>` in the background; `stop()` sends SIGINT and returns the exit code."""

    def __init__(self, *args: str, log_path: Path) -> None:
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen([find_executable("vla_launch", "vla"), "launch", *args],
                                         stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                         start_new_session=True)
        self.stop_s: float | None = None  # s from SIGINT to the launch's exit

    def __enter__(self) -> LaunchProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.kill()

    def text(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 60.0) -> int:
        """SIGINT (Ctrl-C) and wait for the launch to end; its exit code."""
        if self.running():
            t0 = time.monotonic()
            self.proc.send_signal(signal.SIGINT)
            self.proc.wait(timeout)
            self.stop_s = time.monotonic() - t0
        return self.proc.returncode

    def kill(self) -> None:
        """Whatever is left (a failed test): SIGINT, then SIGKILL the launch's group and its children."""
        if self.running():
            try:
                self.stop(timeout=20.0)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()


class Observer(Node):
    """The latest joint state, detections and statuses of the graph, with every bridge status kept."""

    def __init__(self, context, name: str = "test_observer") -> None:
        super().__init__(name, context=context)
        self.q: np.ndarray | None = None
        self.stamp = 0.0                   # the latest joint state's stamp (s): simulated time with a sim
        self.joint_states = 0
        self.detections: DetectionArray | None = None
        self.ctrl: ControllerStatus | None = None
        self.ctrl_log: list[ControllerStatus] = []
        self.teleop: TeleopStatus | None = None
        self.safety: list[SafetyStatus] = []
        sensor = qos_profile_sensor_data
        self.create_subscription(JointState, "joint_states", self._joints, sensor)
        self.create_subscription(DetectionArray, "detections", self._dets, sensor)
        self.create_subscription(ControllerStatus, "controller_node/status", self._ctrl, sensor)
        self.create_subscription(TeleopStatus, "sim_teleoperator/status", self._teleop, sensor)
        self.create_subscription(SafetyStatus, "panda_bridge/status", self.safety.append, sensor)

    def _joints(self, msg: JointState) -> None:
        names = list(msg.name)
        if all(j in names for j in JOINT_NAMES):
            self.q = np.array([msg.position[names.index(j)] for j in JOINT_NAMES])
            self.stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            self.joint_states += 1

    def _dets(self, msg: DetectionArray) -> None:
        self.detections = msg

    def _ctrl(self, msg: ControllerStatus) -> None:
        self.ctrl = msg
        self.ctrl_log.append(msg)

    def _teleop(self, msg: TeleopStatus) -> None:
        self.teleop = msg

    def graph_up(self) -> bool:
        """joint_states, detections and the controller's status have all arrived."""
        return self.q is not None and self.detections is not None and self.ctrl is not None


def thread_nices(executable: str, parent: int) -> dict[int, int]:
    """{thread id: nice value} of the node process whose executable is named so, started by the
    process `parent` (the launch: another graph on the machine runs its own nodes of that name)."""
    return _thread_fields(executable, parent, 16)


def thread_policies(executable: str, parent: int) -> dict[int, int]:
    """{thread id: scheduling policy (os.SCHED_OTHER, os.SCHED_FIFO, ...)} of that node process."""
    return _thread_fields(executable, parent, 38)


def _thread_fields(executable: str, parent: int, index: int) -> dict[int, int]:
    """One numeric field of /proc/<pid>/task/<tid>/stat (`index` counted after the command's name)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                args = (d / "cmdline").read_bytes().split(b"\0")
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == parent and any(Path(a.decode(errors="replace")).name == executable for a in args[:2]):
                pids.append(d)
    assert len(pids) == 1, f"{len(pids)} processes of {parent} run {executable}"
    fields = {}
    for t in (pids[0] / "task").iterdir():
        try:
            fields[int(t.name)] = int((t / "stat").read_text().rsplit(")", 1)[1].split()[index])
        except (OSError, IndexError):
            pass    # a thread that ended meanwhile
    return fields


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.dot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))

"""Benchmark of the panda_bridge node (MuJoCo backend): prints figures, asserts nothing.

1. joint_states publish-interval jitter at state_rate 200 and 1000 Hz (real time, camera off): the
   interval between arrivals at a subscriber in another process, its error from 1/rate (median, p99,
   max) and messages lost (gaps in the simulated-time stamps);
2. the node's real-time factor with real_time_factor:=0 (as fast as possible), camera off and on
   (640x480 at 30 Hz): simulated seconds per wall second, from the /clock it publishes;
3. the per-step cost inside the loop: SafetyFilter.filter bare and as the MuJoCo bridge runs it
   (workspace floor, measured external torque), alternated; one 1 kHz physics step (in-process).

Usage: python bench/bench_bridge.py [--duration 5]   (after `source scripts/env.sh`)
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

from brief import parse
from vla_common.ros.context import end_context
from vla_common.ros.domain import isolate

isolate()  # before any rclpy context exists

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from vla_launch.run import find_executable  # noqa: E402


def _stamp(t) -> float:
    return t.sec + t.nanosec * 1e-9


def run_node(params: dict, duration: float, warmup: float = 1.0) -> dict:
    """Start the installed node with params, record joint_states arrivals and /clock for `duration`."""
    args = [sys.executable, find_executable("vla_panda_bridge", "panda_bridge"), "--ros-args"]
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("bench_bridge", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    arrivals: list[float] = []
    stamps: list[float] = []
    clock: list[tuple[float, float]] = []
    recording = [False]

    def on_state(msg: JointState) -> None:
        if recording[0]:
            arrivals.append(time.perf_counter())
            stamps.append(_stamp(msg.header.stamp))

    def on_clock(msg: Clock) -> None:
        if recording[0]:
            clock.append((time.perf_counter(), _stamp(msg.clock)))

    node.create_subscription(JointState, "joint_states", on_state, QoSProfile(depth=200))
    node.create_subscription(Clock, "/clock", on_clock, QoSProfile(depth=200))
    try:
        end = time.monotonic() + 60.0
        while node.count_publishers("joint_states") == 0 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
            if proc.poll() is not None:
                raise RuntimeError(f"panda_bridge exited: {proc.stderr.read()}")
        t_end = time.monotonic() + warmup
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.01)
        recording[0] = True
        t_end = time.monotonic() + duration
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.01)
        recording[0] = False
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        node.destroy_node()
        ex.shutdown()
        end_context(ctx)
    return {"arrivals": np.array(arrivals), "stamps": np.array(stamps), "clock": np.array(clock)}


def jitter(rate: float, duration: float) -> None:
    r = run_node({"state_rate": float(rate), "camera_rate": 0.0, "real_time_factor": 1.0}, duration)
    period = 1.0 / rate
    intervals = np.diff(r["arrivals"])
    err = np.abs(intervals - period) * 1e3
    gaps = np.round(np.diff(r["stamps"]) / period)
    lost = int(np.sum(gaps - 1)) if gaps.size else 0
    achieved = (r["stamps"][-1] - r["stamps"][0]) / (r["arrivals"][-1] - r["arrivals"][0])
    n = len(r["arrivals"])
    print(f"  {rate:6.0f} Hz  {n:6d} msgs  interval median {np.median(intervals) * 1e3:6.3f} ms"
          f"  |error| median {np.median(err):6.3f} p99 {np.percentile(err, 99):7.3f} max {err.max():7.2f} ms"
          f"  lost {lost}  sim/wall {achieved:5.3f}")


def real_time_factor(label: str, params: dict, duration: float) -> None:
    r = run_node({"real_time_factor": 0.0, **params}, duration)
    c = r["clock"]
    factor = (c[-1, 1] - c[0, 1]) / (c[-1, 0] - c[0, 0]) if len(c) > 1 else float("nan")
    print(f"  {label:34s} real-time factor {factor:6.2f}x")


def step_costs(n: int = 3000, rounds: int = 5) -> None:
    """SafetyFilter.filter as the MuJoCo bridge runs it (the workspace floor, a measured external
    torque) against the bare filter (neither), alternated in rounds on the same commands so that the
    ratio is fair on a loaded machine; then one physics step."""
    from vla_common.kinematics import PandaKinematics
    from vla_common.robot import READY_POSE
    from vla_panda_bridge.safety import SafetyFilter
    from vla_panda_bridge.workspace import DEFAULT_FLOOR, WorkspaceFloor, tcp_height
    from vla_sim.sim import PandaSim

    rng = np.random.default_rng(0)
    cmds = [rng.normal(0, 0.5, 7) if k % 10 == 0 else None for k in range(n)]
    tau = np.full(7, 1.0)                               # a small torque: the contact rule evaluates
    floor = WorkspaceFloor(tcp_height(PandaKinematics()), DEFAULT_FLOOR)

    def run(f: SafetyFilter, tau_ext) -> list[float]:
        q = READY_POSE.copy()
        times = []
        for k, cmd in enumerate(cmds):
            t0 = time.perf_counter()
            dq, _, _ = f.filter(cmd, q, k * 1e-3, tau_ext)
            times.append(time.perf_counter() - t0)
            q = q + 1e-3 * dq
        return times

    bare: list[float] = []
    full: list[float] = []
    for _ in range(rounds):
        bare += run(SafetyFilter(), None)
        full += run(SafetyFilter(floor=floor), tau)
    b, f_ = np.array(bare) * 1e6, np.array(full) * 1e6
    print(f"  SafetyFilter.filter, bare  median {np.median(b):6.1f} us  p99 {np.percentile(b, 99):6.1f} us")
    print(f"  ... + floor + contact      median {np.median(f_):6.1f} us  p99 {np.percentile(f_, 99):6.1f} us"
          f"  (median ratio {np.median(f_) / np.median(b):.2f})")
    sim = PandaSim(render=False, physics_dt=0.001)
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        sim.set_velocity_command(np.zeros(7))
        sim.step(1)
        times.append(time.perf_counter() - t0)
    t = np.array(times) * 1e6
    print(f"  PandaSim command+step 1 ms median {np.median(t):6.1f} us  p99 {np.percentile(t, 99):6.1f} us")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="seconds measured per configuration")
    a = parse(ap, duration=1.0)
    print(f"bench_bridge (nproc={os.cpu_count()}, load average {os.getloadavg()[0]:.1f})")
    print("per-step cost (1 kHz loop):")
    step_costs()
    print("joint_states publish intervals at a subscriber (real time, camera off):")
    for rate in (200, 1000):
        jitter(rate, a.duration)
    print("node real-time factor (real_time_factor:=0, state_rate 200):")
    real_time_factor("camera off", {"camera_rate": 0.0}, a.duration)
    real_time_factor("camera 320x240 @ 30 Hz", {"camera_rate": 30.0, "camera_width": 320,
                                                "camera_height": 240}, a.duration)
    real_time_factor("camera 640x480 @ 30 Hz", {"camera_rate": 30.0}, a.duration)
    return 0


if __name__ == "__main__":
    sys.exit(main())

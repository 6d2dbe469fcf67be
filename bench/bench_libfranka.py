"""Benchmark of the libfranka backend against franka-sim: prints figures, asserts nothing.

The bridge (backend:=libfranka driver:=pylibfranka) runs in this process as it would in its own, with
its 1 kHz loop in a child process joined to franka-sim's private network namespace; the arm follows
a smooth joint-velocity sine published here, with exact zeros for 50 ms every 2 s (an operator's
return to neutral, which re-arms the bridge after a stale-input stop). With `--graph` (the default) the
rest of the teleop graph runs beside it as separate processes on the same cores: camera_node (a 640x480
image at 30 Hz), detector_node (ONNX) on it, controller_node (shipped model, joystick sine from here;
its commands go to a side topic so the arm's motion stays the bench's).

Figures:
1. the loop's cycle: period between robot states (median, p99, max) and the loop's own work per
   cycle, state to command (median, p99, max);
2. robot cycles answered in time: 1 - missed/cycles from the robot's Durations, and franka-sim's
   control_command_success_rate (mean, min; goal >= 0.999). franka-sim slows its state stream in
   lockstep when the machine is overloaded instead of dropping cycles, so read both with the
   simulator's own state rate (from its log) and the load average;
3. latency from a joint_velocity_cmd arriving at the bridge to the first robot command with it
   (median, p99, max).

Both franka-sim and the loop run under SCHED_FIFO 50 (`--priority`, 0 for normal scheduling), as the
loop would on a real-time PC.

Usage: python bench/bench_libfranka.py [--seconds 20] [--no-graph] [--priority 50] [--json]
(after source scripts/env.sh)
Needs .venv-franka-sim (scripts/setup_franka_sim.sh), pylibfranka and root for network namespaces.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import time

from brief import parse, skipped
from vla_common.ros.domain import isolate

isolate()  # before any rclpy context exists

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Joy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from vla_launch.run import find_executable  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "test"))     # franka_sim_server: test support, not a package
from franka_sim_server import FrankaSimServer, Netns, unavailable  # noqa: E402

IMAGE = os.path.join(REPO, "docs", "scene.png")        # a 640x480 view of the simulated scene
NEUTRAL_S = 0.05   # s of exact zero commands every 2 s (the sine's common zero crossing)


def _graph(fr3: bool) -> list[subprocess.Popen]:
    """camera -> detector -> controller, each a process (as `vla launch` would start them)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    controller = ["-r", "joint_velocity_cmd:=controller/joint_velocity_cmd"]
    if fr3:                                         # the shipped models are the Panda's
        mapping = ", ".join(f"'fr3_joint{i}:panda_joint{i}'" for i in range(1, 8))
        controller += ["-p", f"joint_map:=[{mapping}]"]
    nodes = [
        ("vla_camera", "camera_node", ["-p", f"source:={IMAGE}", "-p", "loop:=true", "-p", "fps:=30.0"]),
        ("vla_detector", "detector_node", ["-p", "num_threads:=1"]),
        ("vla_latent_controller", "controller_node", controller),
    ]
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    return [subprocess.Popen([sys.executable, find_executable(pkg, exe), "--ros-args", *args], env=env,
                             **quiet) for pkg, exe, args in nodes]


def _stats(values) -> dict:
    v = np.asarray([x for x in values if math.isfinite(x)])
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "median": float(np.median(v)), "p99": float(np.percentile(v, 99)),
            "max": float(v.max())}


def _ms(s: dict) -> str:
    if not s.get("n"):
        return "n/a"
    return f"median {s['median'] * 1e3:.3f} ms, p99 {s['p99'] * 1e3:.3f} ms, max {s['max'] * 1e3:.3f} ms"


def run(seconds: float, graph: bool, priority: int) -> dict:
    from vla_panda_bridge.bridge_node import PARAMETERS, PandaBridge

    ns = Netns()
    server = FrankaSimServer(ns, enforce_motion_limits=True, enforce_comm_constraints=False,
                             priority=priority)
    server.start()
    fr3 = "robot_model" in PARAMETERS.params
    procs = _graph(fr3) if graph else []
    rclpy.init()
    params = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
              "realtime_config": "ignore", "loop_prefix": " ".join(ns.prefix()), "state_rate": 1000.0,
              "loop_priority": priority,
              # The FCI's FR3 table is 10 rad/s^2 / 5000 rad/s^3 (vla_common.robot's FR3 has the Panda's).
              "acceleration_scale": 0.4999, "jerk_scale": 0.4999}
    if fr3:
        params["robot_model"] = "fr3"
    bridge = PandaBridge(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    io = rclpy.create_node("bench_libfranka")
    ex = SingleThreadedExecutor()
    ex.add_node(bridge)
    ex.add_node(io)
    process = bridge.backend.process

    # Latency: the arrival of each joint_velocity_cmd at the bridge travels with the next writes.
    arrival = [math.nan]
    on_command = bridge._on_command

    def traced(msg):
        arrival[0] = time.monotonic()
        on_command(msg)
    bridge._on_command = traced
    submit = process.submit
    process.submit = lambda values, arrived=None: submit(values, arrival[0] if math.isfinite(arrival[0])
                                                         else None)
    # The node's subscription callback was bound at creation: route it through the wrapper.
    for sub in bridge.subscriptions:
        if sub.topic_name.endswith("joint_velocity_cmd"):
            sub.callback = traced

    cmd_pub = io.create_publisher(Float64MultiArray, "joint_velocity_cmd", 10)
    joy_pub = io.create_publisher(Joy, "joy", 10)
    t0 = [math.inf]                                 # zeros until connected: motion needs a neutral first

    def publish():
        t = max(time.monotonic() - t0[0], 0.0)
        w = 2 * math.pi * 0.25
        cmd = [0.0] * 7
        if t % 2.0 > NEUTRAL_S:   # exact zeros near each common zero crossing: the operator's neutral,
            # which re-arms the bridge after a stop (a stale-input stop stays stopped until a neutral)
            cmd[0], cmd[3], cmd[6] = 0.3 * math.sin(w * t), 0.2 * math.sin(w * t), 0.4 * math.sin(2 * w * t)
        cmd_pub.publish(Float64MultiArray(data=cmd))
        joy_pub.publish(Joy(axes=[0.8 * math.sin(w * t), 0.0], buttons=[0, 0, 0, 0]))
    io.create_timer(0.01, publish)                 # 100 Hz, as the controller publishes

    def spin(sec: float):
        end = time.monotonic() + sec
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)

    deadline = time.monotonic() + 20.0
    while bridge.backend.status.code != 0 or process.read() is None:
        spin(0.05)
        if time.monotonic() > deadline:
            raise RuntimeError(f"the bridge did not connect: {bridge.backend.status}")
    spin(0.2)                                       # zeros reach the node's filter and the loop's
    t0[0] = time.monotonic()
    spin(3.0)                                       # graph warm-up, the arm in motion
    ring_start = process.slots.ring_count
    s0 = process.slots.read_state()
    load0 = os.getloadavg()[0]
    rates, t_start = [], time.monotonic()
    while time.monotonic() - t_start < seconds:
        spin(0.01)
        s = process.slots.read_state()
        if s is not None and s.mode == 1:
            rates.append(s.success_rate)
    s1 = process.slots.read_state()
    rings = process.slots.ring_snapshot()
    n = process.slots.ring_count - ring_start
    rings = {k: v[-n:] for k, v in rings.items()} if 0 < n <= len(rings["period"]) else rings
    cycles = s1.cycle - s0.cycle
    missed = s1.missed - s0.missed
    sim_freq = [float(f) for f in re.findall(r"Freq: ([0-9.]+)Hz", server.log())[-int(seconds):]]
    result = {
        "seconds": seconds, "graph": graph, "priority": priority,
        "load_average_1min": [load0, os.getloadavg()[0]],
        "cycles": int(cycles), "period": _stats(rings["period"]), "busy": _stats(rings["busy"]),
        "robot_cycles_missed": int(missed), "answered_in_time": 1.0 - missed / max(cycles + missed, 1),
        "success_rate_mean": float(np.mean(rates)) if rates else math.nan,
        "success_rate_min": float(np.min(rates)) if rates else math.nan,
        "latency": _stats(rings["latency"]), "sim_state_rate_hz": _stats(sim_freq),
        "loop_status": bridge.backend.status.name, "errors": int(s1.errors - s0.errors),
    }
    bridge.on_shutdown()
    bridge.destroy_node()
    io.destroy_node()
    rclpy.shutdown()
    for p in procs:
        p.terminate()
    for p in procs:
        p.wait(10)
    server.stop()
    ns.close()
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="measured time (after 3 s of warm-up)")
    ap.add_argument("--no-graph", action="store_true",
                    help="the bridge alone, without camera/detector/controller")
    ap.add_argument("--priority", type=int, default=50,
                    help="SCHED_FIFO priority of franka-sim and the loop (0: normal scheduling)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parse(ap, seconds=3.0)
    reason = unavailable()
    if reason is None:
        try:
            import pylibfranka  # noqa: F401
        except ImportError:
            reason = "pylibfranka==0.21.3 is not installed"
    if reason:
        return skipped("FRANKA_SIM", f"bench_libfranka: {reason}")
    r = run(args.seconds, graph=not args.no_graph, priority=args.priority)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    sim = r["sim_state_rate_hz"]
    print(f"libfranka loop vs franka-sim, {r['seconds']:g} s, graph {'on' if r['graph'] else 'off'}, "
          f"SCHED_FIFO {r['priority'] or 'off'}, "
          f"load average {r['load_average_1min'][0]:.2f} -> {r['load_average_1min'][1]:.2f} "
          f"({os.cpu_count()} CPUs)")
    print(f"  cycle period            {_ms(r['period'])}  ({r['cycles']} cycles)")
    print(f"  loop work per cycle     {_ms(r['busy'])}")
    print(f"  answered in time        {r['answered_in_time'] * 100:.3f} %  ({r['robot_cycles_missed']} robot "
          f"cycles missed)")
    print(f"  franka-sim success rate mean {r['success_rate_mean']:.4f}, min {r['success_rate_min']:.4f} "
          f"(goal >= 0.999); its state rate median {sim.get('median', math.nan):.1f} Hz")
    print(f"  cmd -> robot latency    {_ms(r['latency'])}")
    print(f"  loop status {r['loop_status']}, robot errors {r['errors']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

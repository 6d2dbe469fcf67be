"""How long `vla launch` takes to stop the teleop graph on Ctrl-C (issue 21 item 6: ≤ 2 s at rest).

Starts `vla launch vla_bringup teleop.launch.yaml use_sim_time:=true` (the graph of
test/test_launch_sigint.py) `--runs` times in a ROS domain of its own, waits until the graph is up
(joint states and the controller's status arrive), sends SIGINT and times the launch's exit. Prints
each run, the median and the p99, and how many runs needed a SIGTERM/SIGKILL escalation.

    source scripts/env.sh && python bench/bench_launch.py --runs 10
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from brief import parse
from vla_common.ros.domain import isolate

isolate()  # before any rclpy context exists

from rclpy.node import Node  # noqa: E402 - after the domain is chosen
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from vla_common.ros.testing import RosHarness  # noqa: E402
from vla_launch.run import find_executable  # noqa: E402

from vla_interfaces.msg import ControllerStatus  # noqa: E402


class _Watch(Node):
    """Graph up: a joint state and a controller status have arrived."""

    def __init__(self, context, name: str) -> None:
        super().__init__(name, context=context)
        self.seen: set[str] = set()
        self.create_subscription(JointState, "joint_states", lambda m: self.seen.add("q"),
                                 qos_profile_sensor_data)
        self.create_subscription(ControllerStatus, "controller_node/status",
                                 lambda m: self.seen.add("ctrl"), qos_profile_sensor_data)

    def up(self) -> bool:
        return self.seen == {"q", "ctrl"}


def one_run(i: int, log: Path, args: list[str]) -> tuple[float, bool]:
    """Seconds from SIGINT to the launch's exit, and whether a node needed SIGTERM/SIGKILL."""
    h = RosHarness(other_processes=True)  # the launch is other processes
    with open(log, "wb") as f:
        proc = subprocess.Popen([find_executable("vla_launch", "vla"), "launch", "vla_bringup",
                                 "teleop.launch.yaml", *args], stdin=subprocess.DEVNULL, stdout=f,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        watch = h.add(_Watch(h.context, f"bench_launch_watch_{i}"))
        if not h.spin_until(watch.up, 120.0):
            raise SystemExit(f"run {i}: the graph did not come up; log: {log}")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(60)
        dt = time.monotonic() - t0
        text = log.read_text(errors="replace")
        if rc != 0:
            raise SystemExit(f"run {i}: vla launch exited {rc}; log: {log}")
        return dt, "SIGTERM" in text or "SIGKILL" in text
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        h.shutdown()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--launch-arg", action="append", default=["use_sim_time:=true"],
                    help="name:=value for the launch file (repeatable)")
    a = parse(ap, runs=1)
    out = Path(tempfile.mkdtemp(prefix="bench_launch_"))
    times, escalated = [], 0
    for i in range(a.runs):
        dt, esc = one_run(i, out / f"launch{i}.log", a.launch_arg)
        times.append(dt)
        escalated += esc
        print(f"run {i}: stopped {dt:.3f} s after SIGINT{' (escalated)' if esc else ''}", flush=True)
    ordered = sorted(times)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    print(f"teleop graph, Ctrl-C to exit: median {statistics.median(times):.3f} s, p99 {p99:.3f} s, "
          f"max {ordered[-1]:.3f} s over {len(times)} runs; escalated {escalated}; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; logs in {out}")


if __name__ == "__main__":
    main()

"""Benchmark of the operator station (issue 22) with the browser in the loop: prints figures, asserts
nothing.

The shipped teleop.launch.yaml (use_operator_station:=true) on the simulated Panda and one headless
Chromium on its page:
1. key press -> joint_velocity_cmd latency: the page's own keydown handler is fired in the browser
   (its epoch time taken there), the first non-zero command is timed here on the same machine's clock
   (median, p99 over --presses); the goal is p99 <= 30 ms on localhost;
2. e-stop round trip in the browser's clock (press -> the bridge's answer that it latched);
3. frames per second and frame age shown on the page (640x480 from the simulated camera);
4. the station process's CPU share (% of one core) over the run, and the load average.

Usage: python bench/bench_operator.py [--presses 30]   (after `source scripts/env.sh`)
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

from vla_common.ros.domain import isolate

isolate()  # before any rclpy context exists
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

import numpy as np  # noqa: E402
from launch_process import LaunchProcess, Observer  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from test_operator_station import Browser  # noqa: E402
from vla_common.ros.testing import RosHarness  # noqa: E402

PRESS = ("document.body.dispatchEvent(new KeyboardEvent('keydown', {key: 'ArrowUp', bubbles: true}));"
         "return performance.timeOrigin + performance.now();")
RELEASE = "document.body.dispatchEvent(new KeyboardEvent('keyup', {key: 'ArrowUp', bubbles: true}));"


class Cmds(Observer):
    def __init__(self, context):
        super().__init__(context, "bench_operator")
        self.first_move: float | None = None
        self.moving = False
        self.create_subscription(Float64MultiArray, "joint_velocity_cmd", self._cmd, 10)

    def _cmd(self, msg):
        self.moving = bool(np.any(np.abs(np.array(msg.data)) > 1e-6))
        if self.moving and self.first_move is None:
            self.first_move = time.time()


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def station_pid() -> int:
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                cmd = (p / "cmdline").read_bytes()
            except OSError:
                continue
            if b"lib/vla_operator/operator_station" in cmd and b"python" in cmd.split(b"\0")[0]:
                return int(p.name)
    raise RuntimeError("operator_station process not found")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presses", type=int, default=30)
    args = ap.parse_args()
    h = RosHarness()
    with LaunchProcess("vla_bringup", "teleop.launch.yaml", "use_operator_station:=true",
                       "operator_port:=0",
                       log_path=Path("/tmp") / f"bench_operator_{os.getpid()}.log") as run:
        obs = h.add(Cmds(h.context))
        addr = lambda: re.search(r"operator station is at (http://\S+)", run.text())  # noqa: E731
        if not h.spin_until(lambda: obs.graph_up() and addr() is not None, 120.0):
            print(run.text()[-2000:])
            return 1
        b = Browser()
        try:
            b.driver.get(addr().group(1))
            js = lambda e: b.driver.execute_script(f"return {e};")  # noqa: E731
            up = "window.station && window.station.driver && window.station.boxes.length > 0"
            h.spin_until(lambda: js(up), 60.0)
            pid = station_pid()
            c0, w0 = cpu_seconds(pid), time.monotonic()
            lat = []
            for _ in range(args.presses):
                h.spin_until(lambda: not obs.moving and obs.ctrl is not None and obs.ctrl.code == 1, 10.0)
                obs.first_move = None
                t0 = b.driver.execute_script(PRESS) / 1000.0
                if h.spin_until(lambda: obs.first_move is not None, 5.0):
                    lat.append(obs.first_move - t0)
                h.spin_for(0.2)
                b.driver.execute_script(RELEASE)
            h.spin_until(lambda: not obs.moving, 5.0)
            est = []
            for _ in range(5):
                b.driver.execute_script("document.getElementById('estop').click()")
                h.spin_until(lambda: js("window.station.estopLatency !== null"), 5.0)
                est.append(js("window.station.estopLatency"))
                b.driver.execute_script("document.getElementById('release-confirm').click()")
                h.spin_until(lambda: bool(obs.safety) and not obs.safety[-1].estop_active, 5.0)
            fps, age = js("window.station.fps"), js("window.station.age")
            cpu = 100.0 * (cpu_seconds(pid) - c0) / (time.monotonic() - w0)
        finally:
            b.quit()
        run.stop()
    h.shutdown()
    ms = np.array(lat) * 1000.0
    print(f"key press -> joint_velocity_cmd: median {np.median(ms):.1f} ms, "
          f"p99 {np.percentile(ms, 99):.1f} ms, max {ms.max():.1f} ms over {len(ms)} presses "
          "(goal p99 <= 30 ms)")
    print(f"e-stop press -> bridge latched (answer, browser clock): median {np.median(est):.0f} ms, "
          f"max {max(est):.0f} ms over {len(est)}")
    print(f"page: {fps:.1f} frames/s, frame age {age:.0f} ms")
    print(f"operator_station CPU: {cpu:.1f} % of one core")
    print(f"load average: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

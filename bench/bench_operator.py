"""Benchmark of the operator station (issue 22) with the browser in the loop: prints figures, asserts
nothing.

The shipped teleop.launch.yaml (use_operator_station:=true) on the simulated Panda and one headless
Chromium on its page. Every time is on this machine's wall clock: the browser's (performance.timeOrigin
+ now, its offset to ours read through WebDriver after each press, interpolated to it), the stamps DDS
puts on each sample (source: when it was published; received: when it reached this process's reader,
independent of when this process gets round to it) and the station's Joy stamp (arrival of the input at
the station):
1. key press -> joint_velocity_cmd latency over --presses (goal p99 <= 30 ms on localhost), split into
   page -> station (the Joy's stamp), station -> the controller's command (both publish stamps) and the
   command's delivery here; a press that gets no command says why (the page's last refusal, the
   station's counters);
2. e-stop press -> the bridge latched: the first panda_bridge/status with estop_active, by its publish
   stamp (the bridge publishes it inside the estop service, right after latching); and the answer's
   round trip in the browser's clock;
3. frames: the camera's rate (frames the station received), the frames it sent, and what the page
   showed (frames/s, frame age);
4. the station process's CPU share (% of one core) over the run, and the load average.

With --synthetic-camera HZ only the station runs (vla run), fed 640x480 rgb8 frames at HZ from here,
and the page's frame rate, the station's counters and its CPU share are printed: the station and the
page's share of the frame rate without the simulated camera, which falls behind real time on a loaded
machine (the bridge's exit line in the launch log says by how much, and how many frames it dropped).

With --browser-priority N Chromium runs at SCHED_FIFO N, as the nodes on the operator's path do
(`thread_priority`): the page as on a device of its own. On the 2-core machine the browser otherwise
waits behind the simulated robot's renderer like any other normal process.

Usage: python bench/bench_operator.py [--presses 100] [--synthetic-camera 30] [--browser-priority 10]
       (after `source scripts/env.sh`)
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from brief import parse
from vla_common.ros.domain import isolate
from vla_common.ros.qos import IMAGE_QOS, use_large_image_transport

isolate()  # before any rclpy context exists
use_large_image_transport()   # as the nodes: frames to the station through shared memory
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

import numpy as np  # noqa: E402
from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from launch_process import LaunchProcess, Observer  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Image, Joy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from test_operator_station import Browser, browser_offset  # noqa: E402
from vla_common.ros.testing import RosHarness  # noqa: E402
from vla_launch.run import find_executable  # noqa: E402

from vla_interfaces.msg import SafetyStatus  # noqa: E402

NOW = "performance.timeOrigin + performance.now()"
SKEW = 0.01   # s: the browser clock offset's uncertainty (measured: about 2 ms), with a margin
# The browser's clock against ours is read after every press (the best of this many WebDriver round
# trips) and interpolated to the press's time between that reading and the one before: on the shared
# VM our wall clock moved 5 ms per second against the browser's for minutes at a time, and in steps of
# up to 33 s, so one reading before the presses put 0.2-33 s into them. Read after the press, no round
# trip comes just before it (read just before it, the figures were the same: docs/history.md).
OFFSET_READS = 5
PRESS = (f"const t = {NOW};"
         "document.body.dispatchEvent(new KeyboardEvent('keydown', {key: 'ArrowUp', bubbles: true}));"
         "return t;")
RELEASE = "document.body.dispatchEvent(new KeyboardEvent('keyup', {key: 'ArrowUp', bubbles: true}));"
ESTOP = f"const t = {NOW}; document.getElementById('estop').click(); return t;"


def stamp(t) -> float:
    return t.sec + t.nanosec * 1e-9


class Probe(Observer):
    """Joy, commands and the bridge's status with their DDS stamps (seconds, wall clock)."""

    def __init__(self, context):
        super().__init__(context, "bench_operator")
        self.joy: list[tuple[float, float, float]] = []     # (axis, stamp, published)
        self.cmd: list[tuple[bool, float, float]] = []      # (moving, published, received)
        self.latch: list[float] = []                        # published, estop_active rising
        self.station: dict[str, str] = {}
        self._estop = False
        self.create_subscription(Float64MultiArray, "joint_velocity_cmd", self._cmd, 50)
        # best effort as the controller, but deep: this process is blocked in WebDriver calls at times
        self.create_subscription(Joy, "joy", self._joy, QoSProfile(
            reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=200))
        self.create_subscription(SafetyStatus, "panda_bridge/status", self._safety, 50)
        self.create_subscription(DiagnosticStatus, "operator_station/status", self._station, 10)

    def _cmd(self, msg, info):
        moving = bool(np.any(np.abs(np.array(msg.data)) > 1e-6))
        self.cmd.append((moving, info["source_timestamp"] * 1e-9, info["received_timestamp"] * 1e-9))

    def _joy(self, msg, info):
        self.joy.append((msg.axes[0] if msg.axes else 0.0, stamp(msg.header.stamp),
                         info["source_timestamp"] * 1e-9))

    def _safety(self, msg, info):
        if msg.estop_active and not self._estop:
            self.latch.append(info["source_timestamp"] * 1e-9)
        self._estop = msg.estop_active

    def _station(self, msg):
        self.station = {**{kv.key: kv.value for kv in msg.values}, "t": time.monotonic()}

    def moving(self) -> bool:
        return bool(self.cmd) and self.cmd[-1][0]


class BrowserClock:
    """The browser's clock against ours, read between presses and interpolated to each press."""

    def __init__(self, driver):
        self.driver = driver
        self.steps = 0                      # presses whose time is unknown: the clock stepped meanwhile
        self.last = self._read()

    def _read(self) -> tuple[float, float]:
        return time.time(), browser_offset(self.driver, OFFSET_READS)[0]

    def offset(self) -> float:
        return self.last[1]

    def ours(self, browser_t: float) -> float | None:
        """A past moment of the browser's clock (s) on ours, from the last reading and one taken now;
        None where the two readings disagree by more than SKEW (a step of the VM's clock between)."""
        (w0, o0), (w1, o1) = self.last, self._read()
        self.last = (w1, o1)
        if abs(o1 - o0) > SKEW:
            self.steps += 1
            return None
        f = min(max((browser_t - o0 - w0) / max(w1 - w0, 1e-9), 0.0), 1.0)
        return browser_t - (o0 + f * (o1 - o0))


def held_joy(joys: list[tuple[float, float, float]], t0: float) -> tuple[float, float, float] | None:
    """A press's Joy: the first held one stamped after the press. A late sample of the previous press's
    hold may still arrive (the stamp tells them apart), and this one may reach us after the command."""
    return next((j for j in joys if j[0] != 0.0 and j[1] >= t0 - SKEW), None)


def realtime(pids: list[int], priority: int) -> str:
    """Every thread of these processes at SCHED_FIFO `priority`; how many, or why not."""
    n = 0
    for pid in pids:
        for t in Path(f"/proc/{pid}/task").glob("*"):
            try:
                os.sched_setscheduler(int(t.name), os.SCHED_FIFO, os.sched_param(priority))
                n += 1
            except ProcessLookupError:
                pass
            except OSError as e:
                return f"refused ({e.strerror})"
    return f"{n} threads of {len(pids)} processes"


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


def figures(name: str, s: list[float], goal: str = "") -> str:
    ms = np.array(s) * 1000.0
    if ms.size == 0:
        return f"{name}: none"
    return (f"{name}: median {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, "
            f"max {ms.max():.1f} ms over {ms.size}{goal}")


class Camera(Node):
    """640x480 rgb8 frames at `rate` Hz: a textured scene with a moving patch (not trivially compressible),
    and the station's status."""

    def __init__(self, context, rate: float):
        super().__init__("bench_operator_camera", context=context)
        y, x = np.mgrid[0:480, 0:640]
        base = np.stack([(x * 255 // 639), (y * 255 // 479), ((x // 16 + y // 16) % 2) * 200], -1)
        noise = np.random.default_rng(0).integers(0, 40, (480, 640, 3))
        self.frames = []
        for i in range(30):
            f = (base + noise).astype(np.uint8)
            f[200:280, 20 * i:20 * i + 80] = (250, 60, 30)
            self.frames.append(f.tobytes())
        self.pub = self.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
        self.sent, self.station = 0, {}
        self.create_subscription(DiagnosticStatus, "operator_station/status", self._station, 10)
        self.joy: list[tuple[float, float, float]] = []   # (axis, stamp, received here by DDS)
        self.create_subscription(Joy, "joy", self._joy, QoSProfile(
            reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=200))
        self.create_timer(1.0 / rate, self._tick)

    def _joy(self, msg, info):
        self.joy.append((msg.axes[0] if msg.axes else 0.0, stamp(msg.header.stamp),
                         info["received_timestamp"] * 1e-9))

    def _station(self, msg):
        self.station = {**{kv.key: kv.value for kv in msg.values}, "t": time.monotonic()}

    def _tick(self):
        m = Image(height=480, width=640, encoding="rgb8", step=640 * 3)
        m.header.stamp = self.get_clock().now().to_msg()
        m.header.frame_id = "camera_optical_frame"
        m.data = self.frames[self.sent % len(self.frames)]
        self.pub.publish(m)
        self.sent += 1


def synthetic(rate: float, presses: int, seconds: float = 20.0) -> int:
    """Only the station, fed frames from here: its and the page's share of the frame rate, and of the
    key press latency (press -> the Joy's stamp, taken as the input arrives at the station)."""
    h = RosHarness(other_processes=True)   # it talks to the processes it starts
    cam = h.add(Camera(h.context, rate))
    log = Path("/tmp") / f"bench_operator_station_{os.getpid()}.log"
    with open(log, "wb") as out:
        cmd = [find_executable("vla_launch", "vla"), "run", "vla_operator", "operator_station",
               "--ros-args", "-p", "port:=0"]
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    b = None
    try:
        addr = lambda: re.search(r"operator station is at (http://\S+)", log.read_text())  # noqa: E731
        if not h.spin_until(lambda: addr() is not None, 60.0):
            print(log.read_text()[-2000:])
            return 1
        b = Browser()
        b.driver.get(addr().group(1))
        js = lambda e: b.driver.execute_script(f"return {e};")  # noqa: E731
        h.spin_until(lambda: js("window.station && window.station.fps > 0"), 30.0)
        h.spin_for(2.0)
        h.spin_until(lambda: "frames_received" in cam.station, 5.0)
        c0, w0, s0, n0 = cpu_seconds(proc.pid), time.monotonic(), dict(cam.station), cam.sent
        fps = []
        while time.monotonic() - w0 < seconds:
            h.spin_for(1.0)
            fps.append(js("window.station.fps"))
        cpu = 100.0 * (cpu_seconds(proc.pid) - c0) / (time.monotonic() - w0)
        sent_rate = (cam.sent - n0) / (time.monotonic() - w0)
        h.spin_for(1.2)
        s1 = cam.station
        age = js("window.station.age")
        arrive, here = [], []
        for _ in range(presses):
            n = len(cam.joy)
            off, _ = browser_offset(b.driver, OFFSET_READS)
            t0 = b.driver.execute_script(PRESS) / 1000.0 - off
            if h.spin_until(lambda n=n: any(j[0] != 0.0 for j in cam.joy[n:]), 5.0):
                j = next(j for j in cam.joy[n:] if j[0] != 0.0)
                arrive.append(j[1] - t0)
                here.append(j[2] - t0)
            h.spin_for(0.1)
            b.driver.execute_script(RELEASE)
            h.spin_for(0.1)
    finally:
        if b is not None:
            b.quit()
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
        h.shutdown()
    print(f"synthetic camera: {sent_rate:.1f} frames/s published (640x480 rgb8)")
    if "frames_sent" in s1 and "frames_sent" in s0:
        span = s1["t"] - s0["t"]
        keys = ("frames_received", "frames_encoded", "frames_sent")
        rates = [(int(s1[k]) - int(s0[k])) / span for k in keys]
        print("station: {:.1f} received, {:.1f} encoded, {:.1f} sent to the page per s".format(*rates))
    print(f"page: median {np.median(fps):.1f} frames/s (min {min(fps):.1f}, max {max(fps):.1f} over "
          f"{len(fps)} s), frame age {age:.0f} ms")
    print(f"operator_station CPU: {cpu:.1f} % of one core")
    print(figures("key press -> the station (Joy stamp)", arrive) + f" of {presses}")
    print(figures("key press -> its Joy received here", here))
    print(f"load average at the end: {os.getloadavg()}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presses", type=int, default=100,
                    help="key presses (p99 needs about 100: of 30 it is the slowest one)")
    ap.add_argument("--estops", type=int, default=10)
    ap.add_argument("--synthetic-camera", type=float, default=0.0, metavar="HZ",
                    help="only the station, fed 640x480 frames at HZ from here (the frame rate alone)")
    ap.add_argument("--browser-priority", type=int, default=0, metavar="N",
                    help="run Chromium's threads at SCHED_FIFO N (needs root or an rtprio limit): the "
                         "page as on a device of its own, not waiting behind the simulated robot")
    ap.add_argument("launch_args", nargs="*", metavar="NAME:=VALUE",
                    help="teleop.launch.yaml arguments (e.g. log_level:=debug)")
    args = parse(ap, presses=10, estops=3)
    print(f"load average at start: {os.getloadavg()}", flush=True)
    if args.synthetic_camera > 0:
        return synthetic(args.synthetic_camera, args.presses)
    h = RosHarness(other_processes=True)   # it talks to the processes it starts
    with LaunchProcess("vla_bringup", "teleop.launch.yaml", "use_operator_station:=true",
                       "operator_port:=0", *args.launch_args,
                       log_path=Path("/tmp") / f"bench_operator_{os.getpid()}.log") as run:
        obs = h.add(Probe(h.context))
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
            h.spin_until(lambda: "received" in obs.station, 5.0)
            if args.browser_priority:
                how = realtime(b.pids(), args.browser_priority)
                print(f"Chromium at SCHED_FIFO {args.browser_priority}: {how}")
            counters0 = dict(obs.station)
            off0, unc0 = browser_offset(b.driver)
            clock = BrowserClock(b.driver)
            pid = station_pid()
            c0, w0 = cpu_seconds(pid), time.monotonic()
            total, sent, here, to_station, to_cmd, lost, split = [], [], [], [], [], [], []
            for i in range(args.presses):
                h.spin_until(lambda: not obs.moving() and obs.ctrl is not None and obs.ctrl.code == 1, 10.0)
                nj, nc = len(obs.joy), len(obs.cmd)
                pressed = b.driver.execute_script(PRESS) / 1000.0
                near = pressed - clock.offset()    # to tell this press's Joy from the last one's
                moved = h.spin_until(lambda nc=nc: any(m for m, _, _ in obs.cmd[nc:]), 5.0)
                if moved:
                    h.spin_until(lambda nj=nj, t=near: held_joy(obs.joy[nj:], t) is not None, 1.0)
                h.spin_for(0.2)
                b.driver.execute_script(RELEASE)
                t0 = clock.ours(pressed)
                if moved and t0 is not None:
                    _, pub, rec = next(c for c in obs.cmd[nc:] if c[0])
                    joy = held_joy(obs.joy[nj:], near)
                    total.append(pub - t0)
                    here.append(rec - t0)
                    if joy is not None:
                        to_station.append(joy[1] - t0)
                        sent.append(joy[2] - t0)
                        to_cmd.append(pub - joy[2])
                        split.append((pub - t0, joy[1] - t0, joy[2] - joy[1], pub - joy[2]))
                elif not moved:
                    lost.append((i, js("window.station.refused"),
                                 obs.ctrl.reason if obs.ctrl is not None else "",
                                 any(j[0] != 0.0 for j in obs.joy[nj:])))
            h.spin_until(lambda: not obs.moving(), 5.0)
            off1, unc1 = browser_offset(b.driver)
            latch, answer = [], []
            for _ in range(args.estops):
                h.spin_for(0.3)
                n = len(obs.latch)
                pressed = b.driver.execute_script(ESTOP) / 1000.0
                latched = h.spin_until(lambda n=n: len(obs.latch) > n, 5.0)
                h.spin_until(lambda: js("window.station.estopLatency !== null"), 5.0)
                t0 = clock.ours(pressed)
                if latched and t0 is not None:
                    latch.append(obs.latch[n] - t0)
                answer.append(js("window.station.estopLatency") / 1000.0)
                b.driver.execute_script("document.getElementById('release-confirm').click()")
                h.spin_until(lambda: bool(obs.safety) and not obs.safety[-1].estop_active, 5.0)
            fps, age = js("window.station.fps"), js("window.station.age")
            wall = time.monotonic() - w0
            cpu = 100.0 * (cpu_seconds(pid) - c0) / wall
            h.spin_for(1.2)   # the station's next 1 Hz status
            counters1 = dict(obs.station)
        finally:
            b.quit()
        run.stop()
    h.shutdown()
    print(figures("key press -> joint_velocity_cmd published", total, " (goal p99 <= 30 ms)"))
    print(figures("  key press -> the station (Joy stamp)", to_station))
    print(figures("  key press -> the station's Joy published", sent))
    print(figures("  station's Joy published -> the controller's command", to_cmd))
    print(figures("  key press -> the command received here", here))
    print("  the 5 slowest presses (ms): total = page -> station + station's publish + station -> command")
    for tot, st, pb, cm in sorted(split, reverse=True)[:5]:
        print(f"    {tot * 1e3:6.1f} = {st * 1e3:6.1f} + {pb * 1e3:5.1f} + {cm * 1e3:6.1f}")
    print(f"  presses with no command within 5 s: {len(lost)} of {args.presses}"
          + "".join(f"\n    press {i}: page refusal {r!r}, controller {c!r}, Joy moved: {j}"
                    for i, r, c, j in lost))
    print(f"  browser clock offset {off0 * 1000:.1f} +- {unc0 * 1000:.1f} ms before the presses, "
          f"{off1 * 1000:.1f} +- {unc1 * 1000:.1f} ms after (read again after each press and e-stop; "
          f"{clock.steps} left out: the clock stepped by more than {SKEW * 1000:.0f} ms meanwhile)")
    print(figures("e-stop press -> bridge latched (its status published)", latch))
    print(figures("e-stop press -> the bridge's answer on the page (browser clock)", answer))
    diff = {k: int(counters1.get(k, 0)) - int(counters0.get(k, 0)) for k in counters1
            if k in counters0 and str(counters1[k]).lstrip("-").isdigit()}
    span = counters1.get("t", 0.0) - counters0.get("t", -1.0)
    print(f"station counters during the run: {diff}")
    print("frames/s over the run: camera -> station {:.1f}, encoded {:.1f}, sent to the page {:.1f}".format(
        *(diff.get(k, 0) / span for k in ("frames_received", "frames_encoded", "frames_sent"))))
    print(f"page: {fps:.1f} frames/s, frame age {age:.0f} ms")
    print(f"operator_station CPU: {cpu:.1f} % of one core")
    print(f"load average at the end: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

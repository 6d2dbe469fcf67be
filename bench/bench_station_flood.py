"""The operator station under a flood (issue 32, item 7): e-stop press -> the bridge's latch from the
operator's open page, without and with a junk flood from another local socket (the fastest a client can
send: pre-built frames, never reading, reconnecting when closed), and the station's memory and CPU.

The station and the bridge (ros2_control backend, no arm: its e-stop latches and publishes at once)
run as processes, as in the graph; the flooder too. The press is timed from just before the page's
message goes out to the publish stamp of the bridge's status that says it latched (one clock). Each
press of the page is followed by one sent straight to the bridge's ~/estop from this process: what the
machine's load costs at that moment, without the station.

    python bench/bench_station_flood.py                  # 50 presses each way, the flooder reconnecting,
                                                         # then 60 KB DDS statuses for 10 s, a page that
                                                         # never reads
    python bench/bench_station_flood.py --presses 20 --no-reconnect --status-flood 0
    python bench/bench_station_flood.py --quick          # CI: 20 presses, 3 s of statuses
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from brief import parse
from vla_common.ros.domain import isolate

isolate()   # a domain of its own, before rclpy starts
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

import numpy as np  # noqa: E402
from station_flood import (  # noqa: E402
    EstopPage,
    Flooder,
    address_of,
    estop_ready,
    handshake,
    latch_node,
    press_and_time,
    rss_mb,
    station_and_bridge,
)
from std_srvs.srv import SetBool  # noqa: E402
from vla_common.ros.testing import RosHarness  # noqa: E402


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def figures(name: str, s: list[float]) -> str:
    ms = np.array(s) * 1000.0
    return (f"{name}: median {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, "
            f"max {ms.max():.1f} ms over {ms.size}")


def status_flood(h, station, address: str, seconds: float) -> None:
    import rclpy

    from vla_interfaces.msg import SafetyStatus

    node = h.add(rclpy.create_node("bench_station_flood_status", context=h.context))
    pub = node.create_publisher(SafetyStatus, "panda_bridge/status", 10)
    silent = handshake(address)
    before, c0, t0 = rss_mb(station.proc.pid), cpu_s(station.proc.pid), time.monotonic()
    n, text, peak = 0, "x" * 60_000, before
    while time.monotonic() - t0 < seconds:
        pub.publish(SafetyStatus(code=0, text=text))
        n += 1
        if n % 20 == 0:
            h.spin_for(0.0)
            peak = max(peak, rss_mb(station.proc.pid))
    span = time.monotonic() - t0
    print(f"DDS status flood: {n / span:.0f} statuses/s of 60 KB for {span:.0f} s, a page that never reads: "
          f"station memory {before:.0f} -> peak {peak:.0f} MB, CPU "
          f"{100 * (cpu_s(station.proc.pid) - c0) / span:.0f} % of a core")
    silent.close()


def stale_view(h, page: EstopPage, cycles: int) -> None:
    """A camera at 30 Hz stops: time from its last frame to the page's state saying the view is stale
    (the station checks every 0.25 s for no frame in 1 s: at most 1.25 s plus delivery)."""
    import numpy as np
    import rclpy
    from sensor_msgs.msg import Image
    from vla_common.ros.qos import IMAGE_QOS

    node = h.add(rclpy.create_node("bench_station_flood_camera", context=h.context))
    pub = node.create_publisher(Image, "camera/image_raw", IMAGE_QOS)
    img = Image(height=48, width=64, encoding="rgb8", step=192, data=np.zeros(48 * 192, np.uint8).tobytes())
    on, last = [True], [0.0]

    def tick():
        if on[0]:
            pub.publish(img)
            last[0] = time.time()
    node.create_timer(1 / 30, tick)
    out = []
    for _ in range(cycles):
        on[0] = True
        if not h.spin_until(lambda: page.view_stale is False, 30.0):
            print("the view never came live")
            return
        h.spin_for(0.5)
        on[0] = False
        n = len(page.view_changes)
        if h.spin_until(lambda n=n: any(s for _, s in page.view_changes[n:]), 30.0):
            out.append(next(t for t, s in page.view_changes[n:] if s) - last[0])
    print(figures(f"camera stopped -> the page's state says the view is stale ({cycles} stops)", out))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presses", type=int, default=50)
    ap.add_argument("--no-reconnect", action="store_true", help="the flooder stops once closed")
    ap.add_argument("--status-flood", type=float, default=10.0, metavar="S",
                    help="seconds of 60 KB DDS statuses after the junk flood (0: none)")
    ap.add_argument("--quick", action="store_true", help="20 presses each way, 3 s of status flood (CI)")
    a = parse(ap, presses=5, status_flood=1.0)
    if a.quick:
        a.presses, a.status_flood = 20, min(a.status_flood, 3.0)
    tmp = Path(tempfile.mkdtemp(prefix="bench_station_flood_"))
    h = RosHarness(other_processes=True)
    station, bridge = station_and_bridge(tmp)
    page = None
    try:
        latches = h.add(latch_node(h.context))
        if not h.spin_until(lambda: address_of(station) is not None and latches.latched is False, 120.0):
            print(station.text()[-2000:], bridge.text()[-2000:])
            return 1
        address = address_of(station)
        page = EstopPage(address)
        if not estop_ready(h, page, latches):
            print("the station never reached the bridge's e-stop service")
            return 1
        press_and_time(h, page, latches, 5)
        pid = station.proc.pid
        direct = latches.create_client(SetBool, "panda_bridge/estop")
        direct.wait_for_service(timeout_sec=30.0)
        base, base_straight = press_and_time(h, page, latches, a.presses, direct=direct)
        before = rss_mb(pid)
        flooder = Flooder(address, reconnect=not a.no_reconnect, log=tmp / "flooder.log")
        h.spin_for(1.0)
        c0, t0 = cpu_s(pid), time.monotonic()
        flooded, straight = press_and_time(h, page, latches, a.presses, direct=direct)
        cpu = 100 * (cpu_s(pid) - c0) / (time.monotonic() - t0)
        peak = rss_mb(pid)
        sent = flooder.stop()
        h.spin_for(5.0)
        after = rss_mb(pid)
        print(figures("e-stop, the page -> bridge latched, no flood", base))
        print(figures("e-stop, straight to the bridge (no station), no flood", base_straight))
        print(figures("e-stop, the page -> bridge latched, junk flood", flooded))
        print(figures("e-stop, straight to the bridge (no station), junk flood", straight))
        print(f"flooder: {sent.get('sent', 0)} messages written in {sent.get('connections', 0)} connections "
              f"(each closed by the station), {sent.get('refused', 0)} handshakes refused")
        print(f"station: memory {before:.0f} MB before, {peak:.0f} MB flooded, {after:.0f} MB 5 s after; CPU "
              f"{cpu:.0f} % of a core flooded; operator's page {'closed' if page.closed else 'open'}")
        if a.status_flood > 0:
            status_flood(h, station, address, a.status_flood)
        stale_view(h, page, 5 if a.quick else 20)
        print(f"load average at the end: {os.getloadavg()}")
    finally:
        if page is not None:
            page.close()
        station.stop()
        bridge.stop()
        h.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

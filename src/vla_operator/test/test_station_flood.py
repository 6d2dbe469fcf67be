"""One socket cannot starve the others (issue 32, item 7), with the station and the bridge as processes:

- junk at the fastest rate a local client can send (a raw socket writing pre-built frames and never
  reading, reconnecting each time it is closed): the operator's open page's e-stop still latches the
  bridge, p99 over 20 presses within 100 ms plus a stated margin over this run's own baseline (e-stops
  sent straight to the bridge, interleaved with the page's, in the same flood; the rule: no bare
  wall-clock bounds), and the station's memory comes back within 10 % of its level before the flood;
- a DDS peer publishing 60 KB status texts as fast as it can while a page reads nothing: the station's
  memory stays bounded.

The figures on a quiet machine are bench/bench_station_flood.py's.
"""
from __future__ import annotations

import numpy as np
import pytest
from station_flood import (
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
from std_srvs.srv import SetBool
from vla_common.ros.testing import RosHarness

pytestmark = [pytest.mark.slow, pytest.mark.ros]

ESTOP_BOUND = 0.100     # s, the p99 bound from the press to the bridge's latch
# The margin: twice the p99 of e-stops sent straight to the bridge from this process, each right after
# a page's, during the same flood (the machine's own delays then, which the station cannot change; on
# 2 shared cores at load 10-16 they reach 50-300 ms).
MARGIN = 2.0


@pytest.fixture
def graph(tmp_path):
    h = RosHarness(other_processes=True)
    station, bridge = station_and_bridge(tmp_path)
    try:
        latches = h.add(latch_node(h.context))
        assert h.spin_until(lambda: address_of(station) is not None and latches.latched is False, 120.0), \
            station.text()[-2000:] + bridge.text()[-2000:]
        yield h, station, latches, address_of(station)
    finally:
        assert station.stop() == 0, station.text()[-3000:]
        bridge.stop()
        h.shutdown()


def settle_rss(h, pid: int) -> float:
    """The process's memory once it stops changing (2 s apart within 1 MB), or after 20 s."""
    last = rss_mb(pid)
    for _ in range(10):
        h.spin_for(2.0)
        now = rss_mb(pid)
        if abs(now - last) < 1.0:
            return now
        last = now
    return last


def test_a_junk_flood_does_not_delay_another_pages_estop_or_keep_memory(graph, tmp_path):
    h, station, latches, address = graph
    page = EstopPage(address)
    try:
        assert estop_ready(h, page, latches), station.text()[-2000:]
        press_and_time(h, page, latches, 5)                     # warm: the service's first calls
        base = press_and_time(h, page, latches, 10)
        before = settle_rss(h, station.proc.pid)
        direct = latches.create_client(SetBool, "panda_bridge/estop")
        assert direct.wait_for_service(timeout_sec=30.0)
        flooder = Flooder(address, reconnect=True, log=tmp_path / "flooder.log")
        try:
            h.spin_for(1.0)                                     # the flood is on
            flooded, straight = press_and_time(h, page, latches, 20, direct=direct)
            peak = rss_mb(station.proc.pid)
            newcomer = EstopPage(address)                       # a new page opens during the flood
            try:                                                # (issue 32: new pages timed out)
                assert h.spin_until(lambda: newcomer.got >= 2, 30.0)    # hello, role or state
            finally:
                newcomer.close()
        finally:
            sent = flooder.stop()
        after = settle_rss(h, station.proc.pid)
        p99, p99_straight = np.percentile(flooded, 99), np.percentile(straight, 99)
        calm = np.percentile(base, 99)
        figures = (f"e-stop p99 through the page {p99 * 1e3:.1f} ms flooded, straight to the bridge "
                   f"{p99_straight * 1e3:.1f} ms flooded, through the page {calm * 1e3:.1f} ms not "
                   f"flooded; memory {before:.0f} -> {peak:.0f} -> {after:.0f} MB; flooder {sent}")
        assert sent.get("sent", 0) > 0 and sent.get("connections", 0) >= 1, figures
        assert p99 <= ESTOP_BOUND + MARGIN * p99_straight, figures
        assert after <= before * 1.10, figures
        assert not page.closed, figures                         # the operator's page is still open
    finally:
        page.close()


def test_a_dds_status_flood_with_a_page_that_never_reads_keeps_memory_bounded(graph, tmp_path):
    from vla_interfaces.msg import SafetyStatus

    h, station, latches, address = graph
    node = h.add(__import__("rclpy").create_node("station_flood_status", context=h.context))
    pub = node.create_publisher(SafetyStatus, "panda_bridge/status", 10)
    silent = handshake(address)            # a page that opened its socket and never reads from it
    try:
        before = settle_rss(h, station.proc.pid)
        text = "x" * 60_000
        import time
        end, n = time.monotonic() + 10.0, 0
        while time.monotonic() < end:       # as fast as this process can (issue 32: 350 Hz)
            pub.publish(SafetyStatus(code=0, text=text))
            n += 1
            if n % 20 == 0:
                h.spin_for(0.0)
        grown = rss_mb(station.proc.pid) - before
        assert n > 1000, n
        assert grown < 50.0, f"{grown:.0f} MB more after {n} statuses of 60 KB (before: {before:.0f} MB)"
    finally:
        silent.close()

"""`vla launch teleop.launch.yaml use_sim_time:=true` stops on Ctrl-C within 2 s, asserted in the
nodes' own terms: the launch sends SIGINT to every node at once (a "sending signal 'SIGINT' to
process[...]" line each, as ros2 launch words it), and every node ends within 2 s of it, so the launch never
escalates to SIGTERM (`--sigterm-timeout 2`); five times in a row. The stop time is printed; its
median and p99 come from `bench/bench_launch.py`. The 2 s bound is the requirement; measured
(`bench/bench_launch.py --runs 5 --launch-arg use_sim_time:=true`, 2026-12-03, load 3.6 on the 2
cores): Ctrl-C to exit median 0.72 s, max 0.77 s, no escalation: a 2.6x margin."""
from __future__ import annotations

import re

import pytest
from launch_process import LaunchProcess, Observer
from vla_common.ros.testing import RosHarness

pytestmark = [pytest.mark.slow, pytest.mark.ros]

NODES = {"panda_bridge", "detector_node", "controller_node"}


@pytest.mark.timeout(600)
def test_teleop_launch_stops_on_sigint_without_escalating_five_times(tmp_path):
    times = []
    for i in range(5):
        h = RosHarness(other_processes=True)
        try:
            with LaunchProcess("--sigterm-timeout", "2", "vla_bringup", "teleop.launch.yaml",
                               "use_sim_time:=true", log_path=tmp_path / f"launch{i}.log") as run:
                obs = h.add(Observer(h.context, f"test_observer_{i}"))
                assert h.spin_until(obs.graph_up, 90.0), run.text()[-3000:]
                # Our node goes before the graph does: Fast DDS 2.14 deadlocked (once, in CI) when this
                # process deleted a writer while another of its participants removed the stopped
                # graph's (lock order writer -> PDP against PDP -> writer; eProsima/Fast-DDS #6193)
                h.shutdown()
                rc = run.stop()
                out = run.text()
                assert rc == 0, out[-3000:]
                assert out.count("sending signal 'SIGINT' to process[") == len(NODES), out[-3000:]
                assert "SIGTERM" not in out and "SIGKILL" not in out, out[-3000:]
                stopped = set(re.findall(r"\[(\w+)-\d+\]: process has finished cleanly", out))
                assert stopped == NODES, out[-3000:]
                times.append(round(run.stop_s, 2))
        finally:
            h.shutdown()
    print(f"launch stopped {times} s after SIGINT")

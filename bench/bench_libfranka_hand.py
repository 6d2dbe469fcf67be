"""Benchmark of the libfranka hand against franka-sim's gripper server: prints figures, asserts nothing.

The node's hand driver (`libfranka_hand.HandProcess`, libfranka's Gripper in a process of its own
joined to franka-sim's private network namespace) behind `GripperCore`, polled as the node's timer
polls it. franka-sim's hand is kinematic (a command ends at once), so the figures are the driver's
own overhead: the process hop, the wait for the hand's next state datagram (franka-sim sends them
at 60 Hz) and the report period.

Figures, per binding (pylibfranka, panda_py):
1. connect: from starting the hand process to the core's first IDLE (s);
2. request -> done: from an accepted request to the core's IDLE (a move) or HOLDING (a grasp of
   the virtual object) (median, p90, max, in ms);
3. the GIL: in a process whose one thread calls Gripper.read_once in a loop, the longest gap of
   another thread that sleeps 1 ms (the reason the Gripper lives in its own process).

Usage: python bench/bench_libfranka_hand.py [--runs 20] [--json] (after source scripts/env.sh)
Needs .venv-franka-sim (scripts/setup_franka_sim.sh), pylibfranka, panda-python, root for namespaces.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
from brief import parse, skipped
from vla_panda_bridge.gripper import GripperCore
from vla_panda_bridge.libfranka_hand import HandProcess

from vla_panda_bridge import gripper

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "test"))     # franka_sim_server: test support, not a package
from franka_sim_server import FrankaSimServer, Netns, unavailable  # noqa: E402

OBJECT = 0.03
GIL_PROBE = r"""
import sys, threading, time
if sys.argv[1] == "panda_py":
    from panda_py.libfranka import Gripper
else:
    from pylibfranka import Gripper
g = Gripper("127.0.0.1")
stop = False
def reader():
    while not stop:
        g.read_once()
t = threading.Thread(target=reader)
t.start()
gaps, last, end = [], time.monotonic(), time.monotonic() + 2.0
while last < end:
    time.sleep(0.001)
    now = time.monotonic()
    gaps.append(now - last)
    last = now
stop = True
t.join()
print(max(gaps))
"""


def _ms(values: list[float]) -> dict:
    a = np.asarray(values) * 1e3
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max())}


def bench(binding: str, ns: Netns, runs: int) -> dict:
    t0 = time.monotonic()
    hand = HandProcess("127.0.0.1", 0.08, binding, ns.prefix())
    core = GripperCore(hand, min_interval=0.0)
    tick = iter(range(1, 10**9))

    def until(cond, timeout=10.0) -> float:
        start = time.monotonic()
        while time.monotonic() - start < timeout:
            core.update(next(tick))
            if cond():
                return time.monotonic() - start
            time.sleep(0.001)                       # the node polls at its state rate; 1 kHz here
        raise RuntimeError(f"timed out: {core.status}")
    try:
        until(lambda: core.status.state == gripper.IDLE)
        connect = time.monotonic() - t0
        moves, grasps = [], []
        for _ in range(runs):
            assert core.request(gripper.OPEN, next(tick))[0]
            moves.append(until(lambda: core.status.state == gripper.IDLE))
            assert core.request(gripper.GRASP, next(tick), width=OBJECT)[0]
            grasps.append(until(lambda: core.status.state == gripper.HOLDING))
    finally:
        hand.close()
    probe = subprocess.run([*ns.prefix(), sys.executable, "-c", GIL_PROBE, binding], capture_output=True,
                           text=True, timeout=60)
    gil = float(probe.stdout.strip()) if probe.returncode == 0 else float("nan")
    return {"connect_s": connect, "move_ms": _ms(moves), "grasp_ms": _ms(grasps), "gil_gap_ms": gil * 1e3}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--json", action="store_true")
    args = parse(ap, runs=2)
    reason = unavailable()
    if reason:
        return skipped("FRANKA_SIM", f"bench_libfranka_hand: {reason}")
    load = os.getloadavg()[0]
    ns = Netns()
    server = FrankaSimServer(ns, gripper=True, gripper_object_width=OBJECT)
    try:
        server.start()
        results = {b: bench(b, ns, args.runs) for b in ("pylibfranka", "panda_py")}
    finally:
        server.stop()
        ns.close()
    results["load_average_at_start"] = load
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    print(f"load average at start {load:.2f}; {args.runs} runs per figure; franka-sim hand states at 60 Hz")
    for b in ("pylibfranka", "panda_py"):
        r = results[b]
        m, g = r["move_ms"], r["grasp_ms"]
        print(f"{b:12s} connect {r['connect_s']:.2f} s | open -> IDLE median {m['median']:.1f} ms "
              f"p90 {m['p90']:.1f} max {m['max']:.1f} | grasp -> HOLDING median {g['median']:.1f} ms "
              f"p90 {g['p90']:.1f} max {g['max']:.1f} | GIL: longest gap of a 1 ms sleeper beside "
              f"read_once {r['gil_gap_ms']:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())

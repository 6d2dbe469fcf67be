#!/usr/bin/env python3
"""Minimal pylibfranka joint-velocity probe against a running franka-sim (or FR3).

Starts nothing itself: start the server first (see src/vla_panda_bridge/README.md, "franka-sim"), e.g.

    scripts/setup_franka_sim.sh
    FR3_MJCF=.venv-franka-sim/fr3_mjcf/fr3.xml .venv-franka-sim/bin/run-franka-sim-server --no-gripper &

and run this with a Python that has ``pylibfranka==0.21.3`` (a separate venv, not the
franka-sim one: keep the simulator independent of the client under test), e.g.
``python3 -m venv /tmp/pylf-venv && /tmp/pylf-venv/bin/pip install pylibfranka==0.21.3 numpy==2.4.6``:

    python scripts/probe_franka_sim.py --joint 4 --velocity 0.2 --seconds 1.5

It connects to 127.0.0.1 (``--host``), runs joint-velocity control for ``--seconds``
(robot time) at a constant ``--velocity`` on one joint (smooth cosine ramps of ``--ramp`` s at
both ends so the command stays continuous; ``--ramp 0`` gives a velocity step,
which ``--enforce-motion-limits`` rejects), finishes the motion with
``motion_finished = True`` and prints: cycle-time statistics of the pure-Python
readOnce/writeOnce loop, the robot-side cycle count (``Duration`` per readOnce,
so missed 1 ms cycles show up), ``control_command_success_rate`` and the
commanded (integrated) vs measured joint displacement.

``--busy-thread`` runs a CPU-bound Python thread beside the loop and reports how
far it got, which shows whether readOnce releases the GIL (it does not in 0.21.3).
Exit status: 0 on success, 2 when libfranka raised (the exception is printed).
"""

import argparse
import json
import math
import statistics
import sys
import threading
import time


def percentile(values, q):
    if not values:
        return float("nan")
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, int(math.ceil(q / 100.0 * len(ordered))) - 1))
    return ordered[index]


def ramp(t, total, ramp_s):
    """0..1 profile: cosine ramp up over ramp_s, hold, cosine ramp down to 0 at total."""
    if ramp_s <= 0.0:
        return 1.0 if t < total else 0.0
    up = min(1.0, t / ramp_s)
    down = min(1.0, max(0.0, (total - t) / ramp_s))
    s = min(up, down)
    return 0.5 - 0.5 * math.cos(math.pi * s)


class BusyThread(threading.Thread):
    """Pure-Python CPU load in this process: counts loop iterations until stopped."""

    def __init__(self):
        super().__init__(daemon=True, name="busy")
        self.count = 0
        self.stop = False

    def run(self):
        n = 0
        while not self.stop:
            n += 1
            if n % 1000 == 0:
                self.count = n
        self.count = n


def run(args):
    import pylibfranka as franka

    joint = args.joint - 1
    robot = franka.Robot(args.host, franka.RealtimeConfig.kIgnore)
    if args.collision_behavior:
        # Generous thresholds (the libfranka examples' values): no spurious reflexes.
        robot.set_collision_behavior([100.0] * 7, [100.0] * 7, [100.0] * 6, [100.0] * 6)
    start_state = robot.read_once()
    q_start = list(start_state.q)
    print(
        f"connected to {args.host}: robot_mode={start_state.robot_mode.name} "
        f"q={[round(x, 4) for x in q_start]}"
    )

    busy = BusyThread() if args.busy_thread else None
    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval)

    control = robot.start_joint_velocity_control(franka.ControllerMode.JointImpedance)
    periods, read_blocked, robot_dt, rates = [], [], [], []
    integrated = 0.0
    robot_time = 0.0
    last_cmd = 0.0
    cycles = 0
    error = None
    if busy is not None:
        busy.start()
    t0 = time.perf_counter()
    last = None
    try:
        while True:
            before = time.perf_counter()
            state, duration = control.readOnce()
            now = time.perf_counter()
            read_blocked.append(now - before)
            if last is not None:
                periods.append(now - last)
            last = now
            dt = duration.to_sec()
            robot_dt.append(dt)
            integrated += last_cmd * dt
            rates.append(state.control_command_success_rate)
            # Profile in robot time (sum of the Durations), not wall time: when the host is
            # overloaded franka-sim itself slows down, and a wall-clock profile would then
            # take bigger steps per robot cycle (jerk violations on the ramps).
            t = robot_time = robot_time + dt
            v = args.velocity * ramp(t, args.seconds, args.ramp)
            dq = [0.0] * 7
            dq[joint] = v
            cmd = franka.JointVelocities(dq)
            if t >= args.seconds:
                cmd.motion_finished = True
            control.writeOnce(cmd)
            last_cmd = v
            cycles += 1
            if cmd.motion_finished:
                break
    except RuntimeError as exc:  # ControlException, NetworkException, CommandException are RuntimeErrors
        error = exc
    elapsed = time.perf_counter() - t0
    if busy is not None:
        busy.stop = True
        busy.join()

    # After motion_finished do NOT call control.readOnce() again: in 0.21.3 it blocks
    # forever (waits for a Move response that was already consumed). Use robot.read_once().
    final = None
    settle_deadline = time.monotonic() + 2.0
    if error is None or isinstance(error, franka.ControlException):
        try:
            while True:
                final = robot.read_once()
                if max(abs(x) for x in final.dq) < 1e-3 or time.monotonic() > settle_deadline:
                    break
        except RuntimeError as exc:
            print(f"read_once after the motion failed: {type(exc).__name__}: {exc}")

    ms = [p * 1e3 for p in periods]
    blocked = [b * 1e3 for b in read_blocked]
    robot_ticks = round(sum(robot_dt) * 1000.0)
    report = {
        "cycles": cycles,
        "elapsed_s": round(elapsed, 4),
        "loop_hz": round(cycles / elapsed, 1) if elapsed > 0 else None,
        "period_ms": {
            "median": round(statistics.median(ms), 3) if ms else None,
            "p99": round(percentile(ms, 99), 3),
            "max": round(max(ms), 3) if ms else None,
            "over_1.5ms": sum(1 for p in ms if p > 1.5),
        },
        "readOnce_blocked_ms_median": round(statistics.median(blocked), 3) if blocked else None,
        "robot_ticks": robot_ticks,
        "missed_robot_cycles": robot_ticks - cycles + 1 if cycles else 0,
        "max_robot_dt_ms": round(max(robot_dt) * 1e3, 3) if robot_dt else None,
        "success_rate": {
            "min_after_100": round(min(rates[100:]), 3) if len(rates) > 100 else None,
            "mean": round(statistics.fmean(rates), 4) if rates else None,
            "last": round(rates[-1], 3) if rates else None,
        },
    }
    if final is not None:
        report["joint"] = args.joint
        report["integrated_rad"] = round(integrated, 5)
        report["measured_rad"] = round(final.q[joint] - q_start[joint], 5)
        report["final_robot_mode"] = final.robot_mode.name
        report["current_errors"] = str(final.current_errors)
        report["last_motion_errors"] = str(final.last_motion_errors)
    if busy is not None:
        report["busy_thread_iterations_per_s"] = round(busy.count / elapsed)
    if error is not None:
        report["exception"] = {"type": type(error).__name__, "message": str(error)}
    if args.json:
        print(json.dumps(report))
    else:
        for key, value in report.items():
            print(f"{key}: {value}")
    if error is not None and args.recover:
        try:
            robot.automatic_error_recovery()
            print("automatic_error_recovery: ok, robot_mode", robot.read_once().robot_mode.name)
        except RuntimeError as exc:
            print(f"automatic_error_recovery failed: {type(exc).__name__}: {exc}")
    return 0 if error is None else 2


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--joint", type=int, default=4, choices=range(1, 8), metavar="1..7")
    parser.add_argument("--velocity", type=float, default=0.2, help="rad/s (default 0.2)")
    parser.add_argument("--seconds", type=float, default=1.5)
    parser.add_argument("--ramp", type=float, default=0.2, help="ramp time in s; 0 = step")
    parser.add_argument(
        "--busy-thread", action="store_true", help="run a CPU-bound Python thread beside the loop (GIL test)"
    )
    parser.add_argument(
        "--switch-interval",
        type=float,
        default=0.0,
        help="sys.setswitchinterval value (default: Python's 0.005 s)",
    )
    parser.add_argument(
        "--collision-behavior", action="store_true", help="set generous collision thresholds before moving"
    )
    parser.add_argument(
        "--recover", action="store_true", help="call automatic_error_recovery() after an exception"
    )
    parser.add_argument("--json", action="store_true", help="one JSON line instead of key: value")
    args = parser.parse_args(argv)
    try:
        return run(args)
    except RuntimeError as exc:
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

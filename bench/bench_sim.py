"""Simulator speed: physics real-time factor without rendering (target >= 20x) and with the camera
rendering at 30 Hz (target >= 2x), and render time per frame at 320x240 and 640x480. And how the
simulated arm keeps to the Panda's table: max |dq|/dq_max and |ddq|/ddq_max measured on the physics
clock (finite differences of q at 1 kHz) for the command streams of src/vla_sim/test/test_arm_limits.py
run through the SafetyFilter (the test asserts <= 1).

The arm follows a slow sinusoidal joint-velocity command over a 3-object layout so contacts and
servos are exercised. Real-time factors are measured per simulated second (median and the worst
1 % = p1 of the factor); render times per frame (median, p99).

    MUJOCO_GL=egl python bench/bench_sim.py [--seconds 10] [--frames 200]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from brief import parse

os.environ.setdefault("MUJOCO_GL", "egl")

from vla_sim.sim import PandaSim  # noqa: E402

LAYOUT = [("bread", 0.45, 0.2, 0.3), ("soda_can", 0.6, 0.0, 0.0), ("cereal_box", 0.5, -0.25, 1.0)]


def command(t: float) -> np.ndarray:
    return 0.3 * np.sin(2 * np.pi * 0.2 * t + np.arange(7))


def run(sim: PandaSim, seconds: float, camera_hz: float | None) -> np.ndarray:
    """Real-time factor of each simulated second."""
    sim.reset(objects=LAYOUT)
    steps_per_s = int(round(1.0 / sim.physics_dt))
    frame_every = None if camera_hz is None else 1.0 / camera_hz
    next_frame = 0.0
    factors = []
    for _ in range(int(seconds)):
        t0 = time.perf_counter()
        for _ in range(steps_per_s // 10):  # command updated at 50 Hz of sim time, as a node would
            sim.set_velocity_command(command(sim.time))
            sim.step(10)
            if frame_every is not None and sim.time >= next_frame:
                sim.render()
                next_frame += frame_every
        factors.append(1.0 / (time.perf_counter() - t0))
    return np.array(factors)


def render_times(sim: PandaSim, width: int, height: int, frames: int) -> np.ndarray:
    sim.set_camera_size(width, height)
    sim.render()  # context / buffers
    out = []
    for _ in range(frames):
        sim.set_velocity_command(command(sim.time))
        sim.step(17)
        t0 = time.perf_counter()
        sim.render()
        out.append(time.perf_counter() - t0)
    return np.array(out) * 1e3


def limits() -> None:
    """The arm's measured motion per filtered stream (the streams and driver of test_arm_limits)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "vla_sim" / "test"))
    import test_arm_limits as t  # the test's streams: one home for them

    sim = PandaSim(render=False, physics_dt=t.DT)
    for name, make in t.STREAMS.items():
        for seed in (0, 1):
            sim.torque_limited_steps = 0
            qs, _, touched = t._drive(sim, make(np.random.default_rng(seed)))
            rv, ra, _ = t._measured_ratios(qs)
            print(f"  {name:26s} seed {seed}: max |dq|/dq_max {rv:.9f}  |ddq|/ddq_max {ra:.9f}  "
                  f"torque-limited steps {sim.torque_limited_steps}{'  (contact!)' if touched else ''}")
    sim.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per real-time-factor run")
    ap.add_argument("--frames", type=int, default=200, help="frames per render-time measurement")
    args = parse(ap, seconds=1.0, frames=10)

    print("measured motion / limit table, filtered streams into the simulated arm (1 kHz):")
    limits()

    print(f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}  cpu cores={os.cpu_count()}")
    sim = PandaSim(render=False)
    print(f"physics dt = {sim.physics_dt * 1e3:.1f} ms")
    f = run(sim, args.seconds, None)
    print(f"physics only            : real-time factor median {np.median(f):6.1f}x  "
          f"p1 {np.percentile(f, 1):6.1f}x  (target >= 20x)")
    sim.close()

    for w, h in ((640, 480), (320, 240)):
        rsim = PandaSim(camera_width=w, camera_height=h, render=True)
        f = run(rsim, args.seconds, 30.0)
        print(
            f"camera 30 Hz {w}x{h:<4}   : real-time factor median {np.median(f):6.1f}x  "
            f"p1 {np.percentile(f, 1):6.1f}x  (target >= 2x)"
        )
        rsim.close()

    rsim = PandaSim(render=True)
    for w, h in ((320, 240), (640, 480)):
        ms = render_times(rsim, w, h, args.frames)
        print(f"render {w}x{h:<4}          : median {np.median(ms):6.2f} ms  "
              f"p99 {np.percentile(ms, 99):6.2f} ms  max {ms.max():6.2f} ms")
    rsim.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What Ray costs per unit of a sweep (issue 35): the same units run directly (`--serial`, in this
process) and on a local Ray with one worker (units one after another, so that each interval between
two results is one unit plus the engine's cost). Prints the median interval of each, their difference
(the per-unit overhead) and Ray's start-up; the first unit on Ray (the worker's start) is left out.

    python bench/bench_ray_overhead.py [--units 20] [--work-ms 50]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
from brief import parse
from vla_evaluation.sweep import Engine, run_sweep


def matrix() -> np.ndarray:
    return np.random.default_rng(0).standard_normal((96, 96))


def reps_for(work_ms: float) -> int:
    """How many matrix products make `work_ms` here (measured once, in the driver)."""
    a, t0, n = matrix(), time.perf_counter(), 0
    while time.perf_counter() - t0 < 0.5:
        a @ a
        n += 1
    return max(1, int(n * work_ms / 500.0))


class Busy:
    """A unit of fixed CPU work (the same number of matrix products everywhere), returning a small row."""

    def __init__(self, reps: int) -> None:
        self.a, self.reps = matrix(), reps

    def run(self, unit: int) -> dict:
        t0 = time.perf_counter()
        for _ in range(self.reps):
            self.a @ self.a
        return {"unit": unit, "work_s": time.perf_counter() - t0}

    def close(self) -> None:
        pass


def intervals(engine: Engine, units: int, reps: int) -> tuple[list[float], list[float], float]:
    """Seconds between consecutive results (after the first), the same less the unit's own work time
    (measured in the unit, under the same load: what the engine adds), and the whole wall time."""
    stamps: list[float] = []
    work: list[float] = []

    def on_result(key, row) -> None:
        stamps.append(time.perf_counter())
        work.append(row["work_s"])

    t0 = time.perf_counter()
    run_sweep([(f"u{i}", i) for i in range(units + 1)], Busy, engine=engine, shared=reps,
              on_result=on_result, log=lambda s: None)
    gaps = list(np.diff(stamps))
    return gaps, [g - w for g, w in zip(gaps, work[1:])], time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--units", type=int, default=20, help="units measured (one more is run first)")
    p.add_argument("--work-ms", type=float, default=50.0, help="CPU work in each unit (ms)")
    a = parse(p, argv, units=3)
    reps = reps_for(a.work_ms)
    direct, direct_extra, direct_wall = intervals(Engine(serial=True), a.units, reps)
    on_ray, ray_extra, ray_wall = intervals(Engine(cpus=1), a.units, reps)
    ms = lambda xs: 1000 * statistics.median(xs)  # noqa: E731
    print(f"{a.units} units of {a.work_ms:g} ms of work each; medians of the {a.units} intervals between "
          "results, and of each interval less its unit's own work time")
    for name, gaps, extra, wall in (("direct (in this process)", direct, direct_extra, direct_wall),
                                    ("Ray, one local worker", on_ray, ray_extra, ray_wall)):
        print(f"  {name:26s}{ms(gaps):8.1f} ms per unit, {ms(extra):6.2f} ms beyond the work   "
              f"({wall:.1f} s in all)")
    print(f"  per-unit overhead of Ray  {ms(ray_extra) - ms(direct_extra):8.2f} ms; Ray's start-up and the "
          f"worker's first unit {ray_wall - sum(on_ray):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

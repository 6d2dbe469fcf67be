"""The whole base task through the operator station's page (issue 32 item 5): time to success.

The bread pushed east by a scripted keyboard user, single-switch user and gamepad user
(test/page_persons.py: each holds "toward the task", lets go and presses again when the page says
"Let go") in headless Chromium, on the study's graph for a real participant (test/page_task.py:
demo.launch.yaml with the station, real time, the scene reset to a fresh layout per trial). Per person
and run: success, the time to success in simulated s (the evaluation's judge) and in wall s from the
first press, the presses, and the load average. Prints figures, asserts nothing.

    python bench/bench_operator_task.py [--runs 3] [--first-seed 300000]   (after source scripts/env.sh)
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

from brief import parse

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from page_persons import PERSONS  # noqa: E402
from page_task import SEED, push_bread_east, station_graph  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="trials per person (one layout each)")
    ap.add_argument("--first-seed", type=int, default=SEED, help="the first run's layout seed")
    a = parse(ap, runs=1)
    print(f"load average at start: {os.getloadavg()} on {os.cpu_count()} CPUs", flush=True)
    rows: dict[str, list[dict]] = {p.name: [] for p in PERSONS}
    t0 = time.monotonic()
    with station_graph() as (ev, b):
        for run in range(a.runs):
            for person in PERSONS:
                r = push_bread_east(ev, b, person, a.first_seed + run)
                rows[person.name].append(r)
                print(f"run {run} {r['person']:13s} seed {r['seed']}: {'done' if r['done'] else 'NOT DONE'} "
                      f"in {r['sim_s'] if r['sim_s'] is not None else float('nan'):.2f} sim s, "
                      f"{r['wall_s']:.1f} wall s, {r['presses']} press(es), said {r['words']}, "
                      f"load {r['load'][0]:.1f}", flush=True)
    for name, rs in rows.items():
        ok = [r for r in rs if r["done"]]
        sim = [r["sim_s"] for r in ok]
        wall = [r["wall_s"] for r in ok]
        fig = (f"median {statistics.median(sim):.2f} sim s ({min(sim):.2f}-{max(sim):.2f}), "
               f"{statistics.median(wall):.1f} wall s" if ok else "no success")
        print(f"{name:13s}: {len(ok)} of {len(rs)} done; time to success {fig}")
    print(f"{time.monotonic() - t0:.0f} s wall; load average at the end: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

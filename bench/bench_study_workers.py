"""A study slice's wall time with 1 and 2 Ray workers (issue 35): simulated participants x both
strategies x two Seen tasks, one trial each, through the launched graph in lockstep (one per worker),
run on a local Ray of 1 CPU, then of 2, each into a fresh folder. Prints the wall time of each (Ray's
start included, and without it), the speed-up, and whether the rows agree (apart from the fields that
name wall time).

    python bench/bench_study_workers.py [--participants 4] [--time-limit 8]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from brief import parse
from vla_evaluation.sweep import Engine
from vla_study.protocol import load_protocol
from vla_study.runner import run_study

PROTOCOL = """study: bench-workers
participants: sim:{participants}
strategies: [latent-YOLO, end-effector]
settings:
  Seen: [cereal_box/push_south, bread/push_east]
trials: 1
practice: {{trials: 0, reset_seed: 7}}
time_limit: {time_limit}
rate: 20
"""
WALL_FIELDS = ("wall_s", "wall_phases", "trial_rtf", "bag")  # a row's fields that name wall time


def run(proto, out: Path, cpus: int) -> tuple[float, float, dict]:
    """(whole wall time, wall time from the first trial's start to the end, rows by key); a unit that
    failed is said (its trials are missing from the rows)."""
    lines: list[tuple[float, str]] = []
    t0 = time.perf_counter()
    run_study(proto, out, log=lambda s: lines.append((time.perf_counter(), s)), engine=Engine(cpus=cpus))
    wall = time.perf_counter() - t0
    for _t, s in lines:
        if "failed" in s:
            print(f"  ({cpus} worker{'s' if cpus > 1 else ''}) {s}")
    first = next((t for t, s in lines if s.startswith("[study]") and "units on" in s), t0)
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines() if x.strip()]
    return wall, time.perf_counter() - first, {r["key"]: {k: v for k, v in r.items() if k not in WALL_FIELDS}
                                               for r in rows}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--participants", type=int, default=4)
    p.add_argument("--time-limit", type=float, default=8.0, help="s per trial")
    a = parse(p, argv, participants=1, time_limit=2.0)
    tmp = Path(tempfile.mkdtemp(prefix="vla_bench_study_"))
    (tmp / "p.yaml").write_text(PROTOCOL.format(participants=a.participants, time_limit=a.time_limit))
    proto = load_protocol(tmp / "p.yaml")
    results = {n: run(proto, tmp / f"w{n}", n) for n in (1, 2)}
    print(f"study slice: trials of {a.time_limit:g} s ({a.participants} simulated participants x 2 "
          "strategies x 2 tasks), the graph in lockstep, local Ray")
    for n, (wall, sweep, rows) in results.items():
        print(f"  {n} worker{'s' if n > 1 else ' '}  {len(rows)} trials, {wall:7.1f} s in all, {sweep:7.1f} "
              f"s from the first unit's dispatch ({sweep / max(len(rows), 1):.2f} s per trial)")
    one, two = results[1][2], results[2][2]
    common = one.keys() & two.keys()
    print(f"  speed-up of the sweep with 2 workers: {results[1][1] / results[2][1]:.2f}x (per trial: "
          f"{results[1][1] / max(len(one), 1) / (results[2][1] / max(len(two), 1)):.2f}x); rows identical: "
          f"{one == two} ({sum(one[k] == two[k] for k in common)} of {len(common)} trials both ran)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

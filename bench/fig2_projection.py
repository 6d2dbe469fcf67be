"""How far a run of the paper's Figure 2a protocol got, what a model costs, and how long the whole
protocol takes on more cores (issue 35). Reads the run's store (`vla_evaluation experiments --work`:
`<work>/<plan digest>/models.jsonl`) and prints:

- per encoder and demonstrations per object: models done, CPU seconds per model (training and the
  teleoperator's 40 episodes; the worker process's CPU time, which another load does not inflate);
- per encoder a line cpu = a + b * demos fitted to those (least squares), for the models not yet run;
- the whole protocol's CPU time, and its wall time on N cores: the larger of total / N and the longest
  model (one model runs on one core), plus Ray's start-up and per-unit overhead.

    python bench/fig2_projection.py out/fig2_work [--runs 10] [--counts 1-10] [--cores 2,8,32,128]
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ENCODERS = ("detector", "localization", "end_to_end")
RAY_UNIT_OVERHEAD_S = 0.0075  # bench/bench_ray_overhead.py, 2 cores at load 35 (docs/history.md)
RAY_START_S = 120.0  # a local Ray's start-up at load 35-60 on 2 cores (far less on a quiet machine)


def models(work: Path) -> list[dict]:
    """One record per finished model: encoder, demos per object, train and eval CPU seconds."""
    out = []
    for store in sorted(Path(work).glob("*/models.jsonl")):
        for line in store.read_text().splitlines()[1:]:
            unit = json.loads(line)
            rows = unit["result"]
            if not rows or rows[0]["figure"] != "2a":
                continue
            r = rows[0]
            out.append({"encoder": r["encoder"], "count": r["count"], "train": r.get("train_cpu_s"),
                        "eval": r.get("eval_cpu_s"), "train_wall": r["train_s"],
                        "eval_wall": r.get("eval_s")})
    return out


def fit(points: list[tuple[int, float]]) -> tuple[float, float]:
    """cpu = a + b * demos (b = 0 with one count only)."""
    xs = np.array([x for x, _ in points], float)
    ys = np.array([y for _, y in points], float)
    if len(set(xs)) < 2:
        return float(ys.mean()), 0.0
    b, a = np.polyfit(xs, ys, 1)
    return float(a), float(b)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", type=Path)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--counts", default="1-10")
    p.add_argument("--cores", default="2,8,32,128")
    a = p.parse_args(argv)
    lo, hi = (int(x) for x in a.counts.split("-"))
    done = [m for m in models(a.work) if m["train"] is not None]
    print(f"{len(done)} of {len(ENCODERS) * (hi - lo + 1) * a.runs} models of the protocol done\n")
    print(f"{'encoder':13s} {'demos':>5s} {'models':>6s} {'train CPU s':>11s} {'eval CPU s':>10s} "
          f"{'model CPU s':>11s} {'model wall s':>12s}")
    groups: dict = defaultdict(list)
    for m in done:
        groups[(m["encoder"], m["count"])].append(m)
    for (enc, n), ms in sorted(groups.items(), key=lambda kv: (ENCODERS.index(kv[0][0]), kv[0][1])):
        tr, ev = np.mean([m["train"] for m in ms]), np.mean([m["eval"] for m in ms])
        wall = np.mean([m["train_wall"] + (m["eval_wall"] or 0) for m in ms])
        print(f"{enc:13s} {n:5d} {len(ms):6d} {tr:11.1f} {ev:10.1f} {tr + ev:11.1f} {wall:12.1f}")
    total, longest, evals = 0.0, 0.0, 0.0
    print("\nfitted per encoder (CPU s per model = a + b * demos per object), for the models not measured:")
    lines: dict = {}
    for enc in ENCODERS:
        pts = [(n, np.mean([m["train"] + m["eval"] for m in ms]))
               for (e, n), ms in groups.items() if e == enc]
        if len({n for n, _ in pts}) >= 2:
            lines[enc] = fit(pts)
    for enc in ENCODERS:
        pts = [(n, np.mean([m["train"] + m["eval"] for m in ms]))
               for (e, n), ms in groups.items() if e == enc]
        evs = [m["eval"] for m in done if m["encoder"] == enc]
        if not pts:
            print(f"  {enc:13s} no model measured: left out of the total below")
            continue
        how = f"from {len(pts)} demo counts"
        if enc in lines:
            ca, cb = lines[enc]
        else:  # one count: grown with the demos as the best-measured encoder's line grows
            ref = next(iter(lines), None)
            n0, y0 = pts[0]
            ra, rb = lines[ref] if ref else (1.0, 0.0)
            ca, cb = y0 * ra / (ra + rb * n0), y0 * rb / (ra + rb * n0)
            how = f"from 1 demo count, grown as {ref}'s line" if ref else "from 1 demo count"
        print(f"  {enc:13s} a = {ca:8.1f}  b = {cb:8.1f}  ({how})")
        per = [max(ca + cb * n, 0.0) for n in range(lo, hi + 1)]
        total += a.runs * sum(per)
        longest = max(longest, max(per))
        evals += a.runs * (hi - lo + 1) * float(np.mean(evs))
    n_units = len(ENCODERS) * (hi - lo + 1) * a.runs
    print(f"\nthe protocol: {total / 3600:.1f} CPU hours ({n_units} models), of which the teleoperator's "
          f"evaluation {evals / 3600:.1f}; the longest model {longest / 60:.1f} min")
    for cores in (int(c) for c in a.cores.split(",")):
        wall = max(total / cores, longest) + RAY_START_S + n_units * RAY_UNIT_OVERHEAD_S
        print(f"  {cores:4d} cores: {wall / 3600:6.2f} h")
    print(f"  one GPU: not measured here (no GPU was lent); the evaluations stay on the CPU: at least "
          f"{evals / 3600 / 16:.2f} h on 16 cores beside the GPU, plus the trainings on it")
    return 0


if __name__ == "__main__":
    sys.exit(main())

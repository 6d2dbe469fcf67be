"""Success of latent-YOLO and the end-effector baseline as the simulated participant's parameters vary.

    python -m vla_study.sensitivity --out out/study_sensitivity [--delays 0.1,0.3,0.5] [--noise 0.05,0.3]
        [--policy "commit_s=0.3,1.0;gain=0.6,1.4;reverse_margin=1,4;stall_turn=2,8;reach_tol=0.02,0.08"]
One participant, the population's mean parameters (HumanParams()), on the same seeded layouts in every
cell (the graph, in lockstep):
- the person's limits: reaction delay × stick noise, as a grid;
- the person's decision policy, one parameter at a time (the rest at the mean): how long a direction is
  held before it is judged (`commit_s`), how boldly the stick is pushed (`gain`), how much worse the task
  must look before reversing (`reverse_margin`, in perception sds), how many unchanged judgements before
  trying the other way (`stall_turn`), how near a planned point counts as reached (`reach_tol`, the
  end-effector's plan); beside the mean participant ("mean").
Rows go to sensitivity.jsonl (resumable), the tables to sensitivity.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from vla_study.participant import HumanParams
from vla_study.protocol import Protocol
from vla_study.trial import Trial, hash_seed

POLICY = "commit_s=0.3,1.0;gain=0.6,1.4;reverse_margin=1,4;stall_turn=2,8;reach_tol=0.02,0.08"
LAYOUT_SEEDS = 300_000
SETTING = {"cereal_box/push_south": "Seen"}


def cells(delays: str, noise: str, policy: str) -> list[tuple[str, str, dict]]:
    """(key part, what varied, HumanParams overrides) of every cell: the grid, the mean, the policy."""
    out = [(f"{d}|{k}", "reaction_s,motor_k", {"reaction_s": d, "motor_k": k})
           for d in map(float, delays.split(",")) for k in map(float, noise.split(","))]
    if policy:
        out.append(("mean", "mean", {}))
    fields = {f.name: f.type for f in dataclasses.fields(HumanParams)}
    for part in (p for p in policy.split(";") if p.strip()):
        name, values = part.split("=")
        cast = int if fields[name.strip()] in (int, "int") else float
        out += [(f"{name.strip()}={v}", name.strip(), {name.strip(): cast(v)}) for v in values.split(",")]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/study_sensitivity"))
    ap.add_argument("--delays", default="0.1,0.3,0.5")
    ap.add_argument("--noise", default="0.05,0.3", help="motor noise k (sd = k |u| + floor)")
    ap.add_argument("--policy", default=POLICY, help="name=v1,v2;... varied one at a time ('': none)")
    ap.add_argument("--tasks", default="cereal_box/push_south,bread/push_east")
    ap.add_argument("--layouts", type=int, default=2)
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows_path = a.out / "sensitivity.jsonl"
    run_cells(rows_path, cells(a.delays, a.noise, a.policy), a.tasks.split(","), a.layouts, a.out)
    if rows_path.exists():
        rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()]
        text = "\n".join(["# Sensitivity — **simulated participant** (HumanParams() with one thing varied; "
                          "successes/trials)", "", "## Reaction delay × stick noise", "", *grid_table(rows),
                          "", "## The decision policy, one parameter at a time", "", *policy_table(rows)])
        (a.out / "sensitivity.md").write_text(text + "\n")
        print(text)
    return 0


def run_cells(rows_path: Path, todo: list[tuple[str, str, dict]], tasks: list[str], layouts: int,
              out: Path | None = None) -> None:
    """Each cell's trials not yet in `rows_path`, appended as they end (the graph is launched only if a
    trial runs, its logs and bags under `out`, else beside `rows_path`)."""
    proto = Protocol("sensitivity", ["sim:1"], 0, ["latent-YOLO", "end-effector"], {}, 1, 0, 7, "none", 30.0,
                     20.0, models={"latent-YOLO": {"base": "default", "Seen": "cereal_box_push_south"}})
    done = {json.loads(x)["key"] for x in rows_path.read_text().splitlines() if x.strip()} \
        if rows_path.exists() else set()
    made: list = []   # the graph, once a trial needs it

    def backend():
        if not made:
            from vla_study.graph_backend import GraphBackend  # rclpy and the graph: only when a trial runs

            made.append(GraphBackend(proto, out or rows_path.parent, log=lambda s: print(s, flush=True)))
        return made[0]

    try:
        for part, varied, overrides in todo:
            params = dataclasses.replace(HumanParams(), **overrides)
            for strategy, task, j in ((s, t, j) for s in proto.strategies for t in tasks
                                      for j in range(layouts)):
                key = f"{strategy}|{task}|{part}|{j}"
                if key in done:
                    continue
                trial = Trial("sim:1", strategy, SETTING.get(task, "base"), task, j, "test",
                              LAYOUT_SEEDS + j, 0)
                row, _ = backend().run(trial, params, hash_seed(key))
                row.update({"key": key, "strategy": strategy, "task": task, "layout": j, "varied": varied,
                            "reaction_s": params.reaction_s, "motor_k": params.motor_k,
                            "value": overrides.get(varied)})
                with open(rows_path, "a") as f:
                    f.write(json.dumps(row, sort_keys=True) + "\n")
                print(f"[sensitivity] {key}: success {row['success']}", flush=True)
    finally:
        if made:
            made[0].close()


def _tally(rows, strategies, pick) -> list[str]:
    vals = []
    for s in strategies:
        ok = [r["success"] for r in rows if r["strategy"] == s and pick(r)]
        vals.append(f"{sum(ok)}/{len(ok)}" if ok else "–")
    return vals


def grid_table(rows: list[dict]) -> list[str]:
    """Success per (delay, noise) for each strategy (rows made before `varied` are grid rows)."""
    grid = [r for r in rows if r.get("varied", "reaction_s,motor_k") == "reaction_s,motor_k"]
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    lines = ["| reaction delay (s) | stick noise k | " + " | ".join(strategies) + " |",
             "|---|---|" + "---|" * len(strategies)]
    for d, k in sorted({(r["reaction_s"], r["motor_k"]) for r in grid}):
        vals = _tally(grid, strategies, lambda r, d=d, k=k: r["reaction_s"] == d and r["motor_k"] == k)
        lines.append(f"| {d:g} | {k:g} | " + " | ".join(vals) + " |")
    return lines


def policy_table(rows: list[dict]) -> list[str]:
    """Success per policy parameter and value for each strategy, beside the mean participant."""
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    lines = ["| parameter | value | " + " | ".join(strategies) + " |", "|---|---|" + "---|" * len(strategies)]
    mean = HumanParams()
    policy = [r for r in rows if r.get("varied") not in (None, "reaction_s,motor_k")]
    for name in dict.fromkeys(r["varied"] for r in policy):
        if name == "mean":
            vals = _tally(rows, strategies, lambda r: r.get("varied") == "mean")
            lines.append("| (the mean participant) | – | " + " | ".join(vals) + " |")
            continue
        mine = [r for r in policy if r["varied"] == name]
        for v in sorted({r["value"] for r in mine}):
            vals = _tally(mine, strategies, lambda r, v=v: r["value"] == v)
            lines.append(f"| {name} (mean {getattr(mean, name):g}) | {v:g} | " + " | ".join(vals) + " |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())

"""The oracle teleoperator on the study's own layouts: what a latent model can do, beside what the
simulated participants get out of it.

    python -m vla_study.oracle --protocol docs/results/study/protocol_run.yaml --out out/oracle
Every latent test trial of the protocol (its task and seeded layout, the same as the participants')
is driven by the paper's oracle (vla_evaluation.sim_teleoperator: decoder search towards the
planner's waypoints) on the physics backend. Rows go to <out>/oracle.jsonl (resumable, keyed by
strategy, setting, task and layout seed); the success per strategy and setting is printed.
"""
from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

from vla_evaluation.kinematic import TeleopSettings
from vla_evaluation.physics import run_episode

from vla_study.physics_backend import PhysicsBackend
from vla_study.protocol import SHIPPED, STRATEGIES, ProtocolError, load_protocol, parse_participants
from vla_study.runner import trial_plan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", type=Path, default=SHIPPED)
    ap.add_argument("--participants", default=None, help="sim:N (overrides the file)")
    ap.add_argument("--out", type=Path, default=Path("out/study_oracle"))
    a = ap.parse_args(argv)
    try:
        proto = load_protocol(a.protocol)
    except ProtocolError as e:
        print(f"protocol refused:\n{e}")
        return 2
    if a.participants:
        proto.participants = parse_participants(a.participants)
    trials = [t for t in trial_plan(proto) if t.phase == "test" and STRATEGIES[t.strategy] == "latent"]
    a.out.mkdir(parents=True, exist_ok=True)
    rows_path = a.out / "oracle.jsonl"
    rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()] \
        if rows_path.exists() else []
    done = {r["key"] for r in rows}
    todo = []
    for t in trials:
        key = f"oracle|{t.strategy}|{t.setting}|{t.task}|{t.layout_seed}"
        if key not in done:
            done.add(key)
            todo.append((key, t))
    if todo:
        backend = PhysicsBackend(proto)
        settings = TeleopSettings(rate=proto.rate, time_limit=proto.time_limit)
        for key, t in todo:
            layout = backend.reset_scene(t)
            model = backend.model(proto.models[t.strategy][t.setting])
            r = run_episode(model, layout, settings, backend.sim)
            row = {"key": key, "strategy": t.strategy, "setting": t.setting, "task": t.task,
                   "layout_seed": t.layout_seed, "success": bool(r.success), "note": r.note}
            with open(rows_path, "a") as f:
                f.write(json.dumps(row, sort_keys=True) + "\n")
            rows.append(row)
            print(f"[oracle] {key}: success {row['success']}", flush=True)
    tally: dict[tuple[str, str], list[bool]] = defaultdict(list)
    for r in rows:
        tally[(r["strategy"], r["setting"])].append(r["success"])
    for (strategy, setting), v in sorted(tally.items()):
        print(f"oracle teleoperator (simulated), {strategy} {setting}: {sum(v)}/{len(v)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

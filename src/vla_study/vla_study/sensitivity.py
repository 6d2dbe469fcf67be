"""Success against reaction delay and stick noise, latent-YOLO vs the end-effector baseline.

    python -m vla_study.sensitivity --out out/study_sensitivity [--delays 0.1,0.3,0.5]
One participant (the population's mean parameters, HumanParams()) with the delay and the motor noise
varied, the rest held; each cell over the same seeded layouts. Rows go to sensitivity.jsonl (resumable,
as the study's), the table to sensitivity.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from vla_study.analysis import sensitivity_table
from vla_study.participant import HumanParams
from vla_study.physics_backend import PhysicsBackend
from vla_study.protocol import Protocol
from vla_study.trial import Trial, hash_seed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/study_sensitivity"))
    ap.add_argument("--delays", default="0.1,0.3,0.5")
    ap.add_argument("--noise", default="0.05,0.3", help="motor noise k (sd = k |u| + floor)")
    ap.add_argument("--tasks", default="cereal_box/push_south,bread/push_east")
    ap.add_argument("--layouts", type=int, default=2)
    a = ap.parse_args(argv)

    proto = Protocol("sensitivity", ["sim:1"], 0, ["latent-YOLO", "end-effector"], {}, 1, 0, 7, "none", 30.0,
                     20.0, models={"latent-YOLO": {"base": "default", "Seen": "cereal_box_push_south"}})
    setting = {"cereal_box/push_south": "Seen"}
    a.out.mkdir(parents=True, exist_ok=True)
    rows_path = a.out / "sensitivity.jsonl"
    done = {json.loads(x)["key"] for x in rows_path.read_text().splitlines() if x.strip()} \
        if rows_path.exists() else set()
    backend = None
    for delay in [float(x) for x in a.delays.split(",")]:
        for k in [float(x) for x in a.noise.split(",")]:
            params = dataclasses.replace(HumanParams(), reaction_s=delay, motor_k=k)
            for strategy in proto.strategies:
                for task in a.tasks.split(","):
                    for j in range(a.layouts):
                        key = f"{strategy}|{task}|{delay}|{k}|{j}"
                        if key in done:
                            continue
                        trial = Trial("sim:1", strategy, setting.get(task, "base"), task, j, "test",
                                      300_000 + j, 0)
                        backend = backend or PhysicsBackend(proto)
                        row, _ = backend.run(trial, params, hash_seed(key))
                        row.update({"key": key, "strategy": strategy, "task": task, "reaction_s": delay,
                                    "motor_k": k, "layout": j})
                        with open(rows_path, "a") as f:
                            f.write(json.dumps(row, sort_keys=True) + "\n")
                        print(f"[sensitivity] {key}: success {row['success']}", flush=True)
    if rows_path.exists():
        table = "\n".join(sensitivity_table(rows_path))
        (a.out / "sensitivity.md").write_text(
            "# Sensitivity (simulated participant: HumanParams() with the reaction delay and the stick "
            "noise varied; successes/trials)\n\n" + table + "\n")
        print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

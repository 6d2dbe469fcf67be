"""The study's localization-only model (the paper's second strategy): train one for the base tasks.

    python -m vla_evaluation.study.localization_model --out out/models/localization

The paper's "localization-only" encoder: the CNN of the end-to-end model learns where the object is
from the first camera frame, and the object's class comes from an oracle (one-hot): s = q ⊕ g ⊕ c
(vla_latent_training's `--encoder localization`). Demonstrations are made in-process (PandaSim and
the task planner, `experiments.simulate_demos`, the first rendered frame kept), `--demos` per base
task, trained with Figure 2's recipe (`experiments.Plan`, 128 hidden units as the shipped models).
Copy the output to `src/vla_latent_controller/models/localization` and `make setup` to ship it; the
paper protocol (`protocols/paper.yaml`) names it for the base tasks.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

BASE_TASKS = ("bread/push_east", "soda_can/push_south", "milk_carton/push_south_west",
              "glass_bottle/push_west")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="model directory to write (must not exist)")
    ap.add_argument("--demos", type=int, default=10, help="demonstrations per base task (the paper: 10)")
    ap.add_argument("--epochs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.out.exists():
        print(f"{args.out} exists: choose a new --out (nothing is overwritten)", file=sys.stderr)
        return 2
    import torch
    from vla_detector.inference import Detector
    from vla_latent_training.train import train_model

    from vla_evaluation.experiments import Plan, simulate_demos
    from vla_evaluation.resources import detector_model_path

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    detector = Detector(detector_model_path())
    demos = []
    for i, task in enumerate(BASE_TASKS):
        demos += simulate_demos(task, args.demos, seed=1000 * (args.seed + 1) + i, detector=detector)
        print(f"[localization] {len(demos)} demonstrations ({time.perf_counter() - t0:.0f} s)", flush=True)
    cfg = Plan(epochs=args.epochs, hidden=128).train_config("localization", seed=args.seed)
    res = train_model(demos, cfg, progress=False, threads=1, log=lambda s: print(s, flush=True))
    path = res.save(args.out)
    meta = {"demos_per_task": args.demos, "tasks": list(BASE_TASKS), "epochs": args.epochs,
            "seed": args.seed, "wall_s": round(time.perf_counter() - t0, 1)}
    (Path(path) / "provenance.json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"[localization] model in {path} ({meta['wall_s']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

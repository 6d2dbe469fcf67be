"""The study's localization-only models (the paper's second strategy): the base one and the few-shot ones.

    python -m vla_study.localization_model --out out/models/localization
    python -m vla_study.localization_model --out out/models/fewshot \
        --fewshot cereal_box/push_south cereal_box/push_south_east cereal_box/circle

The paper's "localization-only" encoder: the CNN of the end-to-end model learns where the object is
from the first camera frame, and the object's class comes from an oracle (one-hot): s = q ⊕ g ⊕ c
(vla_latent_training's `--encoder localization`). Demonstrations are made in-process (PandaSim and
the task planner, `experiments.simulate_demos`, the first rendered frame kept), `--demos` per base
task, trained with Figure 2's recipe (`experiments.Plan`, 128 hidden units as the shipped models).
With `--fewshot`, each named unseen task gets a model of its own, as the detector's few-shot models
(`training_data.ensure_latent_models`): the same base demonstrations plus `--fewshot-demos` of the new
task (the paper's k = 5), written to `<out>/<task>_localization` (the names `protocols/paper.yaml`
gives). Copy the output under `src/vla_latent_controller/models/` and `make setup` to ship it.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from vla_common.tasks import BASE_TASKS, UNSEEN_TASKS

FEWSHOT_SEED = 5_000  # the few-shot demonstrations' layouts, apart from the base ones (seeds 1000 ...)


def model_name(task: str) -> str:
    """A few-shot localization model's directory: `cereal_box/circle` -> `cereal_box_circle_localization`."""
    return task.replace("/", "_") + "_localization"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True,
                    help="model directory to write (with --fewshot: their folder); must not exist")
    ap.add_argument("--demos", type=int, default=10, help="demonstrations per base task (the paper: 10)")
    ap.add_argument("--fewshot", nargs="+", choices=UNSEEN_TASKS, default=[],
                    help="train one few-shot model per unseen task instead of the base model")
    ap.add_argument("--fewshot-demos", type=int, default=5, help="per unseen task (the paper: 5)")
    ap.add_argument("--epochs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.out.exists():
        print(f"{args.out} exists: choose a new --out (nothing is overwritten)", file=sys.stderr)
        return 2
    import torch
    from vla_detector.inference import Detector
    from vla_evaluation.experiments import Plan, simulate_demos
    from vla_evaluation.resources import detector_model_path
    from vla_latent_training.train import train_model

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    detector = Detector(detector_model_path())
    base = []
    for i, task in enumerate(BASE_TASKS):
        base += simulate_demos(task, args.demos, seed=1000 * (args.seed + 1) + i, detector=detector)
        print(f"[localization] {len(base)} demonstrations ({time.perf_counter() - t0:.0f} s)", flush=True)
    jobs = {args.out: (list(BASE_TASKS), base)}
    if args.fewshot:
        jobs = {}
        for task in args.fewshot:
            new = simulate_demos(task, args.fewshot_demos, seed=FEWSHOT_SEED + UNSEEN_TASKS.index(task),
                                 detector=detector)
            jobs[args.out / model_name(task)] = (list(BASE_TASKS) + [task], base + new)
    cfg = Plan(epochs=args.epochs, hidden=128).train_config("localization", seed=args.seed)
    for out, (tasks, demos) in jobs.items():
        t1 = time.perf_counter()
        print(f"[localization] {out.name}: {len(demos)} demonstrations", flush=True)
        res = train_model(demos, cfg, progress=False, threads=1, log=lambda s: print(s, flush=True))
        path = res.save(out)
        meta = {"demos_per_task": {t: (args.demos if t in BASE_TASKS else args.fewshot_demos) for t in tasks},
                "epochs": args.epochs, "seed": args.seed, "train_wall_s": round(time.perf_counter() - t1, 1),
                "wall_s": round(time.perf_counter() - t0, 1)}
        (Path(path) / "provenance.json").write_text(json.dumps(meta, indent=1) + "\n")
        print(f"[localization] model in {path} ({meta['wall_s']} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

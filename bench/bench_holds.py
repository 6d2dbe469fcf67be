"""Holding the stick toward the task (issue 20 item 5, must-show): N holds of S s at full stick from
the ready pose on fresh layouts for each base task, through the graph on MuJoCo (the shipped models).
Prints per task: holds, reflexes, task done, worst measured |dq|/dq_max; then the totals. A hold the
graph does not finish (a timeout on a loaded machine) counts as a failed hold, is listed, and the run
goes on with a restarted graph. The holds run as units on Ray (a local Ray, `--ray-address` a cluster,
`--serial` one graph in this process), each worker with its own graph on its own ROS domain. The graph
runs in lockstep (a hold is a function of its seed at any load; `--free-running` the old graph);
`--assistance` sets the controller's level (issue 34), `--json` writes each hold's row.

    python bench/bench_holds.py [--n 50] [--seconds 6] [--stick 1] [--path-fraction 0.65] [--tasks base]
                                [--model default] [--assistance high] [--json rows.json] [--log-dir DIR]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from brief import parse
from vla_evaluation.evaluate_cli import task_list
from vla_evaluation.graph import GraphConfig
from vla_evaluation.holds import FRESH_SEED, hold_config, run_holds
from vla_evaluation.kinematic import TeleopSettings
from vla_evaluation.resources import detector_model_path, is_latent_model, latent_model_dir
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_evaluation.sweep import engine_from


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=50, help="holds per task")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each hold (sim s)")
    p.add_argument("--stick", type=float, default=1.0, help="the held stick value")
    p.add_argument("--path-fraction", type=float, default=TeleopSettings.path_fraction,
                   help="the controller's path_fraction (default: %(default)s, the model's calibrated one)")
    p.add_argument("--tasks", default="base", help="base, unseen, all or comma-separated task names")
    p.add_argument("--first-seed", type=int, default=FRESH_SEED)
    p.add_argument("--model", default="default", help="shipped latent model name or a directory")
    p.add_argument("--log-dir", default=None, help="where the graph's output goes")
    p.add_argument("--real-time-factor", type=float, default=GraphConfig.real_time_factor,
                   help="simulated seconds per wall second; lower it on a loaded machine, where joy "
                        "gaps of 0.25 simulated s stop the arm until neutral (default: %(default)s)")
    p.add_argument("--assistance", default="off", choices=("off", "low", "high"),
                   help="the controller's assistance level (issue 34; default: %(default)s, the paper's)")
    p.add_argument("--free-running", action="store_true",
                   help="the old free-running graph; by default the simulation runs in lockstep with the "
                        "controller and the holds are a function of their seeds at any load")
    p.add_argument("--json", default=None, help="also write every hold's row (task, seed, success, ...) here")
    add_engine_arguments(p)
    a = parse(p, argv, n=1, tasks="bread/push_east")
    model = latent_model_dir(a.model)
    if not is_latent_model(model):   # refused here, not as one graph error per hold
        p.error(f"--model {a.model}: no latent model there ({model} has no config.json)")
    cfg = hold_config(str(model), str(detector_model_path()), a.seconds, a.stick,
                      a.path_fraction, log_dir=a.log_dir, real_time_factor=a.real_time_factor,
                      lockstep=not a.free_running,
                      extra_params={"controller_node": {"assistance": a.assistance}})
    t0 = time.monotonic()
    tallies = run_holds(cfg, task_list(a.tasks), a.n, a.first_seed, engine=engine_from(a))
    wall = time.monotonic() - t0
    print(f"\n{a.n} holds of {a.seconds:g} s at stick {a.stick:+g} per task, model {a.model}, assistance "
          f"{a.assistance}, path_fraction {a.path_fraction:g}, "
          f"{'free-running' if a.free_running else 'lockstep'}, real-time factor "
          f"{a.real_time_factor:g} ({wall:.0f} s wall)")
    if a.json:
        rows = [dict(r, model=a.model, assistance=a.assistance, seconds=a.seconds)
                for t in tallies.values() for r in t.rows]
        Path(a.json).write_text(json.dumps(rows, indent=1) + "\n")
    for t in tallies.values():
        print(t.line())
    holds = sum(t.holds for t in tallies.values())
    errors = sum(len(t.graph_errors) for t in tallies.values())
    print(f"total: {holds} holds, {sum(t.reflexes for t in tallies.values())} reflexes, "
          f"task done in {sum(t.successes for t in tallies.values())}"
          + (f"; {errors} graph errors counted as failed holds (reflex unknown), the graph restarted "
             "after each" if errors else ""))
    for t in tallies.values():
        for seed, reason in t.graph_errors:
            print(f"  graph error: {t.task} seed {seed}: {reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

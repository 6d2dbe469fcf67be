"""The trials' TCP paths (`trials/<trial>.npz`) again, from the rows and their seeds.

The paths of a study are kept out of git (1,008 files for the stored runs); the rows are kept. Each row
holds what its trial was made from: the participant (their parameters come from the protocol's
population seed), the strategy, task and layout seed, and the operator seed (from the key, for rows
made before it was kept). `vla_study --paths --protocol P --out DIR` reruns every trial of DIR's
trials.jsonl whose .npz is missing, with those seeds, on the protocol's backend (`--backend` to choose
another), and writes only the .npz: the rows stay as they are. `paths.jsonl` says for each rerun the
backend and whether its outcome was the row's. The graph in lockstep (simulated participants, since
issue 33) reproduces a trial of the same code exactly; a row of the real-time graph, or of the physics
backend (gone), only by its seeds: its outcome may differ.
Real participants' trials cannot be rerun: they are skipped.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from vla_study.analysis import load_rows
from vla_study.backends import Where, make_backend
from vla_study.protocol import Protocol
from vla_study.runner import operator_seed, participant_params, save_arrays, trial_plan
from vla_study.trial import Trial, TrialBackend


def missing_paths(protocol: Protocol, out: Path, log: Callable[[str], None] = print
                  ) -> list[tuple[dict, Trial]]:
    """The rows of `out` without their .npz, each with its trial in `protocol`'s plan; a row the plan
    does not hold as it is (another protocol, other seeds) is named and left out."""
    plan = {t.key: t for t in trial_plan(protocol)}
    todo = []
    for r in load_rows(out):
        if (Path(out) / "trials" / f"{r['file']}.npz").exists():
            continue
        t = plan.get(r["key"])
        if not r.get("simulated", True):
            log(f"[paths] {r['key']}: a person's trial, not rerun")
        elif t is None or t.layout_seed != r["layout_seed"]:
            log(f"[paths] {r['key']}: not a trial of {protocol.source} with layout seed "
                f"{r['layout_seed']}: give the protocol it ran with")
        else:
            todo.append((r, t))
    return todo


def regenerate_paths(protocol: Protocol, out: Path, backend: TrialBackend | None = None,
                     log: Callable[[str], None] = print, limit: int | None = None) -> int:
    """Rerun the trials of `out` whose paths are missing (at most `limit`) and write their .npz;
    returns how many were written."""
    out = Path(out)
    todo = missing_paths(protocol, out, log)[:limit]
    log(f"[paths] {len(todo)} trials of {out} to rerun for their paths")
    if not todo:
        return 0
    (out / "trials").mkdir(parents=True, exist_ok=True)
    params = participant_params(protocol)
    own = backend is None
    backend = backend or make_backend(Where(protocol, out, log))
    try:
        for row, trial in todo:
            seed = row.get("operator_seed", operator_seed(protocol, trial))
            again, arrays = backend.run(trial, params[trial.participant], operator_seed=seed)
            save_arrays(out, row["file"], arrays)
            same = again["success"] == row["success"]
            note = {"key": row["key"], "backend": protocol.backend, "success_recorded": row["success"],
                    "success_now": again["success"], "same_outcome": same,
                    "time_recorded": row.get("time_s"), "time_now": again["time_s"]}
            with open(out / "paths.jsonl", "a") as f:
                f.write(json.dumps(note, sort_keys=True) + "\n")
            log(f"[paths] {row['key']}: path written; outcome {'as recorded' if same else 'NOT as recorded'}")
    finally:
        if own:
            backend.close()
    return len(todo)

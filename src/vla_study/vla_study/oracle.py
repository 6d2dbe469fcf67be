"""The oracle teleoperator on the study's layouts, with every model the protocol names: what each
model can do, beside what the simulated participants get out of it.

    python -m vla_study.oracle --protocol src/vla_study/vla_study/protocols/paper.yaml --out out/oracle
    python -m vla_study.oracle --protocol ... --layouts development --loop kinematic --out out/oracle_dev
    python -m vla_study.oracle --protocol ... --out STUDY/oracle --study STUDY
    python -m vla_study.oracle --protocol ... --models assigned --strategies latent-YOLO --out ...

The paper's oracle (vla_evaluation.sim_teleoperator: a decoder search towards the planner's waypoints)
drives every model the protocol names for a latent strategy and setting (one per training seed where
it names a list; `--models assigned`: only the model each layout's participant drives) on every layout
of that setting: the test trials' layouts (`--layouts test`, the participants' own) or the development
files' (`--layouts development`, for checks before a long run). `--loop graph` (default) runs the
oracle in the study's own system, the launched graph in lockstep (deterministic at any load), on the
very layouts the participants get (the same ~/reset), and judges success as the study does; `--loop
kinematic` is the paper's loop (fast, deterministic, no object: final state error only). Each
episode is a unit of a sweep (vla_evaluation.sweep: --serial, a local Ray or a cluster; a graph per
worker, each on a ROS domain of its own: lockstep keeps their results apart from their load); rows
go to <out>/oracle.jsonl (resumable; a row is keyed by the model's sealed config, so a retrained
model is run again). The tables (per strategy, setting and model seed, then
per task) are printed and written to <out>/oracle.md; with `--study DIR`, the participants' success
in that study folder beside the oracle's on the same layouts with the same model.
"""
from __future__ import annotations

import argparse
import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vla_evaluation.sweep import Needs, engine_from, run_sweep
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_evaluation.unit_store import UnitStore, digest

from vla_study.layouts import development_layouts, trial_layouts
from vla_study.protocol import (
    SHIPPED,
    STRATEGIES,
    Protocol,
    ProtocolError,
    load_protocol,
    model_for,
    model_names,
    parse_participants,
)
from vla_study.protocol_schema import base_strategy
from vla_study.runner import trial_plan

LOOPS = ("graph", "kinematic")
LABEL = "oracle teleoperator (simulated)"


@dataclass(frozen=True)
class OracleUnit:
    """One episode: a model of a strategy and setting (its seed's index in the protocol's list) on one
    layout, in one loop."""

    strategy: str
    setting: str
    model: str
    seed_index: int
    task: str
    layout_seed: int
    loop: str
    layouts: str  # "test" or "development"

    def key(self, model_seal: str) -> str:
        return "|".join(str(x) for x in ("oracle", self.loop, self.layouts, self.strategy, self.setting,
                                         f"{self.model}@{model_seal[:12]}", self.task, self.layout_seed))


def oracle_units(p: Protocol, layouts: str = "test", loop: str = "graph", models: str = "all",
                 per_task: int | None = None, strategies: list[str] | None = None) -> list[OracleUnit]:
    """Every episode of the oracle's table, strategy by strategy and setting by setting (`strategies`:
    only these of the protocol's latent strategies; ValueError naming one it has not)."""
    assigned = _assigned(p) if models == "assigned" else {}
    # an assisted condition drives its strategy's models: the oracle on them is its strategy's
    latent = [s for s in p.strategies if STRATEGIES[s] == "latent" and base_strategy(s) == s]
    if unknown := [s for s in strategies or () if s not in latent]:
        raise ValueError(f"--strategies {', '.join(unknown)}: not among the protocol's latent strategies "
                         f"({', '.join(latent)})")
    out = []
    for strategy in (s for s in latent if strategies is None or s in strategies):
        for setting in p.settings:
            names = model_names(p, strategy, setting)
            chosen = (trial_layouts(p, setting) if layouts == "test" else development_layouts(p, setting))
            for task, seed in _first_per_task(chosen, per_task):
                for i, name in enumerate(names):
                    if models == "all" or name in assigned.get((strategy, setting, task, seed), ()):
                        out.append(OracleUnit(strategy, setting, name, i, task, seed, loop, layouts))
    return out


def _assigned(p: Protocol) -> dict[tuple, set[str]]:
    """Which models drive each test layout in the protocol (the participant's, protocol.model_for)."""
    out: dict[tuple, set[str]] = defaultdict(set)
    for t in trial_plan(p):
        if t.phase == "test" and STRATEGIES[t.strategy] == "latent":
            out[(t.strategy, t.setting, t.task, t.layout_seed)].add(model_for(p, t))
    return out


def _first_per_task(layouts: list[tuple[str, int]], n: int | None) -> list[tuple[str, int]]:
    if n is None:
        return layouts
    count: dict[str, int] = defaultdict(int)
    out = []
    for task, seed in layouts:
        if count[task] < n:
            count[task] += 1
            out.append((task, seed))
    return out


class OracleWorker:
    """A sweep worker. The graph loop: the launched graph in lockstep, started at its first episode, the
    model set per episode. The kinematic loop: a simulator and the detector for the layouts, the models
    and layouts it has used (cached)."""

    def __init__(self, state: dict) -> None:
        self.state = state
        self.ev = None                                   # the graph, once a graph episode runs
        self.sim = self.detector = None
        self._models: dict[str, object] = {}
        self._layouts: dict[tuple[str, int], object] = {}

    def run(self, unit: OracleUnit) -> dict:
        if unit.loop == "graph":
            return oracle_row(unit, self._graph_episode(unit))
        return oracle_row(unit, self._kinematic_episode(unit))

    def _graph_episode(self, unit: OracleUnit):
        from vla_evaluation.graph_sweep import on_a_new_graph_after_errors  # rclpy: only in a worker

        return on_a_new_graph_after_errors(lambda: self._graph_try(unit), self.close,
                                           f"{unit.task} seed {unit.layout_seed} with {unit.model}")

    def _graph_try(self, unit: OracleUnit):
        from vla_evaluation.graph import GraphConfig, GraphEvaluator  # rclpy, the graph: only in a worker
        from vla_evaluation.kinematic import TeleopSettings
        from vla_evaluation.resources import detector_model_path, latent_model_dir

        if self.ev is None:
            settings = TeleopSettings(rate=100.0, time_limit=self.state["time_limit"])
            cfg = GraphConfig(model_path=str(latent_model_dir(unit.model)),
                              detector_model=str(detector_model_path()), lockstep=True,
                              real_time_factor=0.0, settings=settings)
            self.ev = GraphEvaluator(cfg, log=lambda s: None)
            self.ev.start()
        self.ev.set_model(str(latent_model_dir(unit.model)))
        return self.ev.run_episode(unit.task, unit.layout_seed, label=unit.model).result

    def _kinematic_episode(self, unit: OracleUnit):
        from vla_detector.inference import Detector  # MuJoCo, onnxruntime: only in a worker
        from vla_evaluation.kinematic import TeleopSettings
        from vla_evaluation.resources import detector_model_path, latent_model_dir
        from vla_latent_controller.model import LatentModel
        from vla_sim.sim import PandaSim

        from vla_evaluation import kinematic

        if self.sim is None:
            self.sim, self.detector = PandaSim(render=True), Detector(detector_model_path())
        if unit.model not in self._models:
            self._models[unit.model] = LatentModel.load(latent_model_dir(unit.model))
        where = (unit.task, unit.layout_seed)
        if where not in self._layouts:
            self._layouts[where] = kinematic.make_layouts([unit.task], [unit.layout_seed], sim=self.sim,
                                                          detector=self.detector)[0]
        settings = TeleopSettings(rate=self.state["rate"], time_limit=self.state["time_limit"])
        return kinematic.run_episode(self._models[unit.model], self._layouts[where], settings)

    def close(self) -> None:
        if self.ev is not None:
            ev, self.ev = self.ev, None
            ev.close()


def oracle_row(unit: OracleUnit, r) -> dict:
    """One episode's row: the unit, then the outcome (success None in the kinematic loop: no object)."""
    return {"strategy": unit.strategy, "setting": unit.setting, "model": unit.model,
            "seed_index": unit.seed_index, "task": unit.task, "layout_seed": unit.layout_seed,
            "loop": unit.loop, "layouts": unit.layouts,
            "success": bool(r.success) if unit.loop == "graph" else None,
            "time_to_success_s": r.time_to_success, "final_state_error": round(float(r.final_state_error), 4),
            "waypoint_error": r.extra.get("waypoint_error"), "note": r.note, "simulated": True}


def _cell(rows: list[dict]) -> str:
    """Successes of n and the median final state error (rad); the error alone in the kinematic loop."""
    if not rows:
        return ""
    fse = float(np.median([r["final_state_error"] for r in rows]))
    if rows[0]["success"] is None:
        return f"{fse:.3f} rad (n {len(rows)})"
    return f"{sum(r['success'] for r in rows)}/{len(rows)} ({fse:.2f} rad)"


def oracle_tables(rows: list[dict]) -> str:
    """Markdown: per strategy and setting, each model seed and the seeds together; then per task."""
    loop, layouts = rows[0]["loop"], rows[0]["layouts"]
    what = ("successes of n (median final state error)" if loop == "graph"
            else "median final state error, the paper's metric (no object in this loop)")
    seeds = max(r["seed_index"] for r in rows) + 1
    cols = " | ".join(f"model seed {i}" for i in range(seeds))
    head = f"| strategy | setting | {cols} | seeds together |"
    lines = [f"### The {LABEL} on the {layouts} layouts ({loop} loop): {what}", "",
             "Model seed i: the i-th model the protocol lists for the setting (the matched set's training "
             "seed i; participant j drives the (j mod n)-th).", "", head, "|" + "---|" * (seeds + 3)]
    by = _group(rows, ("strategy", "setting"))
    for (strategy, setting), group in by.items():
        per = _group(group, ("seed_index",))
        cells = [_cell(per.get((i,), [])) for i in range(seeds)]
        lines.append(f"| {strategy} | {setting} | " + " | ".join(cells) + f" | {_cell(group)} |")
    lines += ["", "Per task, the seeds together:", "", "| strategy | setting | task | oracle |",
              "|---|---|---|---|"]
    for (strategy, setting, task), group in _group(rows, ("strategy", "setting", "task")).items():
        lines.append(f"| {strategy} | {setting} | {task} | {_cell(group)} |")
    return "\n".join(lines) + "\n"


def beside_participants(rows: list[dict], study_rows: list[dict], p: Protocol) -> str:
    """Markdown: the participants' test trials per strategy, setting and model, and the oracle with the
    same model on the same layouts (graph rows of the test layouts)."""
    oracle = {(r["model"], r["task"], r["layout_seed"]): r for r in rows
              if r["loop"] == "graph" and r["layouts"] == "test"}
    lines = [f"### Participants (simulated) beside the {LABEL}: the same layouts, the same model", "",
             "| strategy | setting | model | participants' successes | oracle's successes |",
             "|---|---|---|---|---|"]
    trials = {t.key: t for t in trial_plan(p)}
    groups: dict[tuple, list] = defaultdict(list)
    for r in study_rows:
        t = trials.get(r.get("key"))
        if t is None or t.phase != "test":
            continue
        model = r.get("model") or (model_for(p, t) if STRATEGIES[t.strategy] == "latent" else "")
        groups[(t.strategy, t.setting, model or "-")].append((r, oracle.get((model, t.task, t.layout_seed))))
    for (strategy, setting, model), pairs in groups.items():
        ours = [o for _, o in pairs if o is not None]
        shown = f"{sum(o['success'] for o in ours)}/{len(ours)}" if ours else "-"
        theirs = f"{sum(r['success'] for r, _ in pairs)}/{len(pairs)}"
        lines.append(f"| {strategy} | {setting} | {model} | {theirs} | {shown} |")
    return "\n".join(lines) + "\n"


def _group(rows: list[dict], keys: tuple[str, ...]) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return out


def model_seal(name: str) -> str:
    """The model's sealed config digest (files.config_sha256): a retrained model has another."""
    from vla_evaluation.resources import latent_model_dir

    cfg = json.loads((latent_model_dir(name) / "config.json").read_text())
    return str(cfg.get("files", {}).get("config_sha256", ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", type=Path, default=SHIPPED)
    ap.add_argument("--participants", default=None, help="sim:N (overrides the file)")
    ap.add_argument("--out", type=Path, default=Path("out/study_oracle"))
    ap.add_argument("--layouts", choices=("test", "development"), default="test")
    ap.add_argument("--loop", choices=LOOPS, default="graph")
    ap.add_argument("--models", choices=("all", "assigned"), default="all",
                    help="every model named for a setting on every layout, or each layout's participant's")
    ap.add_argument("--per-task", type=int, default=None, help="at most this many layouts per task")
    ap.add_argument("--strategies", default=None,
                    help="comma-separated: only these latent strategies (default: all the protocol's)")
    ap.add_argument("--study", type=Path, default=None,
                    help="a study folder: its participants beside the oracle")
    add_engine_arguments(ap)
    a = ap.parse_args(argv)
    try:
        proto = load_protocol(a.protocol)
        if a.participants:
            proto.participants = parse_participants(a.participants)
        chosen = a.strategies.split(",") if a.strategies else None
        units = oracle_units(proto, a.layouts, a.loop, a.models, a.per_task, chosen)
    except (ProtocolError, ValueError) as e:
        print(f"protocol refused:\n{e}")
        return 2
    seals = {u.model: model_seal(u.model) for u in units}
    keyed = {u.key(seals[u.model]): u for u in units}
    store = UnitStore(a.out / "oracle.jsonl", digest({"rate": proto.rate, "time_limit": proto.time_limit}))
    todo = [(k, u) for k, u in keyed.items() if k not in store.done]
    print(f"[oracle] {len(keyed)} episodes, {len(keyed) - len(todo)} already in {store.path}", flush=True)
    failed = run_sweep(todo, OracleWorker, engine=engine_from(a), on_result=store.record,
                       shared={"rate": proto.rate, "time_limit": proto.time_limit}, needs=Needs(cpus=1.0),
                       name="oracle", log=lambda s: print(s, flush=True)) if todo else []
    rows = [store.done[k] for k in keyed if k in store.done]
    if not rows:
        return 1
    text = oracle_tables(rows)
    if a.study is not None:
        study = [json.loads(x) for x in (a.study / "trials.jsonl").read_text().splitlines() if x.strip()]
        text += "\n" + beside_participants(rows, study, proto)
    (a.out / "oracle.md").write_text(text)
    print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

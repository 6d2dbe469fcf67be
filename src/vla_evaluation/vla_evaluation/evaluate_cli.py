"""`vla_evaluation evaluate`: closed-loop evaluation with the simulated teleoperator.

--mode kinematic: the paper's q <- q + phi(z*, s) dt on rendered, detected validation layouts.
--mode graph:     the full node graph (bridge, detector, controller, teleoperator) with physics, in
                  lockstep: the same results at any load (vla_common.lockstep); each episode a unit of
                  a sweep on Ray (a graph per worker; --serial: one, here).
(--mode physics, the graph's computations copied into one process, is gone: PHYSICS_GONE says why.)
Writes episodes.csv, summary.csv, results.json and plots to --out, and prints a table.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from vla_common.catalogue import Catalogue, default_catalogue, load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_detector.inference import Detector
from vla_latent_controller.model import LatentModel

from vla_evaluation.graph import EpisodeRecord, GraphConfig
from vla_evaluation.graph_sweep import EpisodeJob, EpisodeWorker, for_workers
from vla_evaluation.kinematic import VALIDATION_SEED_OFFSET, TeleopSettings, evaluate_kinematic, make_layouts
from vla_evaluation.metrics import summarize
from vla_evaluation.plots import write_evaluation_report
from vla_evaluation.resources import detector_model_path, latent_model_dir
from vla_evaluation.sim_teleoperator import DEFAULT_HORIZON
from vla_evaluation.sweep import Engine, engine_from, run_sweep
from vla_evaluation.sweep import add_arguments as add_engine_arguments

# Why `--mode physics` (and the study's `backend: physics`) is refused: what it was, and what replaces it.
PHYSICS_GONE = ("the in-process physics mode is gone (issue 33): its loop was a copy of the graph's with "
                "another safety-layer configuration (no workspace floor, no contact slowing), the "
                "controller's stick mapping mirrored rather than run and no detector in the loop, so it "
                "gave other numbers for the same trial; the graph runs in lockstep now, deterministic at "
                "any load and as fast as the CPU allows: use --mode graph")


def task_list(spec: str, catalogue: Catalogue | None = None) -> list[str]:
    """"base", "unseen", "all", another task set of the catalogue, or comma-separated task names."""
    cat = catalogue or default_catalogue()
    out: list[str] = []
    for part in spec.split(","):
        part = part.strip()
        if part == "all":
            out.extend(t.name for t in cat.task_set("base") + cat.task_set("unseen"))
        elif part in cat.task_sets:
            out.extend(t.name for t in cat.task_set(part))
        elif part:
            out.append(cat.task(part).name)
    if not out:
        raise ValueError(f"no tasks in {spec!r}")
    return out


def _fraction(text: str) -> float:
    """An argparse type: a number in [0, 1]."""
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not in [0, 1]")
    return value


def add_teleop_arguments(p: argparse.ArgumentParser, rate: float, horizon: float = DEFAULT_HORIZON) -> None:
    d = TeleopSettings()  # the defaults, declared there once
    g = p.add_argument_group("simulated teleoperator and controller")
    g.add_argument("--rate", type=float, default=rate,
                   help="control rate in Hz of simulated time (graph: 100 unless set)")
    g.add_argument("--time-limit", type=float, default=d.time_limit,
                   help="episode length (s), the paper's 30")
    g.add_argument("--switch-time", type=float, default=d.switch_time,
                   help="time on the pre-push waypoint, the paper's k")
    g.add_argument("--horizon", type=float, default=horizon,
                   help=f"look-ahead of the projected state (s; default {horizon:g})")
    g.add_argument("--candidates", type=int, default=d.n_candidates,
                   help="stick values tried over [-1, 1] (odd)")
    g.add_argument("--action-scale", type=float, default=d.action_scale, help="controller action_scale")
    g.add_argument("--max-joint-speed", type=float, default=d.max_joint_speed,
                   help="controller norm clamp (rad/s)")
    g.add_argument("--path-fraction", type=_fraction, default=d.path_fraction,
                   help="controller path_fraction in [0, 1] (default %(default)s: the model's calibrated "
                        "latent.path_fraction, 1 when it has none)")
    g.add_argument("--latent-only", action="store_true",
                   help="graph, tasks with the hand: the user never switches to end-effector mode to align "
                        "the hand where the latent stops short (presses where the path settles)")


def settings_from(args) -> TeleopSettings:
    return TeleopSettings(rate=args.rate, horizon=args.horizon, n_candidates=args.candidates,
                          switch_time=args.switch_time, time_limit=args.time_limit,
                          action_scale=args.action_scale, max_joint_speed=args.max_joint_speed,
                          path_fraction=args.path_fraction, fine_align=not args.latent_only)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=("kinematic", "graph", "physics"), default="kinematic",
                   help="kinematic: the paper's loop; graph: the node graph in lockstep (physics: gone, "
                        "refused with why)")
    p.add_argument("--model", type=Path, default=None,
                   help="latent model directory (default: the shipped one)")
    p.add_argument("--detector-model", type=Path, default=None,
                   help="detector ONNX (default: the shipped one)")
    p.add_argument("--tasks", default="base",
                   help="base, unseen, all, a task set of the catalogue, or comma-separated task names")
    p.add_argument("--catalogue", default="", help="object catalogue YAML (default: the paper's five)")
    p.add_argument("--layouts", type=int, default=10, help="fresh layouts per task")
    p.add_argument("--seed", type=int, default=VALIDATION_SEED_OFFSET, help="first layout seed")
    p.add_argument("--objects", type=int, default=1, help="objects per layout (the task's + distractors)")
    p.add_argument("--out", type=Path, default=Path("out/evaluate"), help="output folder")
    gg = p.add_argument_group("graph mode")
    gg.add_argument("--stop-on-success", action="store_true", help="end an episode 1 s after success")
    gg.add_argument("--real-time-factor", type=float, default=0.0,
                    help="graph: simulated seconds per wall second at most (default 0: as fast as the CPU "
                         "allows; in lockstep it only slows the run, the results are the same)")
    gg.add_argument("--free-running", action="store_true",
                    help="graph: no lockstep, the simulation paced by the wall clock at --real-time-factor "
                         "(how it ran before issue 33: outcomes then depend on the machine's load)")
    gg.add_argument("--domain-id", type=int, default=None,
                    help="ROS_DOMAIN_ID for the graph, with --serial (default and on Ray: a graph's own)")
    add_teleop_arguments(p, rate=20.0)
    add_engine_arguments(p)


def run(args) -> int:
    if args.mode == "physics":
        print(f"evaluate: {PHYSICS_GONE}", file=sys.stderr)
        return 2
    catalogue = load_catalogue(args.catalogue)
    tasks = task_list(args.tasks, catalogue)
    seeds = [args.seed + i for i in range(args.layouts)]
    model_dir = args.model or latent_model_dir("default")
    det_path = args.detector_model or detector_model_path()
    for what, path in (("latent model", model_dir), ("detector model", det_path)):
        if not Path(path).exists():
            print(f"evaluate: {what} {path} not found (train one, or run `make demo` which trains it)",
                  file=sys.stderr)
            return 2
    settings = settings_from(args)
    t0 = time.monotonic()
    if args.mode != "kinematic" and args.rate == 20.0:
        settings.rate = 100.0  # the controller node's default rate
    if args.mode == "kinematic":
        results = _kinematic(model_dir, det_path, tasks, seeds, settings, args.objects, catalogue)
    else:
        rtf = args.real_time_factor or (2.0 if args.free_running else 0.0)
        cfg = GraphConfig(model_path=str(model_dir), detector_model=str(det_path),
                          lockstep=not args.free_running, real_time_factor=rtf, rate=settings.rate,
                          settings=settings,
                          stop_on_success=args.stop_on_success, domain_id=args.domain_id,
                          log_dir=args.out / "logs", catalogue=args.catalogue)
        results = _graph(cfg, tasks, seeds, Path(model_dir).name, args.objects, engine_from(args))
    meta = {"mode": args.mode, "model": str(model_dir), "detector_model": str(det_path), "tasks": tasks,
            "seeds": seeds, "settings": vars(settings), "wall_s": round(time.monotonic() - t0, 1)}
    write_evaluation_report(results, args.out, meta)
    print_table(summarize(results, ("task",)))
    print(f"wrote {args.out}/ (episodes.csv, summary.csv, results.json, plots) in {meta['wall_s']} s")
    return 0


def _result(rec: EpisodeRecord):
    return rec.result


def _graph(cfg: GraphConfig, tasks, seeds, label: str, n_objects: int, engine: Engine) -> list:
    """Every (task, seed) episode as a unit of a sweep; the results in the plan's order."""
    units = [(f"{t}/{s}", (t, s)) for t in tasks for s in seeds]
    job = EpisodeJob(cfg if engine.serial else for_workers(cfg), label, n_objects, summarise=_result,
                     own_logs=not engine.serial)
    got: dict = {}

    def on_result(key: str, r) -> None:
        got[key] = r
        tts = r.time_to_success if r.time_to_success is not None else float("nan")
        print(f"[graph] {r.task:28s} seed {r.layout_seed:>8d}  success {r.success!s:5s}  final state error "
              f"{r.final_state_error:.3f} rad  time {tts:5.1f} s  interventions {r.safety_interventions}  "
              f"violations {r.limit_violations}  ({r.extra['wall_s']:.1f} s wall)", flush=True)

    failed = run_sweep(units, EpisodeWorker, engine=engine, on_result=on_result, shared=job, name="evaluate")
    if failed:
        raise SystemExit(f"evaluate: {len(failed)} episodes failed ({', '.join(failed)}); see above")
    return [got[k] for k, _ in units]


def _kinematic(model_dir, det_path, tasks, seeds, settings, n_objects, catalogue):
    model = LatentModel.load(model_dir)
    kin = PandaKinematics()
    layouts = make_layouts(tasks, seeds, detector=Detector(det_path), kin=kin, n_objects=n_objects,
                           catalogue=catalogue)
    return evaluate_kinematic(model, layouts, settings, kin=kin, label=Path(model_dir).name)


def print_table(summary: list[dict], file=None) -> None:
    file = file or sys.stdout
    print(f"{'task':30s} {'episodes':>8s} {'success':>8s} {'final state error (rad)':>24s} "
          f"{'time to success':>16s} {'interventions':>14s} {'violations':>10s}", file=file)
    for r in summary:
        sr = "-" if r["success_rate"] is None else f"{100 * r['success_rate']:.0f} %"
        tts = "-" if r["time_to_success_median"] is None else f"{r['time_to_success_median']:.1f} s"
        fse = f"{r['final_state_error']:.3f} +- {r['final_state_error_sem']:.3f}"
        iv = "-" if r["safety_interventions"] is None else str(r["safety_interventions"])
        lv = "-" if r["limit_violations"] is None else str(r["limit_violations"])
        print(f"{r['task']:30s} {r['episodes']:8d} {sr:>8s} {fse:>24s} {tts:>16s} {iv:>14s} {lv:>10s}",
              file=file)

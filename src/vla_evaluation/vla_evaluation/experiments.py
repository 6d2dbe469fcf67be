"""`make experiments`: the paper's simulation experiments, evaluated with the simulated teleoperator.

Figure 2a: final state error vs demonstrations per object (1..10) for the `detector`, `localization`
and `end_to_end` encoders on the four base tasks; several runs, each on a different random subset
of the demonstrations; validation layouts never used for demonstrations.
Figure 2c: the unseen cereal box (Seen = push south, Near = push south-east, Far = circle):
transfer (all base demos + k new) vs no transfer (k new only), k = 1..5.
Figure 2b: end-effector paths of the three encoders (10 demos) on the bread task, top-down.

Evaluation is the paper's kinematic loop (`evaluation.kinematic`) on rendered, detected layouts.
Each model (train, then evaluate) is one unit of a sweep on Ray (`vla_evaluation.sweep`: a local Ray,
or a cluster with --ray-address; a GPU per training where the cluster has one). Finished models stream
into `<work>/<plan digest>/models.jsonl`, so a stopped run resumes with the models it lacks. Output in
--out (default docs/results/): CSV of every episode, per-run aggregates, PNG plots and README.md
comparing with H1-H3.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from vla_common.kinematics import PandaKinematics
from vla_common.tasks import BASE_TASKS, parse_task, task_layout
from vla_demo_recorder.dataset import Demo
from vla_detector.inference import Detector
from vla_latent_controller.model import LatentModel
from vla_latent_training.config import POSITION_PRIOR_SCALE, TrainConfig
from vla_latent_training.train_cli import position_scale_arg
from vla_sim.planner import PlanError, plan_task, random_start_pose

from vla_evaluation.experiment_report import demo_consistency, write_report
from vla_evaluation.kinematic import VALIDATION_SEED_OFFSET, TeleopSettings, evaluate_kinematic, make_layouts
from vla_evaluation.resources import detector_model_path
from vla_evaluation.sweep import Engine, Needs, engine_from, run_sweep
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_evaluation.training_data import (
    BASE_SEED,
    UNSEEN_SEED,
    ensure_demos,
    ensure_detector,
    load_task_demos,
)
from vla_evaluation.unit_store import UnitStore, digest

ENCODERS = ("detector", "localization", "end_to_end")
SETTINGS_2C = {
    "Seen": "cereal_box/push_south",
    "Near": "cereal_box/push_south_east",
    "Far": "cereal_box/circle",
}


@dataclass
class Plan:
    """What to run. The defaults fit `make experiments` in under an hour on 2 cores: 3 runs (the
    paper: 10) and 100 training epochs with the learning-rate step at 40 (the paper: 1000 and 400),
    but at least 1000 optimiser updates per model. With batches of 6000 pairs (the paper's, about a
    full batch) a model on 1 demo per object gets one update an epoch: 100 epochs left the small-data
    models far from converged (final state error 1.45 rad at 1 demo/object vs 0.95 with 1000 updates,
    measured on the same demos), and the paper's 1000 epochs give every model >= 1000 updates.
    Hidden layers have 64 units (the paper: 30; the shipped models: 128): at 30 every encoder was
    capacity-bound (10 demos/object, 3 runs: final state error detector 0.58, localization 0.63 rad;
    at 64: 0.33 and 0.45), and 128 does not fit the hour (the CNN encoders' models take longest).
    The detector's (x, y) are divided by a fixed scale (train.POSITION_PRIOR_SCALE), not by the
    demos' spread as by default: at 1-2 demos per object, where each class's position is one or two
    points, the default made the decoder extrapolate from spurious position effects (same subsets,
    seeds and layouts, 64 units: 0.88 / 0.58 / 0.32 / 0.33 rad at 1 / 2 / 5 / 10 demos per object
    vs 0.62 / 0.46 / 0.35 / 0.34); `--position-scale demos` runs the default."""

    encoders: Sequence[str] = ENCODERS
    demo_counts: Sequence[int] = tuple(range(1, 11))
    k_counts: Sequence[int] = tuple(range(1, 6))
    runs: int = 3
    layouts: int = 10
    epochs: int = 100
    step_size: int = 40
    hidden: int = 64
    min_steps: int = 1000  # TrainConfig.min_steps
    position_scale: float | None = POSITION_PRIOR_SCALE  # TrainConfig.position_scale
    fig2a: bool = True
    fig2c: bool = True
    rate: float = 20.0
    extra: dict = field(default_factory=dict)

    def train_config(self, encoder: str, seed: int) -> TrainConfig:
        """The TrainConfig of every model this plan trains."""
        return TrainConfig(encoder=encoder, epochs=self.epochs, step_size=self.step_size, seed=seed,
                           hidden=self.hidden, min_steps=self.min_steps, position_scale=self.position_scale)


def quick_plan() -> Plan:
    return Plan(demo_counts=(1, 3), k_counts=(1, 3), runs=1, layouts=3, epochs=60, step_size=30, rate=10.0,
                min_steps=120)


# ------------------------------------------------------------------ demonstrations
def simulate_demos(task: str, episodes: int, seed: int, detector, sim=None, kin=None) -> list:
    """Demonstrations made in-process (PandaSim + the task planner, no ROS): the same planner and
    physics as `vla_demo_recorder generate`, recorded at 10 Hz with the first camera frame and its
    detection. Used by --quick and --demo-source sim."""
    from vla_sim.sim import PandaSim  # MuJoCo: only where demos are simulated

    spec = parse_task(task)
    kin = kin or PandaKinematics()
    sim = sim or PandaSim()
    demos = []
    attempt = 0
    while len(demos) < episodes:
        rng = np.random.default_rng([seed, attempt])
        attempt += 1
        if attempt > 50 * episodes:
            raise RuntimeError(f"could not plan {episodes} demonstrations of {task}")
        layout = task_layout(spec, rng, n_objects=1)
        q0 = random_start_pose(rng)
        sim.reset(objects=layout, q0=q0)
        sim.step(50)
        goal = next(o for o in sim.object_poses() if o.class_id == spec.object_class)
        try:
            plan = plan_task(kin, spec, goal, sim.q, rng)
        except PlanError:
            continue
        image = sim.render()
        dets = [d for d in detector.detect(image)] if detector is not None else []
        same = [d for d in dets if d.class_id == spec.object_class] or dets
        det = max(same, key=lambda d: d.score) if same else None
        qs, t0 = [sim.q], sim.time
        every = int(round(0.1 / sim.physics_dt))
        n = int(np.ceil((plan.duration + 0.5) / sim.physics_dt))
        for i in range(1, n + 1):
            sim.set_velocity_command(np.clip(plan.command(sim.time - t0, sim.q), -2.0, 2.0))
            sim.step(1)
            if i % every == 0:
                qs.append(sim.q)
        sim.set_velocity_command(np.zeros(7))
        q = np.asarray(qs)
        demos.append(
            Demo(
                task=spec.name,
                object_class=spec.object_class,
                t=np.arange(len(q)) * 0.1,
                q=q,
                first_image=image,
                detection=det,
                image_size=(image.shape[1], image.shape[0]),
                bag_path=f"sim:{spec.name}:{seed}:{attempt - 1}",
            )
        )
    return demos


def collect_demos(
    tasks_counts: dict[str, int], source: str, data_dir: Path, detector, log: Callable[[str], None]
) -> dict[str, list]:
    """{task: demos} with at least the requested count each."""
    out = {}
    sim = kin = None
    for i, (task, count) in enumerate(tasks_counts.items()):
        seed = (BASE_SEED if not task.startswith("cereal_box") else UNSEEN_SEED) + 100 * i
        if source == "sim":
            if sim is None:
                from vla_sim.sim import PandaSim  # MuJoCo: only for --demo-source sim

                sim, kin = PandaSim(), PandaKinematics()
            out[task] = simulate_demos(task, count, seed, detector, sim, kin)
        else:
            folder = ensure_demos(task, count, data_dir, seed, log)
            out[task] = load_task_demos(folder, task, detector, count)
        log(f"[data] {task}: {len(out[task])} demonstrations")
        if len(out[task]) < count:
            raise RuntimeError(f"only {len(out[task])} usable demonstrations of {task} (need {count})")
    return out


# ------------------------------------------------------------------ jobs (units of the sweep)
@dataclass
class Job:
    figure: str  # "2a" or "2c"
    encoder: str
    run: int
    count: int  # demos per object (2a) or new demos k (2c)
    train: dict  # {task: [demo indices]}
    eval_tasks: Sequence[str]
    setting: str = ""  # Seen / Near / Far
    variant: str = ""  # transfer / no_transfer
    keep_paths: bool = False


    @property
    def key(self) -> str:
        return "/".join(str(x) for x in (self.figure, self.encoder, self.setting or "-", self.variant or "-",
                                         f"n{self.count}", f"r{self.run}"))


class ExperimentWorker:
    """A sweep worker: holds the demonstrations, layouts and settings (`state`, sent once per worker)
    and trains and evaluates one model per unit."""

    def __init__(self, state: dict) -> None:
        self.state = state

    def run(self, job: Job) -> list[dict]:
        return run_job(job, self.state)

    def close(self) -> None:
        pass


def run_job(job: Job, state: dict) -> list[dict]:
    """Train one model on the job's demos and evaluate it on the validation layouts (on a GPU where
    this worker has one)."""
    import torch  # only in the worker that trains
    from vla_latent_training.train import train_model  # torch

    torch.set_num_threads(1)
    demos = [state["demos"][t][i] for t, idx in job.train.items() for i in idx]
    plan: Plan = state["plan"]
    cfg = plan.train_config(job.encoder, seed=job.run)
    t0, c0 = time.perf_counter(), time.process_time()
    tmp = Path(tempfile.mkdtemp(prefix="vla_exp_"))
    res = None
    try:
        res = train_model(demos, cfg, progress=False, threads=1, log=lambda s: None,
                          device="cuda" if torch.cuda.is_available() else None)
        train_s, train_cpu_s = time.perf_counter() - t0, time.process_time() - c0
        model = LatentModel.load(res.save(tmp / "model"))
        layouts = [lay for lay in state["layouts"] if lay.task in job.eval_tasks]
        kin = PandaKinematics() if job.keep_paths else None
        t1, c1 = time.perf_counter(), time.process_time()
        results = evaluate_kinematic(model, layouts, state["settings"], kin=kin, label=job.encoder)
        eval_s, eval_cpu_s = time.perf_counter() - t1, time.process_time() - c1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if res is not None and res.cnn_onnx:
            shutil.rmtree(Path(res.cnn_onnx).parent, ignore_errors=True)
    rows = []
    for r in results:
        row = {
            "figure": job.figure,
            "encoder": job.encoder,
            "setting": job.setting,
            "variant": job.variant,
            "count": job.count,
            "run": job.run,
            "task": r.task,
            "layout_seed": r.layout_seed,
            "final_state_error": r.final_state_error,
            "start_error": r.extra.get("start_error"),
            "waypoint_error": r.extra.get("waypoint_error"),
            "detected_class": r.detected_class,
            "note": r.note,
            "train_demos": len(demos),
            "train_s": round(train_s, 2),
            "eval_s": round(eval_s, 2),
            # CPU seconds of the worker's process: the unit's cost whatever else loads the machine
            "train_cpu_s": round(train_cpu_s, 2),
            "eval_cpu_s": round(eval_cpu_s, 2),
            "val_loss": res.config["training"].get("val_loss"),
        }
        if job.keep_paths and r.ee_path is not None:
            row["_path"] = np.asarray(r.ee_path)[:, :2].round(4).tolist()
            row["_object"] = r.object_start
        rows.append(row)
    return rows


def _subset(indices_available: int, n: int, seed: Sequence[int]) -> list[int]:
    rng = np.random.default_rng(list(seed))
    return sorted(rng.choice(indices_available, size=min(n, indices_available), replace=False).tolist())


def make_jobs(plan: Plan, base_tasks: Sequence[str], shortest_first: bool = False) -> list[Job]:
    jobs: list[Job] = []
    if plan.fig2a:
        for enc in plan.encoders:
            for n in plan.demo_counts:
                for r in range(plan.runs):
                    train = {
                        t: _subset(max(plan.demo_counts), n, (r, n, i)) for i, t in enumerate(base_tasks)
                    }
                    keep = n == max(plan.demo_counts) and r == 0
                    jobs.append(Job("2a", enc, r, n, train, list(base_tasks), keep_paths=keep))
    if plan.fig2c:
        for setting, task in SETTINGS_2C.items():
            for k in plan.k_counts:
                for r in range(plan.runs):
                    new = _subset(max(plan.k_counts), k, (r, k, 99))
                    base = {t: list(range(max(plan.demo_counts))) for t in base_tasks}
                    jobs.append(Job("2c", "detector", r, k, {**base, task: new}, [task], setting, "transfer"))
                    jobs.append(Job("2c", "detector", r, k, {task: new}, [task], setting, "no_transfer"))
    # run by run, so that a sweep stopped early has every point of the figures with the same number of
    # runs; within a run longest first, which keeps the workers busy to the end (shortest first: the
    # most models in a bounded time)
    sign = 1 if shortest_first else -1

    def cost(j: Job) -> int:  # the image encoders' models take about three times as long
        return sum(map(len, j.train.values())) * (1 if j.encoder == "detector" else 3)

    jobs.sort(key=lambda j: (j.run, sign * cost(j)))
    return jobs


# ------------------------------------------------------------------ CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: docs/results; with --quick out/experiments_quick)",
    )
    p.add_argument("--quick", action="store_true", help="small version for CI (<= 3 minutes)")
    p.add_argument(
        "--data", type=Path, default=Path("out/data"), help="demonstration bags (generated if missing)"
    )
    p.add_argument(
        "--demo-source",
        choices=("bags", "sim"),
        default=None,
        help="bags: `vla_demo_recorder generate` through the graph (default); sim: in-process",
    )
    p.add_argument("--detector-model", type=Path, default=None, help="detector ONNX (default: shipped)")
    p.add_argument("--runs", type=int, default=None, help="runs (demo subsets / seeds) per point")
    p.add_argument("--epochs", type=int, default=None, help="training epochs per model")
    p.add_argument("--layouts", type=int, default=None, help="validation layouts per task")
    p.add_argument("--min-steps", type=int, default=None,
                   help="at least this many optimiser updates per model (epochs scaled up for few demos)")
    p.add_argument("--counts", default=None,
                   help="Figure 2a demo counts, comma-separated (default 1..10); subsets are drawn "
                   "from the first max(counts) demos of each task")
    p.add_argument("--only", choices=("2a", "2c"), default=None, help="run one figure only")
    p.add_argument("--position-scale", type=position_scale_arg, default=POSITION_PRIOR_SCALE,
                   help="the detector's (x, y) divided by this number (default: 0.2887 = sqrt(1/12)) "
                        "or by their spread over the demos ('demos', the training default)")
    p.add_argument(
        "--encoders", default=None, help="comma-separated subset of detector,localization,end_to_end"
    )
    p.add_argument("--work", type=Path, default=Path("out/experiments"),
                   help="where finished models are kept, per plan, so that a stopped run resumes")
    p.add_argument("--limit", type=int, default=None, help="run at most this many models now (resumable)")
    p.add_argument("--shortest-first", action="store_true",
                   help="within each run the cheapest models first (the most models in a bounded time); "
                        "default longest first")
    p.add_argument("--gpu-share", type=float, default=1.0,
                   help="the share of a GPU each training asks for where the cluster has GPUs")
    add_engine_arguments(p)


def plan_from(args) -> Plan:
    plan = quick_plan() if args.quick else Plan()
    plan.position_scale = getattr(args, "position_scale", plan.position_scale)
    for name in ("runs", "epochs", "layouts", "min_steps"):
        if getattr(args, name) is not None:
            setattr(plan, name, getattr(args, name))
    if args.epochs is not None:
        plan.step_size = max(1, int(round(0.4 * args.epochs)))
    if args.counts:
        plan.demo_counts = tuple(int(c) for c in args.counts.split(",") if c.strip())
    if args.encoders:
        plan.encoders = tuple(e.strip() for e in args.encoders.split(",") if e.strip())
    if args.only:
        plan.fig2a, plan.fig2c = args.only == "2a", args.only == "2c"
    return plan


def run(args) -> int:
    t_all = time.monotonic()
    plan = plan_from(args)
    engine = engine_from(args)
    source = args.demo_source or ("sim" if args.quick else "bags")
    out = (
        Path(args.out)
        if args.out is not None
        else Path("out/experiments_quick" if args.quick else "docs/results")
    )
    out.mkdir(parents=True, exist_ok=True)
    log = _log
    det_path = ensure_detector(args.detector_model or detector_model_path(), args.data, log)
    plan_meta = {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(plan).items()}
    store = UnitStore(Path(args.work) / digest([plan_meta, source, _file_digest(det_path)]) / "models.jsonl",
                      digest([plan_meta, source, _file_digest(det_path)]))
    jobs = make_jobs(plan, BASE_TASKS)  # the report's order
    order = make_jobs(plan, BASE_TASKS, args.shortest_first)
    todo = [j for j in order if j.key not in store.done][: args.limit]
    log(f"[experiments] {len(jobs)} models ({plan.epochs} epochs each), {len(jobs) - len(todo)} already in "
        f"{store.path}, {len(todo)} to train and evaluate on {engine.describe()}")
    demos, seeds, settings = None, [], TeleopSettings(rate=plan.rate)
    if todo:
        demos, seeds = _run_models(plan, todo, store, engine, source, args, det_path, settings, log,
                                   len(jobs) - len(todo), args.gpu_share)
    missing = [j.key for j in jobs if j.key not in store.done]
    if missing:
        log(f"[experiments] {len(missing)} of {len(jobs)} models missing (failed or not run yet): run the "
            "same command again to train them; the report is written when all are done")
        return 1 if todo else 0
    rows = [row for j in jobs for row in store.done[j.key]]  # the plan's order, whatever finished first
    meta = {
        "demo_consistency": demo_consistency(demos) if demos is not None else [],
        "plan": plan_meta,
        "demo_source": source,
        "detector_model": str(det_path),
        "validation_seeds": seeds or [VALIDATION_SEED_OFFSET + i for i in range(plan.layouts)],
        "settings": vars(settings),
        "wall_s": round(time.monotonic() - t_all, 1),
        "quick": bool(args.quick),
        "engine": engine.describe(),
    }
    write_report(rows, out, meta)
    log(f"[experiments] done in {meta['wall_s'] / 60:.1f} min: {out}/README.md")
    return 0


def _run_models(plan: Plan, todo: list[Job], store: UnitStore, engine: Engine, source: str, args, det_path,
                settings: TeleopSettings, log, done_before: int, gpu_share: float):
    """The demonstrations and validation layouts (made here, once), then every model of `todo` as a
    unit of the sweep; each finished model's rows go into `store` as it arrives."""
    detector = Detector(det_path)
    need = {t: max(plan.demo_counts) for t in BASE_TASKS}
    if plan.fig2c:
        need.update({t: max(plan.k_counts) for t in SETTINGS_2C.values()})
    log(f"[experiments] demonstrations ({source}): " + ", ".join(f"{t} x{n}" for t, n in need.items()))
    demos = collect_demos(need, source, args.data, detector, log)
    eval_tasks = list(BASE_TASKS) + (list(SETTINGS_2C.values()) if plan.fig2c else [])
    seeds = [VALIDATION_SEED_OFFSET + i for i in range(plan.layouts)]
    log(f"[experiments] rendering and detecting {len(eval_tasks) * len(seeds)} validation layouts")
    layouts = make_layouts(eval_tasks, seeds, detector=detector)
    state = {"demos": demos, "layouts": layouts, "settings": settings, "plan": plan}
    t0 = time.monotonic()
    failed = run_sweep([(j.key, j) for j in todo], ExperimentWorker, engine=engine, on_result=store.record,
                       shared=state, needs=Needs(cpus=1.0, gpu=gpu_share), name="experiments",
                       done_before=done_before, log=log)
    log(f"[experiments] {len(todo) - len(failed)} models in {(time.monotonic() - t0) / 60:.1f} min"
        + (f"; failed: {', '.join(failed)}" if failed else ""))
    return demos, seeds


def _file_digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def _log(text: str) -> None:
    print(text, flush=True)

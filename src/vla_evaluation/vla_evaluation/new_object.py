"""`vla_evaluation new-object`: teach the robot a new object, end to end, in simulation, and measure it.

The walkthrough of docs/new-object.md as one command. Every step runs the command a user types
(each is logged as `[run] ...`), in this order:

1. renders of scenes that contain the new object (`vla_detector_training synth --catalogue`), and as
   many held-out ones (other seeds, split `test`) to measure on;
2. the detector fine-tuned from the shipped one (`train --init shipped`), the same with renders of the
   whole scene mixed in (`--mix-synth`), and, for comparison, trained from scratch on the same renders;
   each measured (AP@0.5 per class) on the held-out renders, the fine-tuned and the from-scratch
   training timed over repeated runs (median);
3. demonstrations of the new task through the ROS graph (`vla_evaluation generate --catalogue`, with
   the fine-tuned detector in the graph, so the bags hold its detections), and the base tasks'
   demonstrations, generated once and cached under --data exactly as `make demo` caches them;
4. the transfer model: the base demonstrations plus the first k new ones in one model
   (`vla_latent_training train --catalogue`);
5. `vla_evaluation evaluate --mode graph` on fresh layouts of the new task (seeds from 100000, never a
   demonstration's): the success rate. When k demonstrations fall short of the goal, k = 1 ... max are
   all measured and the smallest k that reaches it is reported.

A step whose output is already there is reused (an interrupted run resumes where it stopped); nothing
given to it is modified. Figures are read from the files the commands write (`vla_detector_training
evaluate --json`, the evaluation's results.json), never from their printed output, into typed results
(`NewObjectResults`); they go to --out as results.json and README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path

from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.safety_status import code_name
from vla_common.tasks import BASE_TASKS

from vla_evaluation.kinematic import VALIDATION_SEED_OFFSET
from vla_evaluation.resources import detector_model_path, is_latent_model
from vla_evaluation.training_data import BASE_EPISODES, BASE_SEED, count_bags, ensure_demos, run_command

DETECTOR_AP_GOAL = 0.9  # AP@0.5 of the new class on the held-out renders
DETECTOR_OLD_MAP_GOAL = 0.95  # mAP@0.5 over the classes the shipped detector knew
FINE_TUNE_TIME_GOAL_S = 300.0  # on the 2-core machine
SUCCESS_GOAL = 0.8
NEW_DEMO_SEED = 7_000  # demonstrations of the new task: seeds apart from the base ones (0...) and layouts
RENDER_SEED, TEST_RENDER_SEED = 11, 12
# Fine-tuning from the shipped detector validates at mAP@0.5 >= 0.99 within 6 epochs on 90 renders;
# 10 epochs keep it within the 5 min goal on the shared 2-core machine (about 25 s an epoch at load 6).
DETECTOR_EPOCHS = 10


@dataclass
class NewObjectConfig:
    catalogue: Path
    task: str
    out: Path
    data: Path = Path("out/data")  # base demonstrations, shared with `make demo`
    renders: int = 100
    test_renders: int = 100
    detector_epochs: int | None = DETECTOR_EPOCHS  # both detectors; None: the train command's default
    scratch: bool = True
    mix_synth: int = 100  # also measure fine-tuning with N renders of the scene mixed in (0: not)
    timing_repeats: int = 2  # extra trainings of fine-tuned and scratch, for the median time
    demos: int = 3
    max_demos: int = 5
    sweep: str = "auto"  # auto: 1..max_demos only when `demos` falls short; always; never
    latent_epochs: int = 1000
    latent_seed: int = 0
    layouts: int = 10
    layout_seed: int = VALIDATION_SEED_OFFSET
    real_time_factor: float = 2.0
    goal: float = SUCCESS_GOAL
    extra_eval_args: list[str] = field(default_factory=list)

    def path(self, *parts: str) -> Path:
        return Path(self.out).joinpath(*parts)


# ---------------------------------------------------------------------------------------------- results
@dataclass
class Timing:
    """A project command's wall time and CPU time (user + system, the command and what it waited
    for), in seconds. On a shared machine the CPU time is the steadier figure."""

    wall_s: float
    cpu_s: float | None = None


@dataclass
class DetectorFigures:
    """A detector on the held-out renders (`vla_detector_training evaluate --json`), with its training
    time, the new class's AP@0.5 and the mean AP@0.5 over the classes the shipped detector knew."""

    model: str
    train_wall_s: float
    train_cpu_s: float | None
    split: str
    images: int
    map50: float
    map50_95: float
    centre_error_px: float | None  # None: nothing matched
    precision: float
    recall: float
    ap50: dict[str, float]
    new_class_ap50: float | None
    old_classes_map50: float | None


@dataclass
class TimingRuns:
    """Repeated trainings of one detector: wall and CPU seconds of each run and their medians."""

    runs_s: list[float]
    median_s: float
    cpu_runs_s: list[float]
    median_cpu_s: float | None


@dataclass
class TransferFigures:
    """One transfer model's graph evaluation of the new task: the evaluation's summary row, how often
    the detector latched the task's object, and the safety layer's interventions by kind."""

    task: str
    episodes: int
    success_rate: float | None
    final_state_error: float | None
    final_state_error_sem: float | None
    time_to_success_median: float | None
    safety_interventions: int | None
    limit_violations: int | None
    detected_task_object: int
    interventions_by_code: dict[str, int]
    model: str = ""


@dataclass
class Machine:
    cpu: str
    cores: int | None
    load_average_at_start: list[float]
    python: str


@dataclass
class NewObjectResults:
    """Everything a run measured; results.json is its JSON form."""

    command: str
    date: str
    machine: Machine
    config: dict[str, object]  # NewObjectConfig, paths as text
    catalogue: str
    shipped_detector: str
    steps_s: dict[str, float] = field(default_factory=dict)
    steps_reused: list[str] = field(default_factory=list)
    detector: dict[str, DetectorFigures] = field(default_factory=dict)
    detector_timing: dict[str, TimingRuns] = field(default_factory=dict)
    detector_time_ratio: float | None = None  # median, from scratch / fine-tuned
    detector_cpu_time_ratio: float | None = None
    new_demos: list[str] = field(default_factory=list)
    base_demos: dict[str, int] = field(default_factory=dict)
    transfer: dict[str, TransferFigures] = field(default_factory=dict)  # by the count of new demos
    smallest_sufficient_demos: int | None = None
    wall_s: float = 0.0
    verdicts: dict[str, bool | None] = field(default_factory=dict)

    def save(self, folder: Path) -> None:
        (Path(folder) / "results.json").write_text(json.dumps(asdict(self), indent=2) + "\n")


# ---------------------------------------------------------------------------------------------- steps
class Commands:
    """Runs the project's commands as a user types them (`training_data.run_command`) and counts
    them: a step that ran none was reused."""

    def __init__(self, log: Callable[[str], None]) -> None:
        self.log = log
        self.count = 0

    def run(self, cmd: Sequence[str], accept: Sequence[int] = (0,)) -> int:
        self.count += 1
        return run_command(cmd, self.log, accept)

    def timed(self, cmd: Sequence[str], accept: Sequence[int] = (0,)) -> Timing:
        """Run a command: its wall time and CPU time."""
        t0, r0 = time.monotonic(), resource.getrusage(resource.RUSAGE_CHILDREN)
        self.run(cmd, accept)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        return Timing(time.monotonic() - t0, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))


def render(cfg: NewObjectConfig, cmds: Commands) -> tuple[Path, Path]:
    """Training renders (train + val) and held-out renders (test), each scene with the new object."""
    obj = cfg.task.split("/", 1)[0]
    sets = ((cfg.path("renders"), cfg.renders, RENDER_SEED, "auto"),
            (cfg.path("renders_test"), cfg.test_renders, TEST_RENDER_SEED, "test"))
    for folder, count, seed, split in sets:
        if (folder / "data.yaml").is_file():
            cmds.log(f"[new-object] reusing {folder}")
            continue
        cmds.run(["vla_detector_training", "synth", "--catalogue", str(cfg.catalogue), "--include", obj,
                  "--count", str(count), "--seed", str(seed), "--split", split, "--out", str(folder),
                  "--quiet"])
    return sets[0][0], sets[1][0]


def onnx_in(folder: Path) -> Path | None:
    found = sorted(Path(folder).glob("*.onnx"))
    return found[0] if found else None


def train_detector(cfg: NewObjectConfig, renders: Path, name: str, extra: Sequence[str],
                   cmds: Commands) -> tuple[Path, Timing]:
    """(ONNX, training time) of a detector trained on the renders (whose data.yaml names the
    catalogue's classes) into out/<name>, with the train command's `extra` options (`--init shipped`:
    fine-tuning; none: from scratch)."""
    out = cfg.path(name)
    timing = out / "train_time.json"
    if onnx_in(out) is not None and timing.is_file():
        cmds.log(f"[new-object] reusing {out}")
        saved = json.loads(timing.read_text())
        return onnx_in(out), Timing(float(saved["wall_s"]), saved.get("cpu_s"))
    cmd = ["vla_detector_training", "train", "--data", str(renders), "--out", str(out), *extra, "--quiet"]
    if cfg.detector_epochs is not None and "--epochs" not in extra:
        cmd += ["--epochs", str(cfg.detector_epochs)]
    times = cmds.timed(cmd)
    model = onnx_in(out)
    if model is None:
        raise RuntimeError(f"detector training wrote no .onnx into {out}")
    timing.write_text(json.dumps({**asdict(times), "command": cmd}) + "\n")
    return model, times


def detector_variants(cfg: NewObjectConfig) -> dict[str, tuple[str, list[str]]]:
    """key -> (folder, train options) of the detectors measured; `fine_tuned` is the one used on."""
    out = {"fine_tuned": ("detector", ["--init", "shipped"])}
    if cfg.mix_synth > 0:
        out["fine_tuned_mix"] = ("detector_mix", ["--init", "shipped", "--mix-synth", str(cfg.mix_synth),
                                                  "--catalogue", str(cfg.catalogue)])
    if cfg.scratch:
        out["scratch"] = ("detector_scratch", [])
        if cfg.detector_epochs:  # how far from scratch gets with four times the epochs (and the time)
            out["scratch_4x_epochs"] = ("detector_scratch_4x", ["--epochs", str(4 * cfg.detector_epochs)])
    return out


def median_timing(cfg: NewObjectConfig, renders: Path, first: dict[str, Timing],
                  cmds: Commands) -> dict[str, TimingRuns]:
    """Training time of the fine-tuned and the from-scratch detector over 1 + timing_repeats runs
    each (alternating, so that a change in the shared machine's load falls on both): runs and median."""
    keys = [k for k in ("fine_tuned", "scratch") if k in first]
    runs = {k: [first[k]] for k in keys}
    variants = detector_variants(cfg)
    for r in range(1, cfg.timing_repeats + 1):
        for k in keys:
            runs[k].append(train_detector(cfg, renders, f"timing/{k}_{r}", variants[k][1], cmds)[1])
    out = {}
    for k, vs in runs.items():
        wall, cpu = [v.wall_s for v in vs], [v.cpu_s for v in vs if v.cpu_s is not None]
        out[k] = TimingRuns(runs_s=[round(v, 1) for v in wall], median_s=statistics.median(wall),
                            cpu_runs_s=[round(v, 1) for v in cpu],
                            median_cpu_s=statistics.median(cpu) if cpu else None)
    return out


def read_evaluation(path: Path) -> dict:
    """The figures `vla_detector_training evaluate --json` wrote; RuntimeError when there are none."""
    try:
        fig = json.loads(Path(path).read_text())
        return {"split": str(fig["split"]), "images": int(fig["images"]), "map50": float(fig["map50"]),
                "map50_95": float(fig["map50_95"]),
                "centre_error_px": None if fig["centre_error_px"] is None else float(fig["centre_error_px"]),
                "precision": float(fig["precision"]), "recall": float(fig["recall"]),
                "ap50": {str(c): float(v) for c, v in fig["per_class_ap50"].items()}}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise RuntimeError(f"vla_detector_training evaluate wrote no figures to {path} "
                           f"({type(e).__name__})") from None


def detector_figures(model: Path, test_renders: Path, new_class: str, old_classes: Sequence[str],
                     times: Timing, cmds: Commands) -> DetectorFigures:
    """AP@0.5 per class on the held-out renders (`vla_detector_training evaluate`, its figures in
    held_out.json beside the model, reused by a rerun), the new class's, and the mean over the old
    classes."""
    figures = model.parent / "held_out.json"
    if not figures.is_file():
        cmds.run(["vla_detector_training", "evaluate", "--model", str(model), "--data", str(test_renders),
                  "--split", "test", "--json", str(figures), "--quiet"])
    fig = read_evaluation(figures)
    ap = fig["ap50"]
    old = [ap[c] for c in old_classes if c in ap]
    return DetectorFigures(model=str(model), train_wall_s=times.wall_s, train_cpu_s=times.cpu_s, **fig,
                           new_class_ap50=ap.get(new_class),
                           old_classes_map50=statistics.fmean(old) if old else None)


def new_task_demos(cfg: NewObjectConfig, detector: Path, cmds: Commands, attempts: int = 3) -> list[Path]:
    """`max_demos` successful demonstration bags of the new task (generated through the graph with the
    fine-tuned detector; failed episodes deleted, topped up on the next attempt), in bag order."""
    folder = cfg.path("demos", cfg.task.replace("/", "_"))
    for attempt in range(attempts):
        have = count_bags(folder)
        if have >= cfg.max_demos:
            break
        cmds.run(["vla_evaluation", "generate", "--catalogue", str(cfg.catalogue), "--task", cfg.task,
                  "--episodes", str(cfg.max_demos - have),
                  "--seed", str(NEW_DEMO_SEED + 1000 * attempt + have),
                  "--detector-model", str(detector), "--out", str(folder), "--real-time-factor", "0",
                  "--delete-failed"], accept=(0, 3))  # 3: some episodes failed (deleted)
    bags = sorted(p.parent for p in folder.glob("*/metadata.yaml"))
    if len(bags) < cfg.max_demos:
        raise RuntimeError(f"generation left {len(bags)} of {cfg.max_demos} bags of {cfg.task} in {folder}")
    return bags[: cfg.max_demos]


def base_demo_folders(cfg: NewObjectConfig, log: Callable[[str], None]) -> list[Path]:
    """The base tasks' demonstration folders under --data (generated once, as `make demo` does)."""
    return [ensure_demos(t, BASE_EPISODES, cfg.data, BASE_SEED, log) for t in BASE_TASKS]


def train_transfer(cfg: NewObjectConfig, k: int, base: Sequence[Path], new_bags: Sequence[Path],
                   detector: Path, cmds: Commands) -> Path:
    """The transfer model of k new demonstrations: base + the first k new bags in one model."""
    out = cfg.path("models", f"k{k}")
    if is_latent_model(out):
        cmds.log(f"[new-object] reusing {out}")
        return out
    cmds.run(["vla_latent_training", "train", "--catalogue", str(cfg.catalogue),
              "--bags", *map(str, base), *map(str, new_bags[:k]), "--max-per-task", str(BASE_EPISODES),
              "--detector-model", str(detector), "--epochs", str(cfg.latent_epochs),
              "--seed", str(cfg.latent_seed), "--out", str(out), "--quiet"])
    return out


def evaluate_transfer(cfg: NewObjectConfig, k: int, model: Path, detector: Path,
                      cmds: Commands) -> TransferFigures:
    """The graph evaluation of one transfer model on the fresh layouts (its results.json)."""
    out = cfg.path("eval", f"k{k}")
    if not (out / "results.json").is_file():
        cmds.run(["vla_evaluation", "evaluate", "--mode", "graph", "--catalogue", str(cfg.catalogue),
                  "--tasks", cfg.task, "--layouts", str(cfg.layouts), "--seed", str(cfg.layout_seed),
                  "--model", str(model), "--detector-model", str(detector),
                  "--real-time-factor", str(cfg.real_time_factor), "--out", str(out), *cfg.extra_eval_args])
    else:
        cmds.log(f"[new-object] reusing {out}")
    figures = summary_row(json.loads((out / "results.json").read_text()), cfg.task)
    figures.model = str(model)
    return figures


def summary_row(results: dict, task: str) -> TransferFigures:
    """The evaluation's summary of `task` (success rate, final state error, time to success, ...),
    with what its episodes say beyond it: how often the detector latched the task's object, and the
    safety layer's interventions by kind."""
    rows = [r for r in results.get("summary", []) if r.get("task") == task]
    if not rows:
        raise RuntimeError(f"the evaluation has no summary of {task}")
    row = rows[0]
    episodes = [e for e in results.get("episodes", []) if e.get("task") == task]
    obj = task.split("/", 1)[0]
    by_code: Counter = Counter()
    for e in episodes:
        for code, n in (e.get("x_interventions_by_code") or {}).items():
            by_code[code_name(code)] += int(n)
    return TransferFigures(
        task=task, episodes=int(row["episodes"]), success_rate=row.get("success_rate"),
        final_state_error=row.get("final_state_error"),
        final_state_error_sem=row.get("final_state_error_sem"),
        time_to_success_median=row.get("time_to_success_median"),
        safety_interventions=row.get("safety_interventions"), limit_violations=row.get("limit_violations"),
        detected_task_object=sum(e.get("detected_class") == obj for e in episodes),
        interventions_by_code=dict(by_code))


def demo_counts(cfg: NewObjectConfig, success: dict[int, float | None]) -> list[int]:
    """The demonstration counts still to measure after `success` (k -> success rate)."""
    want = [cfg.demos]
    first = success.get(cfg.demos)
    if cfg.sweep == "always" or (cfg.sweep == "auto" and first is not None and first < cfg.goal):
        want += list(range(1, cfg.max_demos + 1))
    return [k for k in dict.fromkeys(want) if k not in success]


def smallest_sufficient(success: dict[int, float | None], goal: float) -> int | None:
    """The smallest demonstration count whose success rate reaches `goal` (None: none does)."""
    ok = [k for k, s in success.items() if s is not None and s >= goal]
    return min(ok) if ok else None


# --------------------------------------------------------------------------------------------- report
def machine() -> Machine:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return Machine(cpu=cpu, cores=os.cpu_count(), load_average_at_start=list(os.getloadavg()),
                   python=platform.python_version())


def verdicts(res: NewObjectResults, cfg: NewObjectConfig) -> dict[str, bool | None]:
    """Each goal of the issue, met or not (None: not measured)."""
    ft = res.detector.get("fine_tuned")
    timing = res.detector_timing.get("fine_tuned")
    fine_s = timing.median_s if timing is not None else (ft.train_wall_s if ft is not None else None)
    transfer = res.transfer.get(str(cfg.demos))
    rate = transfer.success_rate if transfer is not None else None

    def at_least(v, goal):
        return None if v is None else bool(v >= goal)

    return {
        "new_class_ap50>=0.9": at_least(ft and ft.new_class_ap50, DETECTOR_AP_GOAL),
        "old_classes_map50>=0.95": at_least(ft and ft.old_classes_map50, DETECTOR_OLD_MAP_GOAL),
        "fine_tune_median<=300s": None if fine_s is None else bool(fine_s <= FINE_TUNE_TIME_GOAL_S),
        f"success_with_{cfg.demos}_demos>=80%": at_least(rate, cfg.goal),
    }


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def _num(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def report_markdown(res: NewObjectResults) -> str:
    """README.md of a run: the figures as tables."""
    cfg, m = res.config, res.machine
    lines = [f"# New object: {cfg['task']}", "",
             f"`{res.command}`", "",
             f"{res.date}, {m.cpu}, {m.cores} cores "
             f"(load {m.load_average_at_start[0]:.1f} at start); "
             f"{sum(res.steps_s.values()) / 60:.1f} min in all (the steps' sum; this run "
             f"{res.wall_s / 60:.1f} min).", "", "## Detector (held-out renders)", "",
             "| detector | train time | AP@0.5 new class | mAP@0.5 old classes | mAP@0.5 all "
             "| AP@0.5 per class |",
             "|---|---|---|---|---|---|"]
    for name, d in res.detector.items():
        per = ", ".join(f"{c} {v:.3f}" for c, v in d.ap50.items())
        t = f"{d.train_wall_s:.0f} s" + ("" if d.train_cpu_s is None else f" ({d.train_cpu_s:.0f} s CPU)")
        lines.append(f"| {name} | {t} | {_num(d.new_class_ap50)} | {_num(d.old_classes_map50)} | "
                     f"{_num(d.map50)} | {per} |")
    if res.detector_timing:
        lines += ["", "Training time of the same renders and epochs (runs alternate; CPU = user + system of "
                      "the command, steadier than wall time on the shared machine):", "",
                  "| detector | wall, runs (s) | wall, median (s) | CPU, runs (s) | CPU, median (s) |",
                  "|---|---|---|---|---|"]
        lines += [f"| {k} | {', '.join(f'{v:.0f}' for v in t.runs_s)} | {t.median_s:.0f} | "
                  f"{', '.join(f'{v:.0f}' for v in t.cpu_runs_s)} | {_num(t.median_cpu_s, '.0f')} |"
                  for k, t in res.detector_timing.items()]
    ratios = [("wall", res.detector_time_ratio), ("CPU", res.detector_cpu_time_ratio)]
    shown = [f"{w} {r:.2f}" for w, r in ratios if r]
    if shown:
        lines += ["", f"Median time ratio, from scratch / fine-tuned: {', '.join(shown)}."]
    lines += ["", "## Transfer model, graph evaluation on fresh layouts", "",
              "| new demos | episodes | success | final state error (rad) | median time to success | "
              "detected as the object | safety interventions (by kind) | limit violations |",
              "|---|---|---|---|---|---|---|---|"]
    for k, r in sorted(res.transfer.items(), key=lambda kv: int(kv[0])):
        tts = "-" if r.time_to_success_median is None else f"{r.time_to_success_median:.1f} s"
        kinds = ", ".join(f"{n} {c}" for c, n in r.interventions_by_code.items())
        safety = "-" if r.safety_interventions is None else r.safety_interventions
        lines.append(f"| {k} | {r.episodes} | {_pct(r.success_rate)} | "
                     f"{_num(r.final_state_error)} +- {_num(r.final_state_error_sem)} | {tts} | "
                     f"{r.detected_task_object}/{r.episodes} | {safety}{f' ({kinds})' if kinds else ''} | "
                     f"{'-' if r.limit_violations is None else r.limit_violations} |")
    k = res.smallest_sufficient_demos
    lines += ["", f"Smallest number of new demonstrations reaching {_pct(cfg['goal'])}: "
                  f"{'none of the counts measured' if k is None else k}.", "", "## Goals", ""]
    lines += [f"- {g}: {'-' if v is None else ('met' if v else 'NOT met')}" for g, v in res.verdicts.items()]
    lines += ["", "## Steps (wall time)", ""]
    reused = set(res.steps_reused)
    lines += [f"- {s}: {w:.0f} s{' (an earlier run)' if s in reused else ''}" for s, w in res.steps_s.items()]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------- run
def run_pipeline(cfg: NewObjectConfig, log: Callable[[str], None] = print,
                 command: str = "") -> NewObjectResults:
    """All the steps; returns (and writes to cfg.out) the figures."""
    t_all = time.monotonic()
    catalogue = load_catalogue(cfg.catalogue)
    spec = catalogue.task(cfg.task)  # CatalogueError: names the known tasks and files
    cfg.task = spec.name
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    res = NewObjectResults(command=command, date=time.strftime("%Y-%m-%d %H:%M %Z"), machine=machine(),
                           config={k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
                           catalogue=catalogue.where, shipped_detector=str(detector_model_path()))
    cmds = Commands(log)
    step = _StepClock(res, _previous_steps(cfg), cmds, cfg.out)

    renders, test_renders = render(cfg, cmds)
    step("renders")
    old_classes = [c for c in catalogue.classes if c != spec.object_class]
    first: dict[str, Timing] = {}
    models: dict[str, Path] = {}
    for key, (folder, extra) in detector_variants(cfg).items():
        models[key], first[key] = train_detector(cfg, renders, folder, extra, cmds)
        res.detector[key] = detector_figures(models[key], test_renders, spec.object_class, old_classes,
                                             first[key], cmds)
        step(f"detector {key} + evaluation")
    res.detector_timing = timing = median_timing(cfg, renders, first, cmds)
    if "scratch" in timing:
        scratch, fine_tuned = timing["scratch"], timing["fine_tuned"]
        res.detector_time_ratio = scratch.median_s / fine_tuned.median_s
        if scratch.median_cpu_s and fine_tuned.median_cpu_s:
            res.detector_cpu_time_ratio = scratch.median_cpu_s / fine_tuned.median_cpu_s
    step("detector timing repeats")
    fine = models["fine_tuned"]
    new_bags = new_task_demos(cfg, fine, cmds)
    res.new_demos = [str(b) for b in new_bags]
    step("new-task demonstrations")
    base = base_demo_folders(cfg, log)
    res.base_demos = {str(f): count_bags(f) for f in base}
    step("base demonstrations")
    success: dict[int, float | None] = {}
    while todo := demo_counts(cfg, success):
        k = todo[0]
        model = train_transfer(cfg, k, base, new_bags, fine, cmds)
        res.transfer[str(k)] = row = evaluate_transfer(cfg, k, model, fine, cmds)
        success[k] = row.success_rate
        step(f"transfer model k={k}: training + graph evaluation")
    res.smallest_sufficient_demos = smallest_sufficient(success, cfg.goal)
    res.wall_s = round(time.monotonic() - t_all, 1)
    res.verdicts = verdicts(res, cfg)
    res.save(cfg.out)
    (Path(cfg.out) / "README.md").write_text(report_markdown(res))
    return res


class _StepClock:
    """Records each step's wall time, saving the results after each; a step that ran no command keeps
    the time of the earlier run that did it."""

    def __init__(self, res: NewObjectResults, before: dict[str, float], cmds: Commands, out: Path) -> None:
        self.res, self.before, self.cmds, self.out = res, before, cmds, out
        self.t0, self.count = time.monotonic(), cmds.count

    def __call__(self, name: str) -> None:
        if self.cmds.count == self.count and name in self.before:
            self.res.steps_s[name] = self.before[name]
            self.res.steps_reused.append(name)
        else:
            self.res.steps_s[name] = round(time.monotonic() - self.t0, 1)
        self.t0, self.count = time.monotonic(), self.cmds.count
        self.res.save(self.out)


def _previous_steps(cfg: NewObjectConfig) -> dict[str, float]:
    """The step times of an earlier run into the same folder (empty when there is none)."""
    try:
        return dict(json.loads((Path(cfg.out) / "results.json").read_text()).get("steps_s", {}))
    except (OSError, ValueError):
        return {}


def publish(out: Path, target: Path) -> list[Path]:
    """Copy a run's figures (README.md, results.json, the evaluations' summaries and path plots) to
    `target`."""
    target.mkdir(parents=True, exist_ok=True)
    copied = []
    for name in ("README.md", "results.json"):
        copied.append(Path(shutil.copy2(out / name, target / name)))
    for f in sorted((out / "eval").glob("k*/summary.csv")) + sorted((out / "eval").glob("k*/paths_*.png")):
        copied.append(Path(shutil.copy2(f, target / f"eval_{f.parent.name}_{f.name}")))
    return copied


# ------------------------------------------------------------------------------------------- command
# The run's defaults, declared once in NewObjectConfig.
_DEFAULT = {f.name: f.default for f in fields(NewObjectConfig) if f.default is not MISSING}


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = _DEFAULT
    p.add_argument("--catalogue", type=Path, required=True,
                   help="the lab's catalogue YAML (extends: default)")
    p.add_argument("--task", required=True, help="the new object's task, e.g. spam/push_south_east")
    p.add_argument("--out", type=Path, required=True, help="output folder (reused: a rerun resumes)")
    p.add_argument("--data", type=Path, default=d["data"],
                   help="where the base demonstrations are cached (the folder `make demo` uses)")
    p.add_argument("--renders", type=int, default=d["renders"], help="training renders with the new object")
    p.add_argument("--test-renders", type=int, default=d["test_renders"],
                   help="held-out renders to measure on")
    p.add_argument("--detector-epochs", type=int, default=d["detector_epochs"],
                   help="epochs of both detectors (fine-tuned and from scratch)")
    p.add_argument("--no-scratch", action="store_true", help="skip the from-scratch detector comparison")
    p.add_argument("--mix-synth", type=int, default=d["mix_synth"],
                   help="also fine-tune with N renders of the whole scene mixed in (0: skip)")
    p.add_argument("--timing-repeats", type=int, default=d["timing_repeats"],
                   help="extra trainings of the fine-tuned and from-scratch detectors for median times")
    p.add_argument("--demos", type=int, default=d["demos"], help="new demonstrations in the transfer model")
    p.add_argument("--max-demos", type=int, default=d["max_demos"],
                   help="demonstrations generated (the sweep's top)")
    p.add_argument("--sweep", choices=("auto", "always", "never"), default=d["sweep"],
                   help="measure 1..--max-demos demonstrations: when --demos falls short (auto), "
                        "always, never")
    p.add_argument("--latent-epochs", type=int, default=d["latent_epochs"])
    p.add_argument("--latent-seed", type=int, default=d["latent_seed"])
    p.add_argument("--layouts", type=int, default=d["layouts"], help="fresh layouts of the graph evaluation")
    p.add_argument("--layout-seed", type=int, default=d["layout_seed"])
    p.add_argument("--real-time-factor", type=float, default=d["real_time_factor"],
                   help="of the graph evaluation")
    p.add_argument("--publish", type=Path, default=None,
                   help="also copy the figures here (e.g. docs/results/new-object)")


def run(args: argparse.Namespace) -> int:
    cfg = NewObjectConfig(catalogue=args.catalogue, task=args.task, out=args.out, data=args.data,
                          renders=args.renders, test_renders=args.test_renders,
                          detector_epochs=args.detector_epochs, scratch=not args.no_scratch,
                          mix_synth=args.mix_synth, timing_repeats=args.timing_repeats, demos=args.demos,
                          max_demos=max(args.max_demos, args.demos), sweep=args.sweep,
                          latent_epochs=args.latent_epochs, latent_seed=args.latent_seed,
                          layouts=args.layouts,
                          layout_seed=args.layout_seed, real_time_factor=args.real_time_factor)
    command = "vla_evaluation new-object " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else ""
    try:
        res = run_pipeline(cfg, log=_log, command=command)
    except (CatalogueError, RuntimeError) as err:
        print(f"new-object: {err}", file=sys.stderr)
        return 1 if isinstance(err, RuntimeError) else 2
    print(report_markdown(res))
    if args.publish is not None:
        for p in publish(Path(args.out), Path(args.publish)):
            print(f"wrote {p}")
    return 0


def _log(msg: str) -> None:
    print(msg, flush=True)

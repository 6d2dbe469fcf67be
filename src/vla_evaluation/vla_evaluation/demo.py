"""`make demo` / `vla_evaluation demo`: the project's main job.

Launches the graph users launch, `vla_evaluation demo.launch.yaml` (bridge with MuJoCo physics and
camera, detector, latent-action controller, simulated teleoperator), with the models shipped in the
repository, runs the simulated user over the base tasks, the unseen-object (cereal box) tasks and a
pick-and-place with the hand (the glass bottle 15 cm west) on fresh layouts, prints a table (task,
success, final state error, time), saves it as results.json in --out, and writes a video and an image
strip of the camera view with the end-effector path drawn.

One more row shows the assistance (issue 34, `--assisted`): a person who only holds the stick forward,
with the controller's assistance at high, on a task the paper's controller alone does not finish so.

Models: base tasks use the shipped `default` model (detector encoder, 30 demos per base object);
each cereal-box task uses its few-shot transfer model (base demos + 5 new ones), as in the paper's
Figure 2c; the pick-and-place its own model from 5 generated demonstrations. A missing model is
trained first (demonstrations generated through the graph, progress shown).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from io import StringIO
from pathlib import Path

import cv2
from vla_common.tasks import BASE_TASKS

from vla_evaluation import page_recording
from vla_evaluation.demo_video import write_video_and_strip
from vla_evaluation.evaluate_cli import add_teleop_arguments, print_table, settings_from, task_list
from vla_evaluation.graph import CAMERA_SIZE, CONTROLLER, GraphConfig, GraphError, GraphEvaluator
from vla_evaluation.metrics import summarize, write_json
from vla_evaluation.resources import SOURCE_MODELS, detector_model_path, is_latent_model, latent_model_dir
from vla_evaluation.training_data import ensure_detector, ensure_latent_models

BASE_MODEL = "default"  # the controller node's default model (detector encoder, base tasks)
# The demo's simulated user looks 2 s ahead (the evaluations' default is 1 s). With 1 s the glass bottle
# on the demo's layout was pushed 26-29 deg off its direction (the limit is 30: the closed loop's timing
# decided it); with 2 s, 2-9 deg, and over 28 physics-mode episodes of the seven tasks (seeds
# 200000-200003) 23 succeeded against 22 with 1 s.
DEMO_HORIZON = 2.0
# The main job's tasks: the paper's base pushes and the cereal box's few-shot tasks ("all"), and a
# pick-and-place with the hand (issue 23: 5 generated demonstrations, the operator's grasp button,
# fine alignment in end-effector mode where the latent stops short).
DEMO_TASKS = "all,glass_bottle/pick_place_west"
# The assistance's row (issue 34): the person holds the stick at full for ASSISTED_HOLD_S from the ready
# pose, the controller's assistance at ASSISTED_LEVEL. Far (the circle): held alone, the learned circle
# stalls after about 140 degrees (0 of 8 in the issue; ASSISTED_TASK's figures in docs/history.md).
ASSISTED_TASK = "cereal_box/circle"
ASSISTED_LEVEL = "high"
ASSISTED_HOLD_S = 20.0


def model_name_for(task: str) -> str:
    """Shipped model directory name used for a task."""
    return BASE_MODEL if task in BASE_TASKS else task.replace("/", "_")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--tasks", default=DEMO_TASKS,
                   help=f"base, unseen, all, or comma-separated task names (default: {DEMO_TASKS})")
    p.add_argument("--layouts", type=int, default=1, help="fresh layouts per task")
    p.add_argument("--seed", type=int, default=200_000, help="first layout seed (unseen in training)")
    p.add_argument("--real-time-factor", type=float, default=None,
                   help="simulated seconds per wall second at most (default: as fast as the CPU allows; "
                        "1 with --record-page, so that the page plays at real time); the graph runs in "
                        "lockstep, so the results are the same")
    p.add_argument("--free-running", action="store_true",
                   help="no lockstep: the simulation paced by the wall clock (2.5 x real time unless set), "
                        "as before issue 33; outcomes then depend on the machine's load")
    p.add_argument("--stop-on-success", action="store_true", help="end an episode 1 s after success")
    p.add_argument(
        "--models",
        type=Path,
        default=None,
        help="folder of latent models (default/, cereal_box_*/); default: the shipped ones",
    )
    p.add_argument("--detector-model", type=Path, default=None, help="detector ONNX (default: shipped)")
    p.add_argument(
        "--data",
        type=Path,
        default=Path("out/data"),
        help="where demonstrations are generated when a model must be trained",
    )
    p.add_argument("--assisted", default=ASSISTED_TASK, metavar="TASK",
                   help=f"one more episode of TASK: the stick held at full for {ASSISTED_HOLD_S:g} s with "
                        f"the controller's assistance {ASSISTED_LEVEL} (default: %(default)s; '' for none)")
    p.add_argument("--no-video", action="store_true", help="skip the video and image strip")
    p.add_argument("--record-page", type=Path, default=None, metavar="MP4",
                   help="also start the operator station and record its page (headless Chromium) into MP4")
    p.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID for the graph (default: own)")
    add_teleop_arguments(p, rate=100.0, horizon=DEMO_HORIZON)


def run(args) -> int:
    t_all = time.monotonic()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = task_list(args.tasks)
    det = ensure_detector(args.detector_model or detector_model_path(), args.data, log=_log)
    assisted = task_list(args.assisted)[0] if args.assisted else ""
    names = sorted({model_name_for(t) for t in [*tasks, *([assisted] if assisted else [])]})
    if args.models is not None:
        model_dirs = {n: Path(args.models) / n for n in names}
    else:
        model_dirs = {n: latent_model_dir(n) for n in names}
    missing = [n for n, d in model_dirs.items() if not is_latent_model(d)]
    if missing:
        target = Path(args.models) if args.models is not None else SOURCE_MODELS
        _log(
            f"[demo] models missing ({', '.join(missing)}): generating demonstrations and training them "
            f"into {target}/"
        )
        made = ensure_latent_models(missing, target, det, args.data, log=_log)
        model_dirs.update(made)

    settings = settings_from(args)
    rtf = args.real_time_factor
    if rtf is None:
        rtf = 2.5 if args.free_running else (1.0 if args.record_page else 0.0)
    cfg = GraphConfig(
        model_path=str(model_dirs[model_name_for(tasks[0])]),
        detector_model=str(det),
        lockstep=not args.free_running,
        real_time_factor=rtf,
        rate=settings.rate,
        settings=settings,
        stop_on_success=args.stop_on_success,
        keep_frames=not args.no_video,
        domain_id=args.domain_id,
        log_dir=out / "logs",
        operator_port=page_recording.free_port() if args.record_page else None,
    )
    records = []
    try:
        page = page_recording.recording(args.record_page, cfg.operator_port, _log)
        with GraphEvaluator(cfg, log=_log) as ev, page:
            for task in tasks:
                name = model_name_for(task)
                ev.set_model(str(model_dirs[name]))
                for i in range(args.layouts):
                    rec = ev.run_episode(task, args.seed + i, label=name)
                    rec.result.encoder = _encoder_of(model_dirs[name])
                    _log_episode(rec.result)
                    if cfg.keep_frames:
                        rec.frames = _thin_frames(rec.frames)
                    records.append(rec)
            if assisted:
                records.append(_assisted_episode(ev, assisted, args.seed, model_dirs, cfg.keep_frames))
    except (GraphError, page_recording.RecordingError) as e:
        print(f"demo: {e}", file=sys.stderr)
        return 1
    results = [r.result for r in records]
    summary = summarize(results, ("task", "assistance"))
    for row in summary:
        if row["assistance"]:
            row["task"] = f"{row['task']} assisted"
    print()
    print_table(summary)
    files = {}
    if not args.no_video:
        files = write_video_and_strip(records, out, size=CAMERA_SIZE)
    base = [r for r in results if model_name_for(r.task) == BASE_MODEL]
    data = {
        "summary": summary,
        "episodes": [r.to_json(include_path=True) for r in results],
        "models": {n: str(d) for n, d in model_dirs.items()},
        "detector_model": str(det),
        "settings": vars(settings),
        "real_time_factor": rtf,
        "lockstep": cfg.lockstep,
        "base_success_rate": (sum(bool(r.success) for r in base) / len(base)) if base else None,
        "wall_s": round(time.monotonic() - t_all, 1),
        "files": {k: str(v) for k, v in files.items()},
    }
    write_json(data, out / "results.json")
    print(
        f"\nwrote {out}/results.json"
        + "".join(f", {Path(v).name}" for v in files.values())
        + f" in {data['wall_s']:.0f} s"
    )
    failed = [r.task for r in results if not r.success]
    if failed:      # the main job did not do its job: say so, and let make / CI see it
        print(f"demo: {len(failed)} of {len(results)} episodes failed: {', '.join(failed)}", file=sys.stderr)
        return 3
    return 0


def _assisted_episode(ev, task: str, seed: int, model_dirs: dict, keep_frames: bool):
    """The assistance's row: the stick held at full, the assistance at ASSISTED_LEVEL (run-time
    parameters of the controller and the teleoperator), on the first layout."""
    name = model_name_for(task)
    ev.set_model(str(model_dirs[name]))
    ev.config.settings = replace(ev.config.settings, hold=1.0, switch_time=0.0, time_limit=ASSISTED_HOLD_S)
    ev.config.extra_params = {CONTROLLER: {"assistance": ASSISTED_LEVEL}}
    ev.configure()
    rec = ev.run_episode(task, seed, label=f"{name}, assistance {ASSISTED_LEVEL}, stick held")
    rec.result.encoder = _encoder_of(model_dirs[name])
    rec.result.extra["assistance"] = ASSISTED_LEVEL
    _log(f"[demo] the stick held at full for {ASSISTED_HOLD_S:g} s, assistance {ASSISTED_LEVEL}:")
    _log_episode(rec.result)
    if keep_frames:
        rec.frames = _thin_frames(rec.frames)
    return rec


def _encoder_of(model_dir: Path) -> str:
    try:
        return str(json.loads((Path(model_dir) / "config.json").read_text())["encoder"])
    except (OSError, ValueError, KeyError):
        return ""


def _thin_frames(frames, period: float = 0.5, size: tuple[int, int] = (320, 240)):
    """Keep one frame every `period` s of sim time, downscaled (bounds memory over many episodes)."""
    kept, next_t = [], -1.0
    for t, f in frames:
        if t >= next_t:
            kept.append((t, cv2.resize(f, size, interpolation=cv2.INTER_AREA)))
            next_t = t + period
    return kept


def _log(text: str) -> None:
    print(text, flush=True)


def _log_episode(r) -> None:
    tts = f"{r.time_to_success:5.1f} s" if r.time_to_success is not None else "    - "
    print(
        f"[demo] {r.task:28s} {'success' if r.success else 'FAILED ':8s} final state error "
        f"{r.final_state_error:.3f} rad  time to success {tts}  safety interventions "
        f"{r.safety_interventions}  limit violations {r.limit_violations}",
        flush=True,
    )


def summary_lines(results) -> list[str]:
    """Plain-text table lines (used by tests)."""
    buf = StringIO()
    print_table(summarize(results, ("task",)), file=buf)
    return buf.getvalue().splitlines()

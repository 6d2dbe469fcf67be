"""Demonstrations and models for the demo and the experiments, made on demand with progress shown.

- detector: `vla_detector_training synth` + `vla_detector_training train` when the shipped ONNX is missing;
- demonstrations: `vla_evaluation generate` (through the ROS graph, exactly like recorded ones),
  cached per task under a data folder and reused when enough bags are there;
- latent models: `train_model` on the loaded bags (detector encoder), saved as safetensors + JSON.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from vla_common.catalogue import default_catalogue
from vla_common.tasks import BASE_TASKS, UNSEEN_TASKS
from vla_demo_recorder.dataset import load_demos
from vla_detector.inference import Detector

# Per base object for the shipped models: three times the paper's 10. On fresh layouts (kinematic,
# 10 per task) the mean final state error falls from 0.65 rad with 10 to 0.42 with 30 (0.41 with 60).
# The experiments (Figure 2a) sweep the paper's 1 ... 10 themselves.
BASE_EPISODES = 30
FEW_SHOT_EPISODES = 5  # per unseen task, the paper's largest k
BASE_SEED = 0
UNSEEN_SEED = 5_000
# Tasks with the hand (the demo's pick-and-place): a model of their own, from that task's
# FEW_SHOT_EPISODES demonstrations alone. With the base demos beside them the soda can's context
# would ask one latent for its push south and its pick-and-place at once.
HAND_TASKS: list[str] = [s.name for s in default_catalogue().task_set("hand")]


def run_command(
    cmd: Sequence[str], log: Callable[[str], None] = print, accept: Sequence[int] = (0,)
) -> int:
    """Run a project command, streaming its output (progress bars included); RuntimeError when its
    exit code is not in `accept`. Returns the exit code."""
    log("[run] " + " ".join(str(c) for c in cmd))
    proc = subprocess.run([str(c) for c in cmd], stdout=sys.stdout, stderr=sys.stderr)
    if proc.returncode not in accept:
        raise RuntimeError(
            f"{cmd[0]} {cmd[1] if len(cmd) > 1 else ''} failed with exit code {proc.returncode}"
        )
    return proc.returncode


def ensure_detector(path: Path, data_dir: Path, log: Callable[[str], None] = print) -> Path:
    """The detector ONNX at `path`, or one trained now on synthetic renders under data_dir."""
    path = Path(path)
    if path.is_file():
        return path
    trained = Path(data_dir) / "detector_model"
    found = sorted(trained.glob("*.onnx"))
    if found:
        return found[0]
    log(f"[data] no detector at {path}: rendering a synthetic dataset and training one (several minutes)")
    synth = Path(data_dir) / "detector_synth"
    if not (synth / "data.yaml").is_file():
        run_command(["vla_detector_training", "synth", "--count", "800", "--seed", "0", "--out", str(synth)],
                    log)
    run_command(["vla_detector_training", "train", "--data", str(synth), "--out", str(trained)], log)
    found = sorted(trained.glob("*.onnx"))
    if not found:
        raise RuntimeError(f"detector training wrote no .onnx into {trained}")
    return found[0]


def task_dir(data_dir: Path, task: str) -> Path:
    return Path(data_dir) / "demos" / task.replace("/", "_")


def count_bags(folder: Path) -> int:
    return sum(1 for p in Path(folder).glob("*/metadata.yaml")) if Path(folder).is_dir() else 0


def ensure_demos(
    task: str, episodes: int, data_dir: Path, seed: int, log: Callable[[str], None] = print, attempts: int = 3
) -> Path:
    """A folder with at least `episodes` successful demonstration bags of `task`, generated through
    the graph (`vla_evaluation generate`, failed episodes deleted) when short."""
    folder = task_dir(data_dir, task)
    for attempt in range(attempts):
        have = count_bags(folder)
        if have >= episodes:
            return folder
        log(f"[data] generating {episodes - have} demonstrations of {task} into {folder}")
        cmd = [
            "vla_evaluation",
            "generate",
            "--task",
            task,
            "--episodes",
            str(episodes - have),
            "--seed",
            str(seed + 1000 * attempt + have),
            "--out",
            str(folder),
            "--real-time-factor",
            "0",
            "--delete-failed",
        ]
        if task in HAND_TASKS:
            cmd.append("--spread")   # the object at the region's corners and centre in turn (see generate)
        # exit code 3: some episodes failed the task (deleted); the next attempt tops the folder up
        run_command(cmd, log, accept=(0, 3))
    if count_bags(folder) < episodes:
        raise RuntimeError(f"generation left {count_bags(folder)} of {episodes} bags of {task} in {folder}")
    return folder


def load_task_demos(folder: Path, task: str, detector=None, limit: int | None = None) -> list:
    """Demos of `task` from a folder of bags, each with a detection (the recorded one, else detected
    now on its first image); bags without one are reported and skipped."""
    demos, skipped = load_demos(folder)
    for path, reason in skipped:
        print(f"[data] skipped {path}: {reason}", file=sys.stderr)
    out = []
    for d in sorted(demos, key=lambda d: str(d.bag_path)):
        if d.task != task:
            continue
        if d.detection is None and d.first_image is not None and detector is not None:
            dets = [x for x in detector.detect(d.first_image) if x.class_id == d.object_class] or list(
                detector.detect(d.first_image)
            )
            if dets:
                best = max(dets, key=lambda x: x.score)
                d.detection = best
                d.image_size = (d.first_image.shape[1], d.first_image.shape[0])
        out.append(d)
    return out[:limit] if limit else out


# Training seed of each shipped model. `default` was picked from seeds 0-2 by physics-mode success on
# 20 selection layouts per task (layout seeds 120000...), kept apart from the layouts it is reported on.
SHIPPED_TRAINING_SEEDS: dict[str, int] = {"default": 1}


def ensure_latent_models(
    names: Sequence[str],
    target: Path,
    detector_path: Path,
    data_dir: Path,
    log: Callable[[str], None] = print,
    epochs: int = 1000,
) -> dict[str, Path]:
    """Train the named models (`default`: base tasks; `cereal_box_<action>`: base + few-shot; a task
    with the hand, e.g. `soda_can_pick_place_west`: its few-shot demos alone)."""
    from vla_latent_training.train import TrainConfig, train_model  # torch: optional, only to train

    detector = Detector(detector_path)
    hand = {t.replace("/", "_"): t for t in HAND_TASKS}
    base = []
    if any(name not in hand for name in names):
        for task in BASE_TASKS:
            folder = ensure_demos(task, BASE_EPISODES, data_dir, BASE_SEED, log)
            base += load_task_demos(folder, task, detector, BASE_EPISODES)
    made: dict[str, Path] = {}
    for name in names:
        if name == "default":
            demos = base
        elif name in hand:
            folder = ensure_demos(hand[name], FEW_SHOT_EPISODES, data_dir, UNSEEN_SEED, log)
            demos = load_task_demos(folder, hand[name], detector, FEW_SHOT_EPISODES)
        else:
            task = next((t for t in UNSEEN_TASKS if t.replace("/", "_") == name), None)
            if task is None:
                raise ValueError(f"no recipe for model {name!r}")
            folder = ensure_demos(task, FEW_SHOT_EPISODES, data_dir, UNSEEN_SEED, log)
            demos = base + load_task_demos(folder, task, detector, FEW_SHOT_EPISODES)
        log(f"[train] {name}: {len(demos)} demonstrations, detector encoder, {epochs} epochs")
        result = train_model(
            demos,
            TrainConfig(encoder="detector", epochs=epochs, seed=SHIPPED_TRAINING_SEEDS.get(name, 0)),
            detector=detector,
            progress=True,
            log=log,
        )
        made[name] = result.save(Path(target) / name)
        log(f"[train] saved {made[name]}")
    return made

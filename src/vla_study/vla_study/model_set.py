"""The study's matched models: every latent strategy trained on the same demonstrations, with the same
recipe, for several training seeds, and each model's path fraction chosen by one procedure on the
protocol's development layouts.

    python -m vla_study.model_set --protocol src/vla_study/vla_study/protocols/paper.yaml \
        --out src/vla_latent_controller/models --serial

For every training seed s, every latent strategy of the protocol (latent-YOLO: the detector encoder;
latent-localization: the localization-only encoder, the object's class from an oracle) and every
setting, one model `matched_<encoder>_<setting>_s<s>`:
- demonstrations (the paper's study, Section 7): 9 per base task, and for a few-shot setting those
  same base demonstrations plus 3 of its task (the transfer variant). They are made in-process from
  seeds (`experiments.simulate_demos`: PandaSim and the task planner, the first frame rendered and
  detected), per training seed: seed s draws its own demonstrations, as the paper's runs drew their
  own subsets. Both strategies' models of a seed and setting train on the very same Demo objects;
- the recipe (`Recipe`): the shipped training recipe (TrainConfig's defaults: 128 hidden units, the
  improvements on) with 100 epochs, the learning-rate step at 40 and at least 1000 optimiser updates
  (Figure 2's schedule, `experiments.Plan`: with batches of 6000 pairs about the paper's 1000
  full-batch updates), the same for every strategy, setting and seed;
- the improved training of issue 34, where asked (`--rest-samples`, `--corrective-copies`,
  `--corrective-sigma`, as `vla_latent_training train` takes them): the same demonstrations, epochs and
  seeds, the pairs taught where a task ends and the way back to its path; such a set is named
  `matched_<encoder>_<setting>_ends_s<s>` and ships beside the paper's;
- the path fraction (`vla_evaluation.path_fraction`): a held full stick in the kinematic loop on the
  development layouts of the protocol's `development` files (never a test layout), the fraction of
  {0.5, 0.65, 0.8, 1} whose path comes closest to the planner's waypoints.
Each model directory has `provenance.json` (recipe, demonstrations and their seeds, the path
fraction's measurements, CPU time); a model already there with the same recipe is kept, another is
refused. Every model is a unit of a sweep (`vla_evaluation.sweep`: a local Ray, a cluster with
--ray-address, or --serial here); only this process writes. The protocol names the models per
strategy and setting as a list, one per seed (protocol.model_for: participant i drives seed i mod 3).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

from vla_common.tasks import BASE_TASKS
from vla_evaluation.resources import SOURCE_MODELS, detector_model_path
from vla_evaluation.sweep import Needs, engine_from, run_sweep
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_latent_training.config import TrainConfig  # no torch

from vla_study.layouts import development_layouts, render_layouts
from vla_study.protocol import PAPER, STRATEGIES, Protocol, ProtocolError, load_protocol
from vla_study.protocol_schema import base_strategy

# The encoder each latent strategy's models are trained with (vla_latent_training's --encoder).
ENCODERS = {"latent-YOLO": "detector", "latent-localization": "localization"}
PREFIX = "matched"
PROVENANCE = "provenance.json"
BASE_DEMO_SEED = 1_000  # seed s, base task i: simulate_demos seed 1000 (s + 1) + i
FEWSHOT_DEMO_SEED = 50_000  # seed s, few-shot task j: 50000 + 1000 s + j (apart from the base ones)


# Recipe fields added after the first models were made: left out of the digest at TrainConfig's defaults
_ADDED = ("rest_samples", "corrective_copies", "corrective_sigma")


@dataclass(frozen=True)
class Recipe:
    """How every model of the set is made; one recipe for every strategy, setting and seed."""

    base_demos: int = 9  # per base task (the paper's study: 9 per base object)
    fewshot_demos: int = 3  # per few-shot task (the paper's study: 3)
    epochs: int = 100
    step_size: int = 40  # the learning-rate step, in epochs (0.4 of them, as the paper's 400 of 1000)
    min_steps: int = 1000  # at least this many optimiser updates (TrainConfig.min_steps)
    seeds: tuple[int, ...] = (0, 1, 2)
    # The improved training (issue 34; TrainConfig's, off by default: the paper's pairs)
    rest_samples: int = TrainConfig.rest_samples
    corrective_copies: int = TrainConfig.corrective_copies
    corrective_sigma: float = TrainConfig.corrective_sigma

    @property
    def variant(self) -> str:
        """'ends' where the pairs are taught where a task ends (the improved training), else ''."""
        return "ends" if self.rest_samples or self.corrective_copies else ""

    def train_config(self, encoder: str, seed: int):
        """The TrainConfig of a model of the set: the shipped recipe with this schedule."""
        return TrainConfig(encoder=encoder, epochs=self.epochs, step_size=self.step_size,
                           min_steps=self.min_steps, seed=seed, rest_samples=self.rest_samples,
                           corrective_copies=self.corrective_copies, corrective_sigma=self.corrective_sigma)

    def digest(self) -> str:
        """What a model depends on besides its strategy, setting and seed (seeds excluded: a set with
        more seeds keeps the models it has; the improved training's fields only where set, so that the
        models made before them keep their digest)."""
        d = {k: v for k, v in asdict(self).items()
             if k != "seeds" and not (k in _ADDED and v == getattr(TrainConfig, k))}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Unit:
    """One model of the set."""

    strategy: str
    setting: str
    tasks: tuple[str, ...]  # the base tasks, then the setting's own (few-shot) tasks
    seed: int
    variant: str = ""  # Recipe.variant

    @property
    def encoder(self) -> str:
        return ENCODERS[self.strategy]

    @property
    def name(self) -> str:
        return model_name(self.strategy, self.setting, self.seed, self.variant)


def model_name(strategy: str, setting: str, seed: int, variant: str = "") -> str:
    """`matched_<encoder>_<setting>[_<variant>]_s<seed>`, e.g. matched_localization_far_s2 or
    matched_detector_seen_ends_s0."""
    return f"{PREFIX}_{ENCODERS[strategy]}_{setting.lower()}{'_' + variant if variant else ''}_s{seed}"


def protocol_models(strategies, settings, seeds, variant: str = "") -> dict[str, dict[str, list[str]]]:
    """The protocol's `models` block for the set: per strategy and setting, one model per seed."""
    return {s: {k: [model_name(s, k, seed, variant) for seed in seeds] for k in settings} for s in strategies}


def fewshot_tasks(protocol: Protocol, setting: str) -> tuple[str, ...]:
    """A setting's tasks that are not base tasks (none for the base setting)."""
    return tuple(t for t in protocol.settings[setting] if t not in BASE_TASKS)


def units_of(protocol: Protocol, recipe: Recipe) -> list[Unit]:
    """Every model of the set, seed by seed (a stopped build has whole seeds first)."""
    latent = list(dict.fromkeys(base_strategy(s) for s in protocol.strategies if STRATEGIES[s] == "latent"))
    return [Unit(s, k, tuple(BASE_TASKS) + fewshot_tasks(protocol, k), seed, recipe.variant)
            for seed in recipe.seeds for k in protocol.settings for s in latent]


def demo_seed(task: str, seed: int) -> int:
    """The seed `simulate_demos` draws a task's demonstrations of training seed `seed` from (a task's
    own, whichever other models are made)."""
    if task in BASE_TASKS:
        return BASE_DEMO_SEED * (seed + 1) + BASE_TASKS.index(task)
    return FEWSHOT_DEMO_SEED + 1000 * seed + zlib.crc32(task.encode()) % 1000


def make_demos(units: list[Unit], recipe: Recipe, detector, log=print) -> dict[tuple[int, str], list]:
    """{(seed, task): demonstrations} for every unit, each made once."""
    from vla_evaluation.experiments import simulate_demos  # MuJoCo: only when demos are made

    need = {(u.seed, t) for u in units for t in u.tasks}
    out: dict[tuple[int, str], list] = {}
    for seed, task in sorted(need):
        n = recipe.base_demos if task in BASE_TASKS else recipe.fewshot_demos
        out[(seed, task)] = simulate_demos(task, n, demo_seed(task, seed), detector)
        log(f"[model_set] seed {seed}: {n} demonstrations of {task}")
    return out


class TrainWorker:
    """A sweep worker: holds the demonstrations (sent once) and trains one model per unit."""

    def __init__(self, state: dict) -> None:
        self.state = state

    def run(self, unit: Unit) -> dict:
        return train_unit(unit, self.state["demos"], self.state["recipe"])

    def close(self) -> None:
        pass


def train_unit(unit: Unit, demos: dict, recipe: Recipe) -> dict:
    """Train one model (on a GPU where the worker has one): its config, tensors, CNN and CPU time."""
    import torch  # only where a model trains
    from vla_latent_training.train import train_model

    torch.set_num_threads(1)
    train_demos = [d for t in unit.tasks for d in demos[(unit.seed, t)]]
    cpu0 = time.process_time()
    res = train_model(train_demos, recipe.train_config(unit.encoder, unit.seed), progress=False, threads=1,
                      log=lambda s: None, device="cuda" if torch.cuda.is_available() else None)
    cnn = Path(res.cnn_onnx).read_bytes() if res.cnn_onnx else None
    return {"config": res.config, "tensors": res.tensors, "cnn": cnn, "summary": res.summary,
            "train_cpu_s": round(time.process_time() - cpu0, 1), "device": str(
                "cuda" if torch.cuda.is_available() else "cpu"), "torch": torch.__version__}


def save_unit(out: Path, unit: Unit, result: dict, recipe: Recipe, demo_seeds: dict[str, int],
              source: str) -> Path:
    """The trained model and its provenance (path fraction still to choose)."""
    from vla_latent_controller.artifacts import save_model

    with tempfile.TemporaryDirectory(prefix="vla_model_set_") as tmp:
        cnn = None
        if result["cnn"] is not None:
            cnn = Path(tmp) / "context_cnn.onnx"
            cnn.write_bytes(result["cnn"])
        path = save_model(out / unit.name, result["config"], result["tensors"], cnn)
    per_task = result["config"]["training"]["demos_per_task"]
    provenance = {
        "made_by": "python -m vla_study.model_set", "protocol": source, "strategy": unit.strategy,
        "encoder": unit.encoder, "setting": unit.setting, "tasks": list(unit.tasks),
        "training_seed": unit.seed,
        "demos_per_task": per_task, "demo_seeds": {t: demo_seeds[t] for t in unit.tasks},
        "demo_source": "in-process PandaSim and the task planner (vla_evaluation.experiments.simulate_demos)",
        "recipe": {**asdict(recipe), "seeds": list(recipe.seeds)}, "recipe_digest": recipe.digest(),
        "train_cpu_s": result["train_cpu_s"], "device": result["device"], "torch": result["torch"],
        "commit": _commit(), "path_fraction": None,
    }
    (path / PROVENANCE).write_text(json.dumps(provenance, indent=1) + "\n")
    return path


def read_provenance(path: Path) -> dict | None:
    p = Path(path) / PROVENANCE
    try:
        return json.loads(p.read_text()) if p.is_file() else None
    except (OSError, ValueError):
        return None


def state_of(out: Path, unit: Unit, recipe: Recipe) -> str:
    """'missing', 'trained' (path fraction to choose), 'done', or why the directory is refused."""
    d = Path(out) / unit.name
    if not d.exists():
        return "missing"
    prov = read_provenance(d)
    if prov is None or prov.get("recipe_digest") != recipe.digest():
        return f"{d} holds another model (no provenance of this recipe): remove it or choose another --out"
    return "done" if prov.get("path_fraction") else "trained"


def choose_fractions(out: Path, units: list[Unit], protocol: Protocol, log=print) -> None:
    """Each trained model's path fraction, chosen on the development layouts of its setting."""
    from vla_evaluation.kinematic import TeleopSettings
    from vla_evaluation.path_fraction import FRACTIONS, choose_path_fraction, set_path_fraction
    from vla_latent_controller.model import LatentModel

    settings = TeleopSettings(rate=protocol.rate, time_limit=protocol.time_limit)
    layouts: dict[str, list] = {}
    for u in units:
        if u.setting not in layouts:
            dev = development_layouts(protocol, u.setting)
            layouts[u.setting] = render_layouts(dev)
            log(f"[model_set] {u.setting}: {len(dev)} development layouts")
        path = Path(out) / u.name
        choice = choose_path_fraction(LatentModel.load(path), layouts[u.setting], settings, FRACTIONS)
        set_path_fraction(path, choice.fraction, choice.describe())
        prov = read_provenance(path)
        prov["path_fraction"] = choice.to_dict()
        (path / PROVENANCE).write_text(json.dumps(prov, indent=1) + "\n")
        log(f"[model_set] {u.name}: path fraction {choice.fraction} ({choice.describe()})")


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", type=Path, default=PAPER,
                    help="its latent strategies, settings and development files (default: paper.yaml)")
    ap.add_argument("--out", type=Path, default=SOURCE_MODELS, help="where the model directories go")
    ap.add_argument("--seeds", default="0,1,2", help="training seeds, comma-separated")
    ap.add_argument("--only", default=None, help="comma-separated model names to make (default: all)")
    ap.add_argument("--epochs", type=int, default=Recipe.epochs,
                    help="training epochs (the lr step at 0.4 of them); every model the same")
    ap.add_argument("--min-steps", type=int, default=Recipe.min_steps)
    ap.add_argument("--rest-samples", type=int, default=Recipe.rest_samples,
                    help="the improved training: each demonstration held at its end this many samples more")
    ap.add_argument("--corrective-copies", type=int, default=Recipe.corrective_copies,
                    help="the improved training: copies of every pair from a perturbed state (DART-like)")
    ap.add_argument("--corrective-sigma", type=float, default=Recipe.corrective_sigma,
                    help="rad per joint of those perturbations")
    add_engine_arguments(ap)
    a = ap.parse_args(argv)
    try:
        protocol = load_protocol(a.protocol)
    except ProtocolError as e:
        print(f"protocol refused:\n{e}", file=sys.stderr)
        return 2
    recipe = Recipe(epochs=a.epochs, step_size=max(1, round(0.4 * a.epochs)), min_steps=a.min_steps,
                    seeds=tuple(int(s) for s in a.seeds.split(",") if s.strip()), rest_samples=a.rest_samples,
                    corrective_copies=a.corrective_copies, corrective_sigma=a.corrective_sigma)
    try:
        recipe.train_config("detector", 0).validate()
    except ValueError as e:
        print(f"recipe refused: {e}", file=sys.stderr)
        return 2
    units = units_of(protocol, recipe)
    if a.only:
        names = {n.strip() for n in a.only.split(",")}
        units = [u for u in units if u.name in names]
    states = {u.name: state_of(a.out, u, recipe) for u in units}
    refused = [s for s in states.values() if s not in ("missing", "trained", "done")]
    if refused:
        print("\n".join(refused), file=sys.stderr)
        return 2
    todo = [u for u in units if states[u.name] == "missing"]
    print(f"[model_set] {len(units)} models, {len(todo)} to train, "
          f"{sum(s != 'done' for s in states.values())} to choose a path fraction for", flush=True)
    if todo:
        failed = _train(a, protocol, recipe, todo)
        if failed:
            print(f"[model_set] failed: {', '.join(failed)}; run the same command again", file=sys.stderr)
            return 1
    pending = [u for u in units if state_of(a.out, u, recipe) == "trained"]
    if pending:
        choose_fractions(a.out, pending, protocol, log=lambda s: print(s, flush=True))
    return 0


def _train(a, protocol: Protocol, recipe: Recipe, todo: list[Unit]) -> list[str]:
    from vla_detector.inference import Detector

    detector = Detector(detector_model_path())
    demos = make_demos(todo, recipe, detector, log=lambda s: print(s, flush=True))
    source = _shown(a.protocol)

    def on_result(key: str, result: dict) -> None:
        unit = next(u for u in todo if u.name == key)
        seeds = {t: demo_seed(t, unit.seed) for t in unit.tasks}
        path = save_unit(a.out, unit, result, recipe, seeds, source)
        print(f"[model_set] {key}: {result['summary'][0]} ({result['train_cpu_s']} s CPU) -> {path}",
              flush=True)

    return run_sweep([(u.name, u) for u in todo], TrainWorker, engine=engine_from(a), on_result=on_result,
                     shared={"demos": demos, "recipe": recipe}, needs=Needs(cpus=1.0, gpu=0.25),
                     name="model_set", log=lambda s: print(s, flush=True))


def _shown(path: Path) -> str:
    """The protocol's path as the repository names it (relative where it can be)."""
    try:
        return str(Path(path).resolve().relative_to(Path(__file__).resolve().parents[3]))
    except ValueError:
        return str(path)


if __name__ == "__main__":
    sys.exit(main())

"""Which layouts a protocol tests on, and which are for development: the study's layouts as sets.

A layout is a task and its layout seed (the scene `make_layouts` and the simulated Panda's ~/reset
build from them). The test layouts are those of a protocol's test trials; the development layouts
are those of the test trials of the development files it names (protocol `development`), which the
runner refuses a test protocol to reuse (runner.reused_seeds). Whatever is tuned for the study (a
model's path fraction) is tuned on development layouts only: `development_layouts` never returns a
test layout of the protocol, and says so with an error if its files would.
"""
from __future__ import annotations

from vla_study.protocol import Protocol, load_protocol
from vla_study.runner import trial_plan

Layout = tuple[str, int]  # (task, layout seed)


def trial_layouts(protocol: Protocol, setting: str | None = None) -> list[Layout]:
    """The protocol's test trials' layouts (of one setting, or all), each once, in trial order."""
    out = [(t.task, t.layout_seed) for t in trial_plan(protocol)
           if t.phase == "test" and (setting is None or t.setting == setting)]
    return list(dict.fromkeys(out))


def development_layouts(protocol: Protocol, setting: str) -> list[Layout]:
    """The layouts of the test trials, in the protocol's development files, of the tasks `setting` has
    in this protocol (a development file's settings may name other tasks), each once, sorted.
    ValueError if one of them is a test layout of the protocol (the runner refuses such a protocol)."""
    tasks = set(protocol.settings[setting])
    out: set[Layout] = set()
    for path in protocol.development:
        dev = load_protocol(path)
        out |= {(t.task, t.layout_seed) for t in trial_plan(dev) if t.phase == "test" and t.task in tasks}
    clash = out & set(trial_layouts(protocol, setting))
    if clash:
        raise ValueError(f"{len(clash)} development layouts of {setting} are test layouts of "
                         f"{protocol.source} (the first: {sorted(clash)[0]})")
    return sorted(out)


def render_layouts(layouts: list[Layout], sim=None, detector=None) -> list:
    """The layouts built as a trial's start (vla_evaluation.kinematic.make_layouts): settled, the first
    frame rendered and detected."""
    from vla_detector.inference import Detector  # onnxruntime, MuJoCo: only when layouts are rendered
    from vla_evaluation.kinematic import make_layouts
    from vla_evaluation.resources import detector_model_path
    from vla_sim.sim import PandaSim

    sim = sim or PandaSim(render=True)
    detector = detector or Detector(detector_model_path())
    return [lay for task, seed in layouts for lay in make_layouts([task], [seed], sim=sim, detector=detector)]

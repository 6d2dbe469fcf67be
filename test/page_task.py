"""Test support: the whole base task through the operator station's page (issue 32 item 5), shared by
test/test_operator_task.py (each scripted person must succeed) and bench/bench_operator_task.py (the
time to success, several runs).

The graph is the study's for a real participant (demo.launch.yaml through the evaluation's graph runner,
without the simulated teleoperator, with the station; real time): the scene is reset through the
bridge's ~/reset to one fresh layout before each trial, the controller latches the bread, and the
evaluation's judge watches the simulation's ground truth (scene/objects) for success.
"""
from __future__ import annotations

import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path

from page_persons import until

TASK = "bread/push_east"
SEED = 300_000          # a fresh layout (vla_evaluation.holds.FRESH_SEED): never used for demonstrations
LIMIT_S = 240.0         # wall s a person may take (a loaded machine runs the simulation slower)


def need(ok: bool, why: str) -> None:
    if not ok:
        raise RuntimeError(why)


@contextmanager
def station_graph(home: Path | None = None):
    """(the graph evaluator, one browser on the station's printed address); the station's token and
    settings files in `home` (a temporary one by default), not the user's ~/.config/vla_operator."""
    from test_operator_station import Browser
    from vla_evaluation.graph import GraphConfig, GraphEvaluator
    from vla_evaluation.resources import detector_model_path, latent_model_dir

    home = Path(home or tempfile.mkdtemp(prefix="vla-page-task-"))
    saved = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    cfg = GraphConfig(model_path=str(latent_model_dir("default")), detector_model=str(detector_model_path()),
                      real_time_factor=1.0, camera_rate=10.0, operator_port=0, teleoperator=False,
                      joy_timeout=0.5, log_dir=home / "logs")
    ev = GraphEvaluator(cfg, log=print)
    b = None
    try:
        ev.start()
        log = ev.runner.session.log_path
        found = lambda: re.search(r"operator station is at (http://\S+)", log.read_text())  # noqa: E731
        if not until(lambda: found() is not None, cfg.startup_timeout):
            raise RuntimeError("the station printed no address: " + log.read_text()[-3000:])
        b = Browser()
        b.driver.get(found().group(1))
        if not until(lambda: b.driver.execute_script("return !!(window.station && window.station.driver)"),
                     60.0):
            raise RuntimeError("the page does not drive: "
                               + b.driver.execute_script("return document.body.innerText"))
        yield ev, b
    finally:
        if b is not None:
            b.quit()
        ev.close()
        if saved is None:
            os.environ.pop("HOME", None)
        else:
            os.environ["HOME"] = saved


def save_settings(b, **values) -> None:
    """The caregiver's settings through the page (as its Save button sends them), applied."""
    b.driver.execute_script("window.stationRequest({type: 'settings', values: arguments[0]}, 'settings')",
                            values)
    ok = ("const s = window.station.settings, v = arguments[0];"
          "return Object.keys(v).every((k) => s[k] === v[k]);")
    need(until(lambda: b.driver.execute_script(ok, values), 20.0), f"settings not applied: {values}")


def push_bread_east(ev, b, person_cls, seed: int = SEED) -> dict:
    """One trial: the scene reset to `seed`'s layout, the bread latched, the person drives the page."""
    from vla_common.tasks import parse_task
    from vla_evaluation.graph import EpisodeMonitor

    obs = ev.obs
    spec = parse_task(TASK, ev.catalogue)
    used, start, _q = ev.reset_scene(spec, seed, 1)
    why = ev.latch()
    need(not why and obs.ctrl.latched_class == "bread", f"the bread is not latched: {why or obs.ctrl}")
    person = person_cls(b.driver)
    person.setup(lambda **v: save_settings(b, **v))
    need(b.driver.execute_script("return window.station.speed") == 1.0, "the page's speed is not Fast")
    need(until(lambda: person.word() == "Stopped", 30.0), f"the page says {person.word()!r}, not Stopped")
    monitor = EpisodeMonitor(spec, start, ev.kin, 5, False)
    obs.monitor, monitor.t_start = monitor, obs.now()
    try:
        out = person.drive(lambda: monitor.tracker.time_to_success is not None, LIMIT_S)
    finally:
        obs.monitor = None
        save_settings(b, input_device="buttons")
        b.driver.execute_script("navigator.getGamepads = () => [];")
    return {"person": person.name, "seed": used, "done": out.done, "sim_s": monitor.tracker.time_to_success,
            "wall_s": round(out.wall_s, 1), "presses": out.presses, "words": out.words,
            "interventions": dict(monitor.tally.by_code), "load": os.getloadavg()}

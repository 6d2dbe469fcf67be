"""The runtime installs alone: its modules import and its nodes start where torch, MuJoCo, Ray and the
simulator (vla_sim) cannot be imported, as on a robot or vision PC that has only the runtime packages.

The blocker is test/runtime_blocker/sitecustomize.py, first on PYTHONPATH: a meta-path finder that
refuses those names and records, per process, that it is installed and what it refused. The environment
is otherwise this one, so the ROS wheels' re-exec guard (_ROS_WHEELS_BOOTSTRAP_COMPLETE with
LD_LIBRARY_PATH) is kept and the interpreter is not restarted without it. The one exception is the
bridge's MuJoCo backend (.importlinter), which is not imported and not started here.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from vla_launch.launcher import ProcessSpec
from vla_launch.session import LaunchSession

BLOCKER_DIR = Path(__file__).resolve().parent / "runtime_blocker"
BLOCKED = ("torch", "mujoco", "vla_sim", "ray")
RUNTIME_PACKAGES = ("vla_common", "vla_panda_bridge", "vla_camera", "vla_detector", "vla_latent_controller",
                    "vla_demo_recorder", "vla_joystick", "vla_operator", "vla_launch")
MUJOCO_BACKEND = "vla_panda_bridge.backend_mujoco"


def blocked_env(log: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(BLOCKER_DIR), env.get("PYTHONPATH")) if p)
    env.update(VLA_IMPORT_BLOCKED=",".join(BLOCKED), VLA_IMPORT_BLOCKER_LOG=str(log), PYTHONUNBUFFERED="1",
               RCUTILS_COLORIZED_OUTPUT="0")
    return env


def blocker_events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []


_TRY_IMPORTS = """
import importlib, importlib.util, json, sys
res = {}
for name in sys.argv[1:]:
    try:
        importlib.import_module(name)
        res[name] = "imported"
    except ImportError as e:
        res[name] = str(e)
print(json.dumps(res))
"""
_FIND = "import importlib.util, json, sys; print(json.dumps({n: importlib.util.find_spec(n) is not None " \
        "for n in sys.argv[1:]}))"


def _run_python(code: str, args: tuple[str, ...], env: dict[str, str]) -> dict:
    res = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.splitlines()[-1])


def test_ros_bootstrap_variables_come_together():
    """The children inherit both or neither, or the ROS wheels' .pth would re-exec them half-configured."""
    assert ("_ROS_WHEELS_BOOTSTRAP_COMPLETE" in os.environ) == ("LD_LIBRARY_PATH" in os.environ)


def test_the_blocker_blocks_what_is_installed(tmp_path):
    log = tmp_path / "blocker.jsonl"
    # The control: without the blocker, this interpreter finds them (so what stops them below is it).
    available = _run_python(_FIND, BLOCKED, dict(os.environ))
    if not any(available.values()):
        pytest.skip(f"none of {BLOCKED} is installed here: nothing for the blocker to stop")
    outcome = _run_python(_TRY_IMPORTS, BLOCKED, blocked_env(log))
    for name in BLOCKED:
        assert "blocked by test/runtime_blocker" in outcome[name], outcome
    events = blocker_events(log)
    assert events and events[0]["event"] == "installed"
    assert {e["name"] for e in events if e["event"] == "blocked"} >= set(BLOCKED)


def test_every_runtime_module_imports_without_torch_mujoco_ray_or_the_simulator(tmp_path):
    log = tmp_path / "blocker.jsonl"
    res = subprocess.run([sys.executable, "-m", "import_all", *RUNTIME_PACKAGES], env=blocked_env(log),
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    results = json.loads(res.stdout.splitlines()[-1])
    failed = {m: err for m, err in results.items() if err is not None}
    # The control: the bridge's MuJoCo backend, the one module allowed the simulator, is refused by
    # the blocker, so a runtime module that needed one of the blocked modules would be caught too.
    assert "blocked by test/runtime_blocker" in (failed.pop(MUJOCO_BACKEND, None) or ""), results
    assert not failed, "runtime modules that need a blocked (or missing) module:\n" + "\n".join(
        f"  {m}: {err}" for m, err in sorted(failed.items()))
    for pkg in RUNTIME_PACKAGES:
        assert sum(m.startswith(f"{pkg}.") for m in results) >= 2, f"no modules found in {pkg}: {results}"
    assert any(e["event"] == "installed" for e in blocker_events(log))


# --- the nodes, all at once in one blocked environment ----------------------------------------------

# label: (package, executable, shipped parameter file or None, -p overrides)
NODES = {
    "camera_node": ("vla_camera", "camera_node", "camera.yaml", ["loop:=true", "fps:=5.0"]),
    "detector_node": ("vla_detector", "detector_node", "detector.yaml", []),
    "controller_node": ("vla_latent_controller", "controller_node", "controller.yaml", []),
    "recorder": ("vla_demo_recorder", "recorder", "recorder.yaml", []),
    "joy_node": ("vla_joystick", "joy_node", None, []),  # no device here: it keeps looking for one
    "panda_bridge": ("vla_panda_bridge", "panda_bridge", "panda_bridge.yaml", ["backend:=ros2_control"]),
}
# What shows each node is up and working: camera frames published, detections of them (ONNX Runtime
# ran), each node's ~/status, and for joy_node (silent without a device) its name in the graph.
EVIDENCE = {"camera_node": "frames published on ~/status", "detector_node": "detections of its frames",
            "controller_node": "~/status", "recorder": "~/status", "panda_bridge": "~/status",
            "joy_node": "node in the ROS graph"}


def _node_command(label: str, images: Path, bags: Path) -> list[str]:
    from ament_index_python.packages import get_package_share_directory
    from vla_launch.run import find_executable

    pkg, exe, config, overrides = NODES[label]
    overrides = overrides + {"camera_node": [f"source:={images}"],
                             "recorder": [f"output_dir:={bags}"]}.get(label, [])
    argv = [find_executable(pkg, exe), "--ros-args"]
    if config:
        argv += ["--params-file", f"{get_package_share_directory('vla_bringup')}/config/{config}"]
    return argv + [w for kv in overrides for w in ("-p", kv)]


def _write_images(folder: Path) -> None:
    import cv2

    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(folder / f"frame{i}.png"), rng.integers(0, 255, (240, 320, 3), dtype=np.uint8))


def _observe(procs: LaunchSession, timeout: float) -> dict[str, bool]:
    """Spin an observer until every node has shown its evidence, one has exited, or `timeout`."""
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data as sensor
    from vla_common.ros.testing import RosHarness

    from vla_interfaces.msg import (
        CameraStatus,
        ControllerStatus,
        DetectionArray,
        RecorderStatus,
        SafetyStatus,
    )

    seen = dict.fromkeys(NODES, False)

    def mark(label: str, ok=lambda m: True):
        def callback(msg) -> None:
            seen[label] = seen[label] or bool(ok(msg))
        return callback

    h = RosHarness(other_processes=True)
    try:
        n = h.add(Node("runtime_imports_observer", context=h.context))
        frames = mark("camera_node", lambda m: m.frames_published > 0)
        n.create_subscription(CameraStatus, "camera_node/status", frames, 10)
        n.create_subscription(DetectionArray, "detections", mark("detector_node"), sensor)
        n.create_subscription(ControllerStatus, "controller_node/status", mark("controller_node"), 10)
        # the recorder executable runs the node "recorder"
        n.create_subscription(RecorderStatus, "recorder/status", mark("recorder"), 10)
        n.create_subscription(SafetyStatus, "panda_bridge/status", mark("panda_bridge"), 10)
        joy = mark("joy_node", lambda _: "joy_node" in n.get_node_names())
        n.create_timer(0.5, lambda: joy(None))
        h.spin_until(lambda: all(seen.values()) or bool(procs.ended()), timeout)
    finally:
        h.shutdown()
    return seen


@pytest.fixture(scope="module")
def runtime_nodes(tmp_path_factory):
    """Start every runtime node in parallel under the blocker; observe them; stop them with SIGINT."""
    tmp = tmp_path_factory.mktemp("runtime_nodes")
    images, bags, log = tmp / "images", tmp / "bags", tmp / "blocker.jsonl"
    _write_images(images)
    # supervised as `vla launch` does: own process groups, SIGINT then SIGTERM/SIGKILL after 10 s each,
    # in reverse order; one node ending does not stop the others
    specs = [ProcessSpec(label, _node_command(label, images, bags)) for label in NODES]
    procs = LaunchSession.of_processes(specs, env=blocked_env(log), log_path=tmp / "logs" / "nodes.log",
                                       keep_going=True, sigterm_timeout=10.0, sigkill_timeout=10.0)
    try:
        procs.start()
        t0 = time.monotonic()
        seen = _observe(procs, timeout=120.0)
        up_s = time.monotonic() - t0
        pids = procs.pids
        alive = {label: procs.alive(label) for label in NODES}
        description = procs.describe()
        procs.stop()
        codes = procs.exit_codes()
    finally:
        procs.stop()
    events = blocker_events(log)
    print(f"runtime nodes up in {up_s:.1f} s: {seen}; exit codes {codes}")
    yield {"seen": seen, "alive": alive, "codes": codes, "pids": pids, "events": events,
           "description": description + "\n" + procs.describe()}


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("label", list(NODES))
def test_runtime_node_starts_without_torch_mujoco_ray_or_the_simulator(runtime_nodes, label):
    r = runtime_nodes
    pid = r["pids"][label]
    assert r["seen"][label], f"{label}: no {EVIDENCE[label]} within the timeout\n{r['description']}"
    assert r["alive"][label], f"{label} exited while the others ran\n{r['description']}"
    assert r["codes"][label] == 0, f"{label}: exit code {r['codes'][label]} on SIGINT\n{r['description']}"
    mine = [e for e in r["events"] if e["pid"] == pid]
    assert any(e["event"] == "installed" for e in mine), f"the blocker was not loaded in {label} (pid {pid})"
    tried = [e["name"] for e in mine if e["event"] == "blocked"]
    assert not tried, f"{label} tried to import {tried} (a runtime node must not even try)"

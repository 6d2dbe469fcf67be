"""Every parameter name we ship or document is one its node declares, and a misspelt one stops the node.

A node refuses to start on a parameter it does not declare (vla_common.ros.parameters, issue 20 item
7), so a name in a shipped parameter file, a launch file or a documented `ros2 run` / `vla run` command
that the node does not declare would stop it. These tests read the names from the files as written,
and the tables from the nodes' own modules (found through their console-script entry points).
"""
from __future__ import annotations

import importlib
import re
import shlex
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest
import yaml
from vla_common.kinematics import panda_urdf_path
from vla_common.ros.context import end_context
from vla_common.ros.parameters import ParameterTable
from vla_launch.launch_file import ParamDict, ParamFile, load_launch_file
from vla_launch.substitutions import SubstitutionContext

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "src" / "vla_bringup" / "config"
ROS_OWN = {"use_sim_time", "start_type_description_service"}  # declared by rclpy for every node
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "src").glob("*/README.md")])


def node_parameters() -> dict[str, set[str]]:
    """executable -> the names its ParameterTable declares (plus rclpy's own)."""
    out = {}
    for ep in entry_points(group="console_scripts"):
        module = importlib.import_module(ep.value.split(":")[0]) if ep.value.startswith("vla_") else None
        tables = [v for v in vars(module).values() if isinstance(v, ParameterTable)] if module else []
        if tables:
            out[ep.name] = set(tables[0].params) | ROS_OWN
    return out


NODES = node_parameters()


def file_names(path: Path) -> set[str]:
    doc = yaml.safe_load(path.read_text())
    return {k for section in doc.values() for k in section["ros__parameters"]}


def test_the_nodes_are_found():
    assert {"panda_bridge", "detector_node", "controller_node", "recorder", "camera_node",
            "joy_node", "sim_teleoperator"} <= set(NODES)


@pytest.mark.parametrize("config, executable", [
    ("panda_bridge", "panda_bridge"), ("detector", "detector_node"), ("controller", "controller_node"),
    ("recorder", "recorder"), ("camera", "camera_node"), ("sim_teleoperator", "sim_teleoperator"),
])
def test_shipped_parameter_files_name_declared_parameters(config, executable):
    assert file_names(CONFIG / f"{config}.yaml") - NODES[executable] == set()


@pytest.mark.parametrize("launch", sorted([*(ROOT / "src" / "vla_bringup" / "launch").glob("*.yaml"),
                                           *(ROOT / "src" / "vla_evaluation" / "launch").glob("*.yaml")]),
                         ids=lambda p: p.name)
def test_launch_files_pass_declared_parameters(launch):
    ctx = SubstitutionContext(find_share=lambda pkg: str(ROOT / "src" / pkg))
    everything = {"use_joy": "true", "use_camera": "true", "robot_description_file": panda_urdf_path()}
    args = {k: v for k, v in everything.items() if f"name: {k}" in launch.read_text()}
    for process in load_launch_file(str(launch), args, ctx).processes:
        if not process.pkg.startswith("vla_"):
            continue                      # robot_state_publisher, tf2_ros: their parameters, not ours
        names = set()
        for p in process.params:
            names |= set(p.values) if isinstance(p, ParamDict) else file_names(Path(p.path)) \
                if isinstance(p, ParamFile) else set()
        assert names - NODES[process.executable] == set(), process.executable


def documented_runs() -> list[tuple[str, str, str, set[str]]]:
    """(doc, executable, command, its -p names) of every `ros2 run` / `vla run` command in the docs."""
    out = []
    for doc in DOCS:
        text = re.sub(r"\\\n\s*", " ", doc.read_text())  # shell line continuations
        for line in text.splitlines():
            for m in re.finditer(r"(?:ros2|vla) run \S+ (\S+) --ros-args([^`&|;\n]*)", line):
                names = set(re.findall(r"-p\s+['\"]?([A-Za-z_][\w.]*):=", m.group(2)))
                if names:
                    out.append((doc.relative_to(ROOT).as_posix(), m.group(1), m.group(0), names))
    return out


RUNS = documented_runs()


def test_the_documented_commands_are_found():
    assert any(doc == "docs/real-robot.md" and "velocity_scale" in names for doc, _, _, names in RUNS)


@pytest.mark.parametrize("doc, executable, command, names", RUNS, ids=[f"{r[0]}:{r[1]}" for r in RUNS])
def test_documented_commands_name_declared_parameters(doc, executable, command, names):
    assert names - NODES[executable] == set(), command


def documented_values() -> list[tuple[str, str, list[str]]]:
    """(doc, command, its `-p` values) of each documented run whose line holds the whole command (a
    value quoted over several lines, the joint_map example, is not joined here)."""
    out = []
    for doc, _, command, _ in RUNS:
        try:
            words = shlex.split(command.split("--ros-args", 1)[1], comments=True)
        except ValueError:
            continue
        out.append((doc, command, [v for flag, v in zip(words, words[1:]) if flag == "-p" and ":=" in v]))
    return out


@pytest.mark.parametrize("doc, command, values", documented_values(), ids=lambda v: str(v)[:40])
def test_documented_parameter_values_are_read_by_rcl(doc, command, values):
    """Each documented `-p name:=value` is one rcl reads (`-p 'ee_axes:=[x, y, z]'` was not: rcl reads a
    bare y as true and refuses a list of mixed types)."""
    import rclpy
    context = rclpy.context.Context()
    rclpy.init(context=context, args=["prog", "--ros-args", *[a for v in values for a in ("-p", v)]])
    end_context(context)


def test_a_misspelt_parameter_stops_the_real_robot_command_with_the_closest_name(tmp_path):
    """docs/real-robot.md's command with `velocity_scal` for `velocity_scale`, in a parameter file keyed
    by the renamed, namespaced node and with -p: exit code 2 before anything connects."""
    shipped = CONFIG / "panda_bridge.yaml"
    misspelt = tmp_path / "first_session.yaml"
    misspelt.write_text("/lab/arm:\n  ros__parameters:\n    velocity_scal: 0.3\n")
    base = [sys.executable, "-m", "vla_launch.cli", "run", "vla_panda_bridge", "panda_bridge", "--ros-args",
            "--params-file", str(shipped), "-p", "backend:=libfranka", "-p", "robot_ip:=172.16.0.2",
            "-p", "robot_model:=fr3", "-p", "loop_priority:=80", "-p", "acceleration_scale:=0.4999"]
    renamed = ["-r", "__ns:=/lab", "-r", "__node:=arm", "--params-file", str(misspelt)]
    for extra, node in ((renamed, "/lab/arm"), (["-p", "velocity_scal:=0.3"], "/panda_bridge")):
        try:  # refused within about 2 s; a node that runs on with the misspelt name never exits
            res = subprocess.run(base + extra, capture_output=True, text=True, timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{node} ran on with 'velocity_scal' for 60 s instead of refusing it")
        assert res.returncode == 2, res.stderr
        assert f"{node} has no parameter 'velocity_scal' (did you mean 'velocity_scale'?)" in res.stderr

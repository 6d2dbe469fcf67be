"""Turning a node description into the command line a ROS 2 node understands.

`<exe> [args] [--ros-args <ros_args>] --ros-args -r __node:=N -r __ns:=/NS <params> -r from:=to`,
the layout launch_ros uses. Parameters keep launch_ros's precedence (later entries win): a trailing
run of scalar-only inline entries becomes `-p name:=value` (rcl applies `-p` after every params file,
so only a trailing run can use it without changing precedence); every other inline entry is written to
a temporary params file (lists, or anything followed by a `from:` file). A string that rcl would read
as another type (its booleans y and n, strtod's 1e5 or inf) is quoted: PyYAML writes them plain, and
rcl would read a string "y" as true.
"""
from __future__ import annotations

import math
import os
import shutil
import tempfile
from typing import Any

import yaml

from vla_launch.launch_file import ParamDict, ParamFile, ProcessDescription
from vla_launch.run import RunError, find_executable

_RCL_BOOLS = {"y", "Y", "n", "N"}  # rcl's booleans that PyYAML reads as strings (it has yes, on, ...)


def _rcl_reads_otherwise(text: str) -> bool:
    """Whether rcl reads this plain scalar as a boolean or a number where PyYAML reads a string: rcl's
    y/n, and what strtol/strtod take (1e5, inf, nan, 0x1A)."""
    if text in _RCL_BOOLS:
        return True
    for parse in (float, lambda t: int(t, 0), float.fromhex):
        try:
            parse(text)
            return True
        except ValueError:
            pass
    return False


class _RclDumper(yaml.SafeDumper):
    """PyYAML's safe dumper, quoting the strings rcl would read as another type."""


_RclDumper.add_representer(str, lambda dumper, value: dumper.represent_scalar(
    "tag:yaml.org,2002:str", value, style="'" if _rcl_reads_otherwise(value) else None))


def _scalar_for_cli(value: Any) -> str | None:
    """A YAML scalar that rcl reads back as the same type, or None when a file is needed."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, str) and ("\n" in value or "\r" in value):
        return None
    if not isinstance(value, (bool, int, float, str)):
        return None
    text = yaml.dump(value, Dumper=_RclDumper, default_flow_style=True, width=1 << 30)
    if text.endswith("\n...\n"):
        text = text[: -len("\n...\n")]
    return text.rstrip("\n")


def _params_file(values: dict[str, Any], node_key: str, tmpdir: str) -> str:
    fd, path = tempfile.mkstemp(prefix="params_", suffix=".yaml", dir=tmpdir)
    plain = {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        yaml.dump({node_key: {"ros__parameters": plain}}, f, Dumper=_RclDumper, default_flow_style=False)
    return path


def parameter_arguments(params: list[ParamFile | ParamDict], node_key: str, tmpdir: str) -> list[str]:
    """`--params-file`/`-p` arguments for the node's parameter entries, in order."""
    cli_from = len(params)
    while cli_from > 0:
        p = params[cli_from - 1]
        if isinstance(p, ParamDict) and all(_scalar_for_cli(v) is not None for v in p.values.values()):
            cli_from -= 1
        else:
            break
    out: list[str] = []
    for i, p in enumerate(params):
        if isinstance(p, ParamFile):
            out += ["--params-file", p.path]
        elif i >= cli_from:
            for k, v in p.values.items():
                out += ["-p", f"{k}:={_scalar_for_cli(v)}"]
        elif p.values:
            out += ["--params-file", _params_file(p.values, node_key, tmpdir)]
    return out


def resolve_executable(proc: ProcessDescription) -> str:
    """The path to run: through the ament index for `pkg` + `exec`, else PATH or a path."""
    if proc.pkg:
        try:
            return find_executable(proc.pkg, proc.executable)
        except RunError as e:
            raise RunError(f"{proc.source}: {proc.pkg} {proc.executable}: {e}") from e
    if os.sep in proc.executable:
        return proc.executable
    found = shutil.which(proc.executable)
    if found is None:
        raise RunError(f"{proc.source}: executable '{proc.executable}' not found on PATH")
    return found


def build_command(proc: ProcessDescription, tmpdir: str, executable_path: str | None = None) -> list[str]:
    """The full argv for one process (temporary params files go into `tmpdir`)."""
    exe = executable_path or resolve_executable(proc)
    cmd = list(proc.launch_prefix) + [exe] + list(proc.args)
    if not proc.is_node:
        return cmd
    if proc.ros_args:
        cmd += ["--ros-args"] + list(proc.ros_args)
    ros: list[str] = []
    if proc.name:
        ros += ["-r", f"__node:={proc.name}"]
    if proc.namespace:
        ros += ["-r", f"__ns:={proc.namespace}"]
    # Like launch_ros: the node's full name when launch fixes both parts, else every node.
    node_key = proc.namespace.rstrip("/") + "/" + proc.name if proc.name and proc.namespace else "/**"
    ros += parameter_arguments(proc.params, node_key, tmpdir)
    for src, dst in proc.remaps:
        ros += ["-r", f"{src}:={dst}"]
    if ros:
        cmd += ["--ros-args"] + ros
    return cmd

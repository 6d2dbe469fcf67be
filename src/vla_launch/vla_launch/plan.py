"""From `<file> | <package> <file>` and `name:=value` words to the processes a launch starts.

Shared by `vla launch` (cli.py) and by Python harnesses (session.py), so both start exactly the same
commands with the same parameters.
"""
from __future__ import annotations

import os
from collections.abc import Mapping

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

from vla_launch.launch_file import LaunchFileError, LaunchPlan, load_launch_file
from vla_launch.launcher import ProcessSpec
from vla_launch.node_command import build_command


def find_launch_file(package: str, name: str) -> str:
    """`name` anywhere under the package's share folder, as `ros2 launch <package> <name>` finds it."""
    try:
        share = get_package_share_directory(package)
    except (PackageNotFoundError, ValueError) as e:
        raise LaunchFileError(f"Package '{package}' not found") from e
    matches = []
    for dirpath, dirnames, filenames in os.walk(share):
        dirnames.sort()
        if name in filenames:
            matches.append(os.path.join(dirpath, name))
    if not matches:
        raise LaunchFileError(f"file '{name}' was not found in the share directory of package '{package}' "
                              f"({share})")
    if len(matches) > 1:
        raise LaunchFileError(f"file '{name}' is ambiguous in package '{package}': {matches}")
    return matches[0]


def resolve_launch_file(words: list[str]) -> tuple[str, list[str]]:
    """Split `file [a:=b ...]` or `package file [a:=b ...]`; find the file like ros2 launch."""
    first = words[0]
    if os.path.isfile(first) or ":=" in first or len(words) == 1 or ":=" in words[1]:
        if not os.path.isfile(first):
            raise LaunchFileError(f"launch file not found: {first}")
        return first, words[1:]
    return find_launch_file(words[0], words[1]), words[2:]


def parse_launch_arguments(words: list[str]) -> dict[str, str]:
    out = {}
    for w in words:
        name, sep, value = w.partition(":=")
        if not sep or not name:
            raise LaunchFileError(f"launch arguments are written name:=value, got {w!r}")
        out[name] = value
    return out


def process_specs(plan: LaunchPlan, tmpdir: str) -> list[ProcessSpec]:
    """The launcher's process specs for a loaded plan (temporary parameter files go into `tmpdir`)."""
    return [ProcessSpec(label=p.label, cmd=build_command(p, tmpdir), env=p.env, cwd=p.cwd,
                        on_exit_shutdown=p.on_exit_shutdown, respawn=p.respawn,
                        respawn_delay=p.respawn_delay, sigterm_timeout=p.sigterm_timeout,
                        sigkill_timeout=p.sigkill_timeout, exec_name=p.exec_name)
            for p in plan.processes]


def load(path: str, arguments: Mapping[str, str], tmpdir: str) -> tuple[LaunchPlan, list[ProcessSpec]]:
    """Evaluate a launch file with its arguments; the plan (messages, temp files) and the specs."""
    plan = load_launch_file(path, dict(arguments))
    return plan, process_specs(plan, tmpdir)

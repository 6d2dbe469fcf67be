"""`vla run <package> <executable> [args...]`: what `ros2 run` does, without ros2cli.

Executables are looked up exactly like ros2run: through the ament index, every executable regular
file under `<prefix>/lib/<package>/` (sub-folders included, hidden ones skipped) whose name matches.
"""
from __future__ import annotations

import os
import shlex
import sys

from ament_index_python.packages import PackageNotFoundError, get_package_prefix


class RunError(RuntimeError):
    """Package or executable not found; the message is what `ros2 run` would print."""


def package_prefix(package: str) -> str:
    try:
        return get_package_prefix(package)
    except (PackageNotFoundError, ValueError) as e:
        raise RunError(f"Package '{package}' not found") from e


def _is_executable(path: str) -> bool:
    return os.path.isfile(path) and os.access(path, os.X_OK)


def executables(package: str) -> list[str]:
    """Paths of every executable of a package (sorted like ros2run)."""
    base = os.path.join(package_prefix(package), "lib", package)
    found = []
    for dirpath, dirnames, filenames in os.walk(base):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        paths = (os.path.join(dirpath, f) for f in sorted(filenames))
        found += [p for p in paths if _is_executable(p)]
    return found


def find_executable(package: str, executable: str) -> str:
    """The path of `executable` in `package`; RunError with ros2 run's wording otherwise."""
    matches = [p for p in executables(package) if os.path.basename(p) == executable]
    if not matches:
        raise RunError("No executable found")
    if len(matches) > 1:
        raise RunError("Multiple executables found:\n" + "\n".join(f"- {p}" for p in matches))
    return matches[0]


def run_command(package: str, executable: str, argv: list[str], prefix: str | None = None) -> list[str]:
    """The command line `vla run` executes."""
    return (shlex.split(prefix) if prefix else []) + [find_executable(package, executable)] + list(argv)


def main(package: str, executable: str | None, argv: list[str], prefix: str | None = None) -> int:
    """Replace this process with the executable (signals and exit code are then the node's own)."""
    try:
        if executable is None:
            names = sorted({os.path.basename(p) for p in executables(package)})
            listing = ", ".join(names) or "(none)"
            print(f"vla run: give an executable of '{package}': {listing}", file=sys.stderr)
            return 2
        cmd = run_command(package, executable, argv, prefix)
    except RunError as e:
        print(e, file=sys.stderr)
        return 1
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        os.execvp(cmd[0], cmd)
    except OSError as e:
        print(f"vla run: cannot execute {cmd[0]}: {e.strerror}", file=sys.stderr)
        return 126
    return 0  # not reached

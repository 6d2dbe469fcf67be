"""The `vla` command: `vla run` and `vla launch`, stand-ins for `ros2 run` / `ros2 launch`.

ros2cli and launch are not installable from PyPI; these two subcommands cover what the project needs
and keep the same command-line shape, so the instructions work on a full ROS 2 install too.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import shutil
import sys
import tempfile

from vla_launch import plan as plan_mod
from vla_launch import run as run_mod
from vla_launch.launch_file import LaunchFileError, declared_arguments
from vla_launch.launcher import Launcher
from vla_launch.plan import parse_launch_arguments, resolve_launch_file
from vla_launch.run import RunError
from vla_launch.substitutions import SubstitutionError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vla", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run an executable of a package (like ros2 run)",
                       description="Run a package's executable, found through the ament index.")
    r.add_argument("--prefix", help="prefix command, e.g. 'gdb -ex run --args' (shell-split)")
    r.add_argument("package_name")
    r.add_argument("executable_name", nargs="?")
    r.add_argument("argv", nargs=argparse.REMAINDER, help="arguments for the executable (--ros-args ...)")

    lp = sub.add_parser(
        "launch", help="start the nodes of a YAML launch file (like ros2 launch)",
        description="Start the processes of a ROS 2 YAML launch file: `vla launch <file>` or "
                    "`vla launch <package> <file>`, followed by name:=value launch arguments.")
    lp.add_argument("-s", "--show-args", action="store_true",
                    help="list the file's launch arguments and exit")
    lp.add_argument("--dry-run", action="store_true", help="print the commands that would run and exit")
    lp.add_argument("--abort-on-exit", action="store_true",
                    help="a process dying tears the others down, and its code is the exit code "
                         "(default: as ros2 launch, the others keep running and the exit code is 0)")
    lp.add_argument("--sigterm-timeout", type=float, default=5.0, metavar="S",
                    help="seconds after SIGINT before SIGTERM (default 5)")
    lp.add_argument("--sigkill-timeout", type=float, default=5.0, metavar="S",
                    help="seconds after SIGTERM before SIGKILL (default 5)")
    lp.add_argument("launch_args", nargs="+", metavar="ARG",
                    help="<file.launch.yaml> | <package> <file.launch.yaml>, then name:=value ...")
    return p


def _show_args(path: str) -> int:
    args = declared_arguments(path)
    if not args:
        print("No arguments.")
    for a in args:
        print(f"    '{a.name}':")
        print(f"        {a.description or 'no description given'}")
        if a.choices:
            print(f"        Valid choices are: {a.choices}")
        print(f"        (default: '{a.default}')" if a.default is not None else "        (required)")
    return 0


def launch_main(ns: argparse.Namespace) -> int:
    tmpdir = None
    plan = None
    try:
        path, rest = resolve_launch_file(ns.launch_args)
        if ns.show_args:
            return _show_args(path)
        tmpdir = tempfile.mkdtemp(prefix="vla_launch_")
        plan, specs = plan_mod.load(path, parse_launch_arguments(rest), tmpdir)
        for m in plan.messages:
            print(f"[INFO] [launch.user]: {m}", file=sys.stderr)
        if ns.dry_run:
            for s in specs:
                print(f"{s.label}: {shlex.join(s.cmd)}")
            return 0
        if not specs:
            print("[INFO] [launch]: nothing to launch", file=sys.stderr)
            return 0
        return Launcher(specs, sigterm_timeout=ns.sigterm_timeout, sigkill_timeout=ns.sigkill_timeout,
                        keep_going=not ns.abort_on_exit).run()
    except (LaunchFileError, SubstitutionError, RunError) as e:
        print(f"vla launch: error: {e}", file=sys.stderr)
        return 1
    finally:
        if tmpdir:
            shutil.rmtree(tmpdir, ignore_errors=True)
        for f in plan.temp_files if plan else []:
            with contextlib.suppress(OSError):
                os.unlink(f)


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    ns, extra = parser.parse_known_args(argv)
    if extra and (ns.command != "launch" or not all(":=" in w for w in extra)):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:  # launch arguments given after an option: `vla launch f.yaml --dry-run a:=b`
        ns.launch_args += extra
    if ns.command == "run":
        return run_mod.main(ns.package_name, ns.executable_name, ns.argv, ns.prefix)
    return launch_main(ns)


if __name__ == "__main__":
    sys.exit(main())

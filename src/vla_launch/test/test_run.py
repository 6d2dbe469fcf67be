"""`vla run`: ament-index resolution like `ros2 run`, clear errors, arguments passed through."""
import os
import subprocess
import sys

import pytest
from vla_launch.run import RunError, executables, find_executable, run_command

VLA = [sys.executable, "-m", "vla_launch.cli"]


def vla(*args, timeout=30):
    return subprocess.run(VLA + list(args), capture_output=True, text=True, timeout=timeout)


def test_resolves_installed_executable_like_ros2_run():
    from ament_index_python.packages import get_package_prefix

    path = find_executable("vla_panda_bridge", "panda_bridge")
    prefix = get_package_prefix("vla_panda_bridge")
    assert path == os.path.join(prefix, "lib", "vla_panda_bridge", "panda_bridge")
    assert os.access(path, os.X_OK)
    names = {os.path.basename(p) for p in executables("vla_launch")}
    assert names == {"vla"}


def test_missing_package_and_executable_errors():
    with pytest.raises(RunError, match="^Package 'no_such_package' not found$"):
        find_executable("no_such_package", "x")
    with pytest.raises(RunError, match="^No executable found$"):
        find_executable("vla_launch", "no_such_exe")


def test_prefix_is_shell_split():
    cmd = run_command("vla_launch", "vla", ["--help"], prefix="env FOO='a b'")
    assert cmd[:2] == ["env", "FOO=a b"] and cmd[2].endswith("/vla") and cmd[3:] == ["--help"]


def test_cli_runs_the_executable_with_arguments_and_exit_code():
    r = vla("run", "vla_launch", "vla", "launch", "--help")
    assert r.returncode == 0 and "--show-args" in r.stdout
    r = vla("run", "vla_launch", "vla", "launch", "/no/such.launch.yaml")
    assert r.returncode == 1 and "launch file not found" in r.stderr
    r = vla("run", "--prefix", "echo PREFIX", "vla_panda_bridge", "panda_bridge",
            "--ros-args", "-p", "rate:=2.0")
    assert r.returncode == 0 and r.stdout.startswith("PREFIX /") and r.stdout.rstrip().endswith(
        "panda_bridge --ros-args -p rate:=2.0")


def test_cli_errors():
    r = vla("run", "no_such_package", "x")
    assert r.returncode == 1 and r.stderr.strip() == "Package 'no_such_package' not found"
    r = vla("run", "vla_launch", "no_such_exe")
    assert r.returncode == 1 and r.stderr.strip() == "No executable found"
    r = vla("run", "vla_panda_bridge")
    assert r.returncode == 2 and "panda_bridge" in r.stderr

"""Build a ROS interface package from its published definition (colcon, rosidl) for the tests of an
optional path: vision_msgs and control_msgs have no PyPI wheel, so their paths are exercised with a
package built here (`test_vision_msgs.py`, `test_control_msgs.py`). Kept in build/ (ignored) while the
definitions are the same: ~10 s at rest, minutes on a loaded 2-core machine."""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>{name}</name><version>{version}</version><description>test build</description>
  <maintainer email="t@example.com">t</maintainer><license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  {depends}
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE = """cmake_minimum_required(VERSION 3.8)
project({name})
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
{finds}
rosidl_generate_interfaces(${{PROJECT_NAME}} {files} DEPENDENCIES {deps})
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""


def build(name: str, version: str, interfaces: dict[str, str], deps: list[str]) -> Path:
    """The install folder of package `name` with `interfaces` ({"msg/X.msg": text, ...})."""
    if shutil.which("colcon") is None:
        pytest.fail("colcon is not installed: run make setup")
    files = dict(interfaces)
    files["package.xml"] = PACKAGE_XML.format(name=name, version=version,
                                              depends="".join(f"<depend>{d}</depend>" for d in deps))
    finds = "\n".join(f"find_package({d} REQUIRED)" for d in deps)
    listed = " ".join(f'"{f}"' for f in interfaces)
    files["CMakeLists.txt"] = CMAKE.format(name=name, finds=finds, files=listed, deps=" ".join(deps))
    digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()[:16]
    ws = ROOT / "build" / f"test_{name}"
    install = ws / "install" / name
    if (ws / "stamp").is_file() and (ws / "stamp").read_text() == digest:
        return install
    shutil.rmtree(ws, ignore_errors=True)
    for path, text in files.items():
        (ws / "src" / name / path).parent.mkdir(parents=True, exist_ok=True)
        (ws / "src" / name / path).write_text(text)
    venv = Path(sys.prefix)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv))
    r = subprocess.run(
        ["colcon", "--log-base", "log", "build", "--base-paths", "src", "--event-handlers", "console_direct-",
         "--cmake-args", f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF", "-Wno-dev"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=1500)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    (ws / "stamp").write_text(digest)
    return install


def environment(install: Path) -> dict[str, str]:
    """This process's environment with the built package importable (Python, its libraries, ament)."""
    site = install / Path(sysconfig.get_paths()["purelib"]).relative_to(sys.prefix)
    env = dict(os.environ)
    paths = (("PYTHONPATH", site), ("LD_LIBRARY_PATH", install / "lib"), ("AMENT_PREFIX_PATH", install))
    for var, path in paths:
        env[var] = os.pathsep.join(filter(None, [str(path), env.get(var)]))
    return env


def run_check(install: Path, script: str, ok: str) -> None:
    """Run test/<script> where the package is importable; it must print `ok`."""
    r = subprocess.run([sys.executable, str(ROOT / "test" / script)], env=environment(install),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and ok in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]

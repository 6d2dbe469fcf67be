"""vision_msgs/Detection2DArray paths, with a vision_msgs interface package built here (colcon, rosidl)
from its documented definition (ros-perception/vision_msgs 4.x, the Jazzy release): vision_msgs has no
PyPI wheel, so this is how the optional path gets exercised on this machine. Without it (the usual
case here) the nodes must still start: that is every other node test."""
import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.ros, pytest.mark.slow]

# The message definitions of vision_msgs 4.x (ros-perception/vision_msgs, ROS 2 branch), as used here.
MSGS = {
    "Point2D": "float64 x\nfloat64 y\n",
    "Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "ObjectHypothesis": "string class_id\nfloat64 score\n",
    "ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    "Detection2D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox2D bbox\n"
                   "string id\n",
    "Detection2DArray": "std_msgs/Header header\nDetection2D[] detections\n",
}
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>vision_msgs</name><version>4.1.1</version><description>test build</description>
  <maintainer email="t@example.com">t</maintainer><license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>std_msgs</depend><depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE = """cmake_minimum_required(VERSION 3.8)
project(vision_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(std_msgs REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} %s DEPENDENCIES std_msgs geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""


@pytest.fixture(scope="module")
def vision_msgs_install() -> Path:
    """Build once, keep it in build/ (ignored) while the definitions are the same: ~10 s at rest,
    minutes on a loaded 2-core machine."""
    if shutil.which("colcon") is None:
        pytest.fail("colcon is not installed: run make setup")
    files = {f"msg/{n}.msg": t for n, t in MSGS.items()}
    files["package.xml"] = PACKAGE_XML
    files["CMakeLists.txt"] = CMAKE % " ".join(f'"msg/{n}.msg"' for n in MSGS)
    digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()[:16]
    ws = ROOT / "build" / "test_vision_msgs"
    install = ws / "install" / "vision_msgs"
    if (ws / "stamp").is_file() and (ws / "stamp").read_text() == digest:
        return install
    shutil.rmtree(ws, ignore_errors=True)
    for name, text in files.items():
        (ws / "src" / "vision_msgs" / name).parent.mkdir(parents=True, exist_ok=True)
        (ws / "src" / "vision_msgs" / name).write_text(text)
    venv = Path(sys.prefix)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv))
    r = subprocess.run(
        ["colcon", "--log-base", "log", "build", "--base-paths", "src", "--event-handlers", "console_direct-",
         "--cmake-args", f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF", "-Wno-dev"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=1500)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    (ws / "stamp").write_text(digest)
    return install


@pytest.mark.timeout(1800)
def test_detector_publishes_and_controller_accepts_detection2d_array(vision_msgs_install):
    site = vision_msgs_install / Path(sysconfig.get_paths()["purelib"]).relative_to(sys.prefix)
    lib = vision_msgs_install / "lib"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")]))
    env["LD_LIBRARY_PATH"] = os.pathsep.join(filter(None, [str(lib), env.get("LD_LIBRARY_PATH")]))
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(filter(None, [str(vision_msgs_install),
                                                             env.get("AMENT_PREFIX_PATH")]))
    r = subprocess.run([sys.executable, str(ROOT / "test" / "vision_msgs_check.py")], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "vision_msgs paths ok" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]


def test_without_vision_msgs_the_module_says_so():
    from vla_common.ros import vision

    assert vision.AVAILABLE in (True, False)
    if not vision.AVAILABLE:
        assert vision.Detection2DArray is None

"""What each package imports, as package.xml dependency keys (rosdep keys for Python modules)."""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

# Python module -> the rosdep key that provides it (pip-only modules use rosdep's `-pip` convention).
MODULE_KEYS = {
    "numpy": "python3-numpy",
    "cv2": "python3-opencv",
    "yaml": "python3-yaml",
    "lark": "python3-lark-parser",
    "ruamel": "python3-ruamel.yaml",
    "evdev": "python3-evdev",
    "aiohttp": "python3-aiohttp",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "pinocchio": "pinocchio",
    "example_robot_data": "example-robot-data",
    "mujoco": "python3-mujoco-pip",
    "onnxruntime": "python3-onnxruntime-pip",
    "onnx": "python3-onnx-pip",
    "safetensors": "python3-safetensors-pip",
    "torch": "python3-pytorch-pip",
    "mcap": "python3-mcap-pip",
    "mcap_ros2": "mcap-ros2-support",
    "rosbags": "python3-rosbags-pip",
    "pylibfranka": "python3-pylibfranka-pip",
    "panda_py": "python3-panda-python-pip",
    "pydantic": "python3-pydantic-pip",
    "pydantic_core": "python3-pydantic-pip",
    "ray": "python3-ray-pip",
}
# ROS packages are their own keys (rclpy, sensor_msgs, vla_common, ...).
IGNORED = set(sys.stdlib_module_names) | {"__future__"}


def python_packages() -> list[str]:
    return sorted(p.name for p in SRC.iterdir() if (p / p.name).is_dir())


def imported_modules(package: str) -> set[str]:
    """Top-level modules imported by the package's own code (not its tests)."""
    found: set[str] = set()
    for f in (SRC / package / package).rglob("*.py"):
        for n in ast.walk(ast.parse(f.read_text())):
            if isinstance(n, ast.Import):
                found.update(a.name.split(".")[0] for a in n.names)
            elif isinstance(n, ast.ImportFrom) and n.module and n.level == 0:
                found.add(n.module.split(".")[0])
    return found - IGNORED - {package}


def launched_packages(package: str) -> set[str]:
    """Packages the package's launch files start or read files from (`pkg:` and `$(find-pkg-share X)`)."""
    found: set[str] = set()
    for f in (SRC / package / "launch").glob("*.launch.yaml"):
        text = f.read_text()
        found.update(re.findall(r"^\s*pkg:\s*([\w]+)", text, flags=re.M))
        found.update(re.findall(r"\$\(find-pkg-share\s+([\w]+)\)", text))
    return found - {package}


def required_keys(package: str) -> set[str]:
    """What the package's code imports and its launch files start, as dependency keys."""
    return {MODULE_KEYS.get(m, m) for m in imported_modules(package)} | launched_packages(package)

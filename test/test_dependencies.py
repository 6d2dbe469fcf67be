"""The locks follow pyproject.toml, and each part of the workspace finds what it imports in its lock.

pyproject.toml lists the direct dependencies with their reasons: the runtime's, the evaluation's extra
(torch, MuJoCo, Ray) and dev's. `make lock` compiles them into requirements.txt (all) and
requirements-runtime.txt (the runtime alone). A dependency imported but not declared, a lock not
regenerated after an edit, or torch, MuJoCo or Ray reaching the runtime fails here.
"""
from __future__ import annotations

import importlib.metadata as md
import re
import tomllib
from pathlib import Path

import pytest
from package_deps import imported_modules, python_packages
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
# What runs on a robot or vision PC: these packages' imports come from requirements-runtime.txt.
RUNTIME = ("vla_common", "vla_panda_bridge", "vla_camera", "vla_detector", "vla_latent_controller",
           "vla_demo_recorder", "vla_joystick", "vla_operator", "vla_launch")
NOT_IN_RUNTIME = ("torch", "mujoco", "ray")
# Imports that are the runtime's but not its lock's: the bridge's MuJoCo backend (the simulator, which
# the runtime does not install: test_runtime_imports.py), and the packages' own test helpers.
OPTIONAL_IN_RUNTIME = {"vla_panda_bridge": {"mujoco"}}


def pins(lock: str) -> dict[str, Version]:
    found = {}
    for line in (ROOT / lock).read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9._-]+)==(\S+)", line)
        if m:
            found[canonicalize_name(m[1])] = Version(m[2])
    return found


def project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def direct(*extras: str) -> list[Requirement]:
    p = project()
    reqs = list(p["dependencies"])
    for extra in extras:
        reqs += p["optional-dependencies"][extra]
    return [Requirement(r) for r in reqs]


def distributions_of(modules: set[str]) -> dict[str, set[str]]:
    """{module: its installed distributions} for the third-party modules among `modules`."""
    table = md.packages_distributions()
    return {m: {canonicalize_name(d) for d in table[m]} for m in modules if m in table}


def test_every_direct_dependency_is_pinned_in_the_lock_within_its_specifier():
    lock = pins("requirements.txt")
    for req in direct(*project()["optional-dependencies"]):
        name = canonicalize_name(req.name)
        assert name in lock, f"{req} is in pyproject.toml but not in requirements.txt: run `make lock`"
        assert req.specifier.contains(lock[name], prereleases=True), (
            f"requirements.txt pins {name}=={lock[name]}, outside pyproject.toml's {req}: run `make lock`")


def test_the_runtime_lock_has_no_torch_mujoco_or_ray_and_agrees_with_the_full_lock():
    runtime, full = pins("requirements-runtime.txt"), pins("requirements.txt")
    assert not [n for n in runtime if n.split("-")[0] in NOT_IN_RUNTIME], sorted(runtime)
    assert {canonicalize_name(r.name) for r in direct()} <= set(runtime)
    assert {n: v for n, v in runtime.items() if full.get(n) != v} == {}
    for name in NOT_IN_RUNTIME:
        assert name in full, f"{name} is not in requirements.txt"


@pytest.mark.parametrize("package", python_packages())
def test_what_a_package_imports_is_declared_and_locked(package):
    """Each third-party distribution the package imports is a direct dependency (the runtime's for a
    runtime package) and is pinned in that part's lock. The ROS wheels come in as a whole through
    ros-jazzy-* (their message packages are not listed one by one)."""
    runtime = package in RUNTIME
    ours = {p.name for p in (ROOT / "src").iterdir()}
    imports = imported_modules(package) - OPTIONAL_IN_RUNTIME.get(package, set()) - ours
    dists = distributions_of(imports)
    declared = {canonicalize_name(r.name) for r in (direct() if runtime else direct("evaluation"))}
    lock = pins("requirements-runtime.txt" if runtime else "requirements.txt")
    for module, names in sorted(dists.items()):
        assert names & set(lock), f"{package} imports {module} ({names}), not in its lock"
        if not any(n.startswith("ros-") or n in ("rclpy",) for n in names) and module != "setuptools":
            assert names & declared, (f"{package} imports {module} from {sorted(names)}, not a direct "
                                      f"dependency of {'the runtime' if runtime else 'the evaluation'} "
                                      "in pyproject.toml")


def test_the_check_sees_a_missing_declaration():
    """The control: a module whose distribution is not declared is caught."""
    dists = distributions_of({"torch", "yaml"})
    runtime_declared = {canonicalize_name(r.name) for r in direct()}
    assert dists["yaml"] & runtime_declared
    assert not dists["torch"] & runtime_declared
    assert md.version("torch").startswith("2.13.0")

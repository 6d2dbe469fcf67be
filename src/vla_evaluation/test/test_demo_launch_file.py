"""demo.launch.yaml, this package's launch file: it loads with vla_bringup's parameter files, starts the
demo graph on simulated time, and defaults its arguments to the shipped parameter values."""

import os

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from require import missing
from vla_launch.launch_file import ParamDict, ParamFile, declared_arguments, load_launch_file
from vla_launch.substitutions import SubstitutionContext

PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "launch", "demo.launch.yaml")
EXECS = ["panda_bridge", "detector_node", "controller_node", "sim_teleoperator"]
CONFIG_FILES = {"panda_bridge": "panda_bridge", "detector_node": "detector", "controller_node": "controller",
                "sim_teleoperator": "sim_teleoperator"}
# launch argument -> (vla_bringup parameter file, parameter) whose shipped value is the argument's default
ARGUMENT_DEFAULTS = {
    "real_time_factor": ("panda_bridge", "real_time_factor"),
    "state_rate": ("panda_bridge", "state_rate"),
    "camera_rate": ("panda_bridge", "camera_rate"),
    "rate": ("controller", "rate"),
}


@pytest.fixture(scope="module")
def bringup_share() -> str:
    try:
        return get_package_share_directory("vla_bringup")
    except (LookupError, ValueError):
        missing("SETUP", "vla_bringup not installed (make setup)")


def test_demo_launch_file_starts_the_demo_graph_on_simulated_time(bringup_share):
    ctx = SubstitutionContext(find_share=lambda pkg: bringup_share if pkg == "vla_bringup" else "")
    plan = load_launch_file(PATH, {}, ctx)
    assert [p.executable for p in plan.processes] == EXECS
    for p in plan.processes:
        # each node reads vla_bringup's config/<exec>.yaml first (it exists), then the arguments
        assert isinstance(p.params[0], ParamFile), p.executable
        assert p.params[0].path == os.path.join(bringup_share, "config", f"{CONFIG_FILES[p.executable]}.yaml")
        assert os.path.isfile(p.params[0].path)
        assert all(isinstance(d, ParamDict) for d in p.params[1:])
        inline = {k: v for d in p.params if isinstance(d, ParamDict) for k, v in d.values.items()}
        if p.executable != "panda_bridge":
            assert inline["use_sim_time"] is True
        assert p.env.get("OPENBLAS_NUM_THREADS") == os.environ.get("OPENBLAS_NUM_THREADS", "1")
    for a in declared_arguments(PATH):
        assert a.description, f"argument {a.name} has no description"


def test_demo_argument_defaults_are_the_shipped_parameter_values(bringup_share):
    checked = 0
    for a in declared_arguments(PATH):
        if a.name in ARGUMENT_DEFAULTS:
            config, param = ARGUMENT_DEFAULTS[a.name]
            with open(os.path.join(bringup_share, "config", f"{config}.yaml")) as f:
                shipped = yaml.safe_load(f)["/**"]["ros__parameters"][param]
            assert yaml.safe_load(a.default) == shipped, (a.name, a.default, shipped)
            checked += 1
    assert checked == len(ARGUMENT_DEFAULTS)

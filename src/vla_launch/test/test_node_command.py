"""Node description -> command line, and that rclpy reads the parameters back with the same types."""
import os

import pytest
import yaml
from vla_launch.launch_file import ParamDict, ParamFile, ProcessDescription
from vla_launch.node_command import build_command, parameter_arguments


def test_node_fields_map_onto_ros_args(tmp_path):
    proc = ProcessDescription(
        label="t", executable="panda_bridge", pkg="vla_panda_bridge", name="talker", namespace="/robot",
        params=[ParamFile("/cfg/a.yaml"), ParamDict({"rate": 2.0, "message": "hi"})],
        remaps=[("chatter", "/chat")], ros_args=["--log-level", "debug"], args=["--x", "1"],
        launch_prefix=["nice", "-n", "5"])
    cmd = build_command(proc, str(tmp_path))
    assert cmd[:3] == ["nice", "-n", "5"]
    assert cmd[3].endswith("lib/vla_panda_bridge/panda_bridge") and os.access(cmd[3], os.X_OK)
    assert cmd[4:] == ["--x", "1", "--ros-args", "--log-level", "debug",
                       "--ros-args", "-r", "__node:=talker", "-r", "__ns:=/robot",
                       "--params-file", "/cfg/a.yaml", "-p", "rate:=2.0", "-p", "message:=hi",
                       "-r", "chatter:=/chat"]


def test_plain_executable_gets_no_ros_args(tmp_path):
    proc = ProcessDescription(label="x", executable="/bin/echo", is_node=False, args=["a"])
    assert build_command(proc, str(tmp_path)) == ["/bin/echo", "a"]


def test_inline_params_keep_launch_precedence(tmp_path):
    """Only a trailing run of scalar entries may use -p: rcl applies -p after every params file."""
    params = [ParamDict({"a": 1}), ParamFile("/f.yaml"), ParamDict({"b": [1, 2]}), ParamDict({"c": "x"})]
    args = parameter_arguments(params, "/**", str(tmp_path))
    assert args[0] == "--params-file" and args[2:4] == ["--params-file", "/f.yaml"]
    assert args[4] == "--params-file" and args[6:] == ["-p", "c:=x"]
    with open(args[1]) as f:
        assert yaml.safe_load(f) == {"/**": {"ros__parameters": {"a": 1}}}
    with open(args[5]) as f:
        assert yaml.safe_load(f) == {"/**": {"ros__parameters": {"b": [1, 2]}}}


TRICKY = {
    "s_true": "true", "s_float": "1.0", "s_empty": "", "s_colon": "a: b", "s_hash": "#x",
    "s_list": "[1]", "s_null": "null", "s_yes": "yes", "s_tilde": "~", "s_space": "two words",
    "s_quote": "it's \"q\"", "s_path": "/a/b:c", "i": 7, "i_neg": -3, "i_big": 2**40, "f": 1.0,
    "f_small": 1e-9, "f_neg": -2.5, "b": True, "b_false": False,
    "nested.inner": 3, "l_int": (1, 2), "l_str": ("a", "true"), "l_float": (0.5, 1.0), "l_bool": (True,),
    "s_multi": "line1\nline2",
    # plain scalars rcl reads as another type than PyYAML does (its booleans y/n, strtod's numbers)
    "s_y": "y", "s_n": "N", "s_exp": "1e5", "s_inf": "inf", "s_nan": "nan", "s_hex": "0x1A",
    "l_axes": ("x", "y", "z"),
}


@pytest.mark.ros
def test_rclpy_reads_every_value_back_with_its_type(tmp_path):
    import rclpy
    from rclpy.context import Context
    from vla_common.ros.context import end_context

    scalars = {k: v for k, v in TRICKY.items() if not isinstance(v, tuple) and "\n" not in str(v)}
    others = {k: v for k, v in TRICKY.items() if k not in scalars}
    proc = ProcessDescription(label="n", executable="/bin/true", name="probe", namespace="/robot",
                              params=[ParamDict(others), ParamDict(scalars)])
    cmd = build_command(proc, str(tmp_path), executable_path="/bin/true")
    assert cmd.count("-p") == len(scalars) and cmd.count("--params-file") == 1
    ctx = Context()
    rclpy.init(args=cmd, context=ctx)
    try:
        node = rclpy.create_node("anything", context=ctx,
                                 automatically_declare_parameters_from_overrides=True)
        assert node.get_fully_qualified_name() == "/robot/probe"
        for name, want in TRICKY.items():
            got = node.get_parameter(name).value
            if isinstance(want, tuple):
                got = tuple(got)
            assert got == want and type(got) is type(want), (name, got, want)
        node.destroy_node()
    finally:
        end_context(ctx)

"""The parameter table: declared with descriptors, ranges and choices; applied or refused at run time."""
import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from vla_common.ros.node_main import ConfigError
from vla_common.ros.parameters import Param, ParameterTable

TABLE = ParameterTable([
    Param("rate", 100.0, "rate (Hz)", range=(1.0, 1000.0)),
    Param("mode", "latent", "mode", choices=("latent", "end_effector"), dynamic=True),
    Param("count", 3, "count", range=(0, 10), dynamic=True,
          check=lambda v: "odd only" if v % 2 == 0 else None),
    Param("names", [], "names", array="string_array", dynamic=True),
    Param("fixed", [], "fixed", array="double_array"),
])


@pytest.fixture
def ctx():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield context
    rclpy.shutdown(context=context)


def make(ctx, overrides=(), on_change=None):
    node = Node("t", context=ctx, parameter_overrides=list(overrides))
    return node, TABLE.declare(node, on_change)


def test_declared_with_defaults_ranges_and_read_only(ctx):
    node, values = make(ctx)
    assert values == {"rate": 100.0, "mode": "latent", "count": 3, "names": [], "fixed": []}
    assert node.get_parameter("names").value == [] and node.get_parameter("fixed").value == []
    d = node.describe_parameter("rate")
    assert d.read_only and d.floating_point_range[0].to_value == 1000.0
    assert "one of: latent, end_effector" in node.describe_parameter("mode").additional_constraints
    assert not node.set_parameters([Parameter("rate", value=50.0)])[0].successful  # read-only
    assert not node.set_parameters([Parameter("fixed", value=[1.0])])[0].successful
    node.destroy_node()


def test_an_integer_is_taken_for_a_double_and_overrides_apply(ctx):
    node, values = make(ctx, [Parameter("rate", value=500), Parameter("names", value=["a", "b"])])
    assert values["rate"] == 500.0 and isinstance(values["rate"], float) and values["names"] == ["a", "b"]
    node.destroy_node()


@pytest.mark.parametrize("override, message", [
    (Parameter("mode", value="other"), "must be one of"),
    (Parameter("count", value=4), "odd only"),
    (Parameter("rate", value=5000.0), "parameter 'rate'"),
])
def test_refused_at_startup(ctx, override, message):
    with pytest.raises(ConfigError, match=message):
        make(ctx, [override])


def test_run_time_changes_are_applied_or_refused(ctx):
    applied = []
    node, _ = make(ctx, on_change=lambda n, v: "busy" if v == 7 else applied.append((n, v)))
    assert node.set_parameters([Parameter("mode", value="end_effector")])[0].successful
    r = node.set_parameters([Parameter("mode", value="nope")])[0]
    assert not r.successful and "must be one of" in r.reason
    r = node.set_parameters([Parameter("count", value=7)])[0]
    assert not r.successful and r.reason == "busy" and node.get_parameter("count").value == 3
    # a batch is checked as a whole before anything is applied
    r = node.set_parameters_atomically([Parameter("names", value=["x"]), Parameter("count", value=2)])
    assert not r.successful and ("names", ["x"]) not in applied
    assert applied == [("mode", "end_effector")]
    node.destroy_node()


# -- names the node does not declare (issue 20 item 7) ------------------------------------------------

def _node_with_args(tmp_path, args, name="t"):
    """A node created as `ros2 run` would, with `--ros-args ...` given to rcl (files, -p, remaps)."""
    context = rclpy.context.Context()
    rclpy.init(context=context, args=["prog", "--ros-args", *args])
    try:
        node = Node(name, context=context)
        try:
            return TABLE.declare(node)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def _file(tmp_path, key, params):
    body = "".join(f"    {k}: {v}\n" for k, v in params.items())
    path = tmp_path / "params.yaml"
    path.write_text(f"{key}:\n  ros__parameters:\n{body}")
    return str(path)


@pytest.mark.parametrize("source", ["file", "-p"])
def test_a_misspelt_parameter_is_refused_naming_the_closest(tmp_path, source):
    args = (["--params-file", _file(tmp_path, "/**", {"rat": 50.0})] if source == "file"
            else ["-p", "rat:=50.0"])
    with pytest.raises(ConfigError, match=r"/t has no parameter 'rat' \(did you mean 'rate'\?\)"):
        _node_with_args(tmp_path, args)


def test_a_name_far_from_every_parameter_lists_them(tmp_path):
    with pytest.raises(ConfigError, match="'zzz'.*its parameters are count, fixed, mode, names, rate, "
                                          "start_type_description_service, use_sim_time$"):
        _node_with_args(tmp_path, ["-p", "zzz:=1"])


def test_namespaced_and_renamed_nodes_check_their_own_section(tmp_path):
    remap = ["-r", "__ns:=/arm", "-r", "__node:=left"]
    with pytest.raises(ConfigError, match="/arm/left has no parameter 'modes'"):
        _node_with_args(tmp_path, [*remap, "--params-file", _file(tmp_path, "/arm/left", {"modes": "x"})])
    with pytest.raises(ConfigError, match="/arm/left has no parameter 'modes'"):
        _node_with_args(tmp_path, [*remap, "--params-file", _file(tmp_path, "/**/left", {"modes": "x"})])
    # another node's section is that node's concern; ours and rclpy's own names start
    values = _node_with_args(tmp_path, [*remap, "--params-file",
                                        _file(tmp_path, "/arm/right", {"modes": "x"})])
    assert values["mode"] == "latent"
    values = _node_with_args(tmp_path, [*remap, "--params-file", _file(
        tmp_path, "/**", {"rate": 50, "use_sim_time": "true", "mode": "end_effector"})])
    assert values["rate"] == 50.0 and values["mode"] == "end_effector"


def test_constructor_overrides_are_checked_too(ctx):
    with pytest.raises(ConfigError, match="did you mean 'count'"):
        make(ctx, [Parameter("cuont", value=3)])


def test_an_exception_in_on_change_refuses_the_change_and_the_node_lives(ctx):
    def on_change(name, value):
        raise TypeError("a defect in the node")

    node, _ = make(ctx, on_change=on_change)
    r = node.set_parameters([Parameter("mode", value="end_effector")])[0]
    assert not r.successful and r.reason == ("parameter 'mode' could not be applied (TypeError); the node "
                                             "keeps the previous value")
    assert node.get_parameter("mode").value == "latent"
    node.destroy_node()

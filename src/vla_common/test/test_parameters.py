"""The parameter table: declared with descriptors, ranges and choices; applied or refused at run time."""
import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from vla_common.ros.context import end_context
from vla_common.ros.node_main import ConfigError
from vla_common.ros.parameter_sources import key_matches, remember
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
    end_context(context)


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

class Warnings(list):
    """A logger that keeps its warnings."""

    def warning(self, text):
        self.append(text)


def _node_with_args(tmp_path, args, name="t", warnings=None):
    """A node created as `ros2 run` would, with `--ros-args ...` given to rcl (files, -p, remaps), its
    command line remembered as run_node remembers it."""
    context = rclpy.context.Context()
    argv = ["prog", "--ros-args", *args]
    rclpy.init(context=context, args=argv)
    remember(context, argv)
    try:
        node = Node(name, context=context)
        node.get_logger = lambda: Warnings() if warnings is None else warnings
        try:
            return TABLE.declare(node)
        finally:
            node.destroy_node()
    finally:
        end_context(context)


def _file(tmp_path, key, params, name="params.yaml"):
    body = "".join(f"    {k}: {v}\n" for k, v in params.items())
    path = tmp_path / name
    path.write_text(f"{key}:\n  ros__parameters:\n{body}")
    return str(path)


@pytest.mark.parametrize("source", ["file", "-p"])
def test_a_misspelt_parameter_is_refused_naming_the_closest(tmp_path, source):
    args = (["--params-file", _file(tmp_path, "/t", {"rat": 50.0})] if source == "file"
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


# -- whose section: the node's own refuses, a shared one warns (issue 32 item 10) ---------------------

def test_an_unknown_name_under_a_shared_section_warns_and_the_node_starts(tmp_path):
    """One `/**` file for several nodes: a name another node declares must not stop this one."""
    shared = _file(tmp_path, "/**", {"rate": 50, "other_nodes_param": 1, "rat": 2})
    warnings = Warnings()
    values = _node_with_args(tmp_path, ["--params-file", shared], warnings=warnings)
    assert values["rate"] == 50.0
    assert len(warnings) == 2
    assert warnings[0].startswith(f"parameter 'other_nodes_param' given under '/**' in {shared} is not a "
                                  "parameter of /t: ignored")
    assert "parameter 'rat' given under '/**'" in warnings[1] and "(did you mean 'rate'?)" in warnings[1]


@pytest.mark.parametrize("key", ["/**", "/arm/*", "/arm/**"])
def test_every_wildcard_section_is_shared(tmp_path, key):
    warnings = Warnings()
    _node_with_args(tmp_path, ["-r", "__ns:=/arm", "--params-file", _file(tmp_path, key, {"zzz": 1})],
                    warnings=warnings)
    assert len(warnings) == 1 and f"under '{key}'" in warnings[0]


@pytest.mark.parametrize("own", ["t", "/t", "/**/t", "/*/t"])
def test_an_unknown_name_under_the_nodes_own_key_is_refused_even_beside_a_shared_one(tmp_path, own):
    shared = _file(tmp_path, "/**", {"rat": 1}, "shared.yaml")
    ns = ["-r", "__ns:=/arm"] if own == "/*/t" else []
    with pytest.raises(ConfigError, match=r"has no parameter 'rat' \(did you mean 'rate'\?\)"):
        _node_with_args(tmp_path, [*ns, "--params-file", shared, "--params-file",
                                   _file(tmp_path, own, {"rat": 1}, "own.yaml")])


def test_a_parameter_file_with_no_section_for_the_node_warns_naming_the_close_key(tmp_path):
    """`panda_bridg:` for `panda_bridge`: rcl ignores the file without a word; the node says so."""
    misspelt = _file(tmp_path, "panda_bridg", {"rate": 50})
    warnings = Warnings()
    values = _node_with_args(tmp_path, ["--params-file", misspelt], name="panda_bridge", warnings=warnings)
    assert values["rate"] == 100.0
    assert warnings == [f"no section of parameter file {misspelt} applies to /panda_bridge: its keys are "
                        "'panda_bridg' (did you mean '/panda_bridge' for 'panda_bridg'?); the file is "
                        "ignored"]
    # a file for other nodes only is named too, without a guess
    warnings.clear()
    _node_with_args(tmp_path, ["--params-file", _file(tmp_path, "/camera", {"fps": 1})], warnings=warnings)
    assert warnings == [f"no section of parameter file {tmp_path / 'params.yaml'} applies to /t: its keys "
                        "are '/camera'; the file is ignored"]


KEYS = ["/**", "**", "/*", "/arm/*", "/arm/**", "/*/left", "/**/left", "arm/left", "/arm/left", "left",
        "/left", "/**/arm/left", "/arm/*/left", "/*/*", "/other/left", "/arm/lef", "/arm/left/**"]


@pytest.mark.parametrize("fqn", ["/arm/left", "/left", "/a/arm/left"])
def test_section_keys_match_as_rcl_matches_them(tmp_path, fqn):
    """Each key, given to rcl with a parameter of its own: what rcl applies is what key_matches says."""
    keys = [k for k in KEYS if k != "**"]  # rcl's YAML reader refuses a bare ** (an alias)
    path = tmp_path / "keys.yaml"
    path.write_text("".join(f"{k}:\n  ros__parameters:\n    p{i}: 1\n" for i, k in enumerate(keys)))
    ns, _, name = fqn.rpartition("/")
    context = rclpy.context.Context()
    rclpy.init(context=context, args=["prog", "--ros-args", "-r", f"__ns:={ns or '/'}", "-r",
                                      f"__node:={name}", "--params-file", str(path)])
    try:
        node = Node("t", context=context)
        applied = {keys[int(n[1:])] for n in node._parameter_overrides}
        node.destroy_node()
    finally:
        end_context(context)
    assert applied == {k for k in keys if key_matches(k, fqn)}

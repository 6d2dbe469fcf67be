"""Launch file reading: arguments, lets, conditions, groups, includes, node fields and parameters."""

import os
import textwrap

import pytest
from vla_bringup.launch_file import (
    LaunchFileError,
    ParamDict,
    ParamFile,
    declared_arguments,
    load_launch_file,
    normalize_param_value,
)
from vla_bringup.substitutions import SubstitutionContext

PKG_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# executable -> its parameter file in vla_bringup/config (written by each node's owner)
CONFIG_FILES = {
    "panda_bridge": "panda_bridge",
    "detector_node": "detector",
    "controller_node": "controller",
    "recorder_node": "recorder",
}


def write(tmp_path, text, name="t.launch.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


def load(tmp_path, text, **args):
    return load_launch_file(write(tmp_path, text), args)


def test_node_fields(tmp_path):
    (tmp_path / "p.yaml").write_text("/**:\n  ros__parameters:\n    a: 1\n")
    plan = load(
        tmp_path,
        """
        launch:
          - node:
              pkg: vla_bringup
              exec: demo_talker
              name: talker
              namespace: robot
              exec_name: my_talker
              args: "--flag 'two words'"
              ros_args: "--log-level debug"
              param:
                - from: "$(dirname)/p.yaml"
                - name: rate
                  value: 2.5
              remap:
                - from: chatter
                  to: /other
              env:
                - name: FOO
                  value: bar
    """,
    )
    (p,) = plan.processes
    assert (p.pkg, p.executable, p.name, p.namespace, p.label) == (
        "vla_bringup",
        "demo_talker",
        "talker",
        "/robot",
        "my_talker",
    )
    assert p.args == ["--flag", "two words"]
    assert p.ros_args == ["--log-level", "debug"]
    assert p.params == [ParamFile(str(tmp_path / "p.yaml")), ParamDict({"rate": 2.5})]
    assert p.remaps == [("chatter", "/other")]
    assert p.env == {"FOO": "bar"}


def test_arguments_defaults_overrides_required_and_choices(tmp_path):
    text = """
        launch:
          - arg: {name: mode, default: "a", choice: [{value: "a"}, {value: "b"}]}
          - arg: {name: needed}
          - let: {name: both, value: "$(var mode)-$(var needed)"}
          - node: {pkg: p, exec: e, name: "n_$(var mode)", args: "$(var both)"}
    """
    assert load(tmp_path, text, needed="x").processes[0].args == ["a-x"]
    assert load(tmp_path, text, needed="x", mode="b").processes[0].name == "n_b"
    with pytest.raises(LaunchFileError, match="required launch argument 'needed' was not provided"):
        load(tmp_path, text)
    with pytest.raises(LaunchFileError, match=r"valid choices are \['a', 'b'\]"):
        load(tmp_path, text, needed="x", mode="c")
    args = declared_arguments(write(tmp_path, text))
    assert [(a.name, a.default, a.choices) for a in args] == [
        ("mode", "a", ["a", "b"]),
        ("needed", None, None),
    ]


def test_conditions_groups_and_namespaces(tmp_path):
    plan = load(
        tmp_path,
        """
        launch:
          - arg: {name: extra, default: "false"}
          - node: {pkg: p, exec: a, if: "$(var extra)"}
          - node: {pkg: p, exec: b, unless: "$(var extra)"}
          - group:
              - push_ros_namespace: {namespace: arm}
              - let: {name: inner, value: "1"}
              - node: {pkg: p, exec: c, namespace: cam}
              - node: {pkg: p, exec: d, namespace: /abs}
              - node: {pkg: p, exec: e}
          - node: {pkg: p, exec: f, args: "$(optenv NOT_SET_ANYWHERE)"}
    """,
    )
    assert [p.executable for p in plan.processes] == ["b", "c", "d", "e", "f"]
    assert [p.namespace for p in plan.processes] == [None, "/arm/cam", "/abs", "/arm", None]
    with pytest.raises(LaunchFileError, match="'inner' does not exist"):
        load(
            tmp_path,
            """
            launch:
              - group: {children: [{let: {name: inner, value: "1"}}]}
              - node: {pkg: p, exec: a, args: "$(var inner)"}
        """,
        )


def test_include_passes_arguments_and_is_scoped(tmp_path):
    write(
        tmp_path,
        """
        launch:
          - arg: {name: who, default: "nobody"}
          - let: {name: leaked, value: "x"}
          - node: {pkg: p, exec: inc, name: "$(var who)"}
    """,
        name="inner.launch.yaml",
    )
    plan = load(
        tmp_path,
        """
        launch:
          - include:
              file: "$(dirname)/inner.launch.yaml"
              arg: [{name: who, value: "somebody"}]
          - include: {file: inner.launch.yaml}
          - node: {pkg: p, exec: outer, args: "$(optenv X)"}
    """,
    )
    assert [p.name for p in plan.processes[:2]] == ["somebody", "nobody"]
    with pytest.raises(LaunchFileError, match="included file not found"):
        load(tmp_path, "launch:\n  - include: {file: nope.launch.yaml}\n")


@pytest.mark.parametrize(
    "text,expected",
    [
        ("5", 5),
        ("2.5", 2.5),
        ("true", True),
        ("hello", "hello"),
        ("'5'", "5"),
        ("", ""),
        ("[1, 2]", (1, 2)),
        ("[a, b]", ("a", "b")),
        ("{a: 1}", "{a: 1}"),
        ("~/x", "~/x"),
    ],
)
def test_parameter_text_is_read_as_yaml_like_launch_ros(text, expected):
    assert normalize_param_value(text) == expected


def test_parameter_values_and_nesting(tmp_path):
    plan = load(
        tmp_path,
        """
        launch:
          - let: {name: n, value: "3"}
          - node:
              pkg: p
              exec: e
              param:
                - {name: from_var, value: "$(var n)"}
                - {name: quoted, value: "'007'"}
                - {name: floats, value: [1.0, 2.5]}
                - {name: strings, value: ["1", "$(var n)"]}
                - name: group
                  param:
                    - {name: inner, value: false}
    """,
    )
    values = {}
    for p in plan.processes[0].params:
        values.update(p.values)
    assert values == {
        "from_var": 3,
        "quoted": "007",
        "floats": (1.0, 2.5),
        "strings": ("1", "3"),
        "group.inner": False,
    }


@pytest.mark.parametrize(
    "body,err",
    [
        ("- node: {pkg: p, exec: e, nme: x}", r"unsupported attribute\(s\) \['nme'\]"),
        ("- nodes: {pkg: p, exec: e}", "unsupported action 'nodes'"),
        ("- node: {pkg: p}", "missing attribute 'exec'"),
        ("- node: {pkg: p, exec: e, name: 5}", "must be a string"),
        ("- arg: {name: a, default: 1}", "must be a string"),
        ("- node: {pkg: p, exec: e, name: 'bad name'}", "invalid node name"),
        ("- node: {pkg: p, exec: e, if: 'maybe'}", "expected 'true'"),
        ("- node: {pkg: p, exec: e, if: 'true', unless: 'true'}", "mutually exclusive"),
        ("- node: {pkg: p, exec: e, param: [{from: /no/such.yaml}]}", "parameter file not found"),
        ("- node: {pkg: p, exec: e, param: [{name: x, value: [1, 2.0]}]}", "mixes types"),
        ("- node: {pkg: p, exec: e, param: [{name: x}]}", "exactly one of 'value'"),
        ("- node: {pkg: p, exec: e, remap: [{from: a}]}", "exactly 'from' and 'to'"),
        ("- node: {pkg: p, exec: '$(var nope)'}", "'nope' does not exist"),
    ],
)
def test_bad_files_get_clear_errors(tmp_path, body, err):
    with pytest.raises(LaunchFileError, match=err):
        load(tmp_path, "launch:\n  " + body + "\n")


def test_bad_roots_and_formats(tmp_path):
    with pytest.raises(LaunchFileError, match="root must be a single key 'launch'"):
        load(tmp_path, "nodes: []\n")
    with pytest.raises(LaunchFileError, match="invalid YAML"):
        load(tmp_path, "launch: [\n")
    with pytest.raises(LaunchFileError, match="only YAML launch files"):
        load_launch_file(str(tmp_path / "x.launch.py"))


def _stub_ctx(tmp_path):
    """find-pkg-share -> a folder with stub config files, so the shipped files load without them."""
    share = tmp_path / "share"
    (share / "config").mkdir(parents=True, exist_ok=True)
    for name in CONFIG_FILES.values():
        (share / "config" / f"{name}.yaml").write_text("/**:\n  ros__parameters:\n    use_sim_time: false\n")
    return SubstitutionContext(find_share=lambda pkg: str(share))


@pytest.mark.parametrize(
    "name,execs",
    [
        ("sim", ["panda_bridge"]),
        ("teleop", ["panda_bridge", "detector_node", "controller_node"]),
        ("record", ["panda_bridge", "detector_node", "recorder_node"]),
        ("demo", ["demo_talker", "demo_listener"]),
    ],
)
def test_shipped_launch_files(tmp_path, name, execs):
    path = os.path.join(PKG_DIR, "launch", f"{name}.launch.yaml")
    plan = load_launch_file(path, {}, _stub_ctx(tmp_path))
    assert [p.executable for p in plan.processes] == execs
    for p in plan.processes:
        files = [x for x in p.params if isinstance(x, ParamFile)]
        if p.pkg != "vla_bringup":  # our nodes read config/<exec>.yaml first, then the arguments
            assert isinstance(p.params[0], ParamFile) and len(files) == 1
            assert p.params[0].path.endswith(f"config/{CONFIG_FILES[p.executable]}.yaml")
        for d in p.params[1:]:
            assert isinstance(d, ParamDict)
        if p.executable in ("detector_node", "controller_node", "recorder_node"):
            assert {"use_sim_time": False} in [d.values for d in p.params if isinstance(d, ParamDict)]
    for a in declared_arguments(path):
        assert a.description, f"{name}: argument {a.name} has no description"


def test_teleop_arguments_reach_the_nodes(tmp_path):
    path = os.path.join(PKG_DIR, "launch", "teleop.launch.yaml")
    plan = load_launch_file(
        path,
        {"use_sim_time": "true", "detector_model": "/m/d.onnx", "use_joy": "true", "real_time_factor": "4.0"},
        _stub_ctx(tmp_path),
    )
    by_exec = {
        p.executable: {k: v for d in p.params if isinstance(d, ParamDict) for k, v in d.values.items()}
        for p in plan.processes
    }
    assert by_exec["detector_node"] == {"model_path": "/m/d.onnx", "use_sim_time": True}
    assert by_exec["controller_node"]["use_sim_time"] is True
    assert by_exec["panda_bridge"] == {"backend": "mujoco", "real_time_factor": 4.0}
    assert "joy_node" in by_exec
    with pytest.raises(LaunchFileError, match="valid choices"):
        load_launch_file(path, {"backend": "gazebo"}, _stub_ctx(tmp_path))


def test_config_files_are_ros_parameter_files():
    import glob

    import yaml

    files = glob.glob(os.path.join(PKG_DIR, "config", "*.yaml"))
    assert files
    for path in files:
        with open(path) as f:
            data = yaml.safe_load(f)
        assert isinstance(data, dict) and data, path
        for node, body in data.items():
            assert isinstance(body, dict) and set(body) == {"ros__parameters"}, (path, node)
            assert isinstance(body["ros__parameters"], dict), (path, node)


@pytest.mark.parametrize("name", ["sim", "teleop", "record"])
def test_shipped_launch_files_with_the_real_config_files(name):
    """Every parameter file the launch file names exists in config/ (once its owner has written it)."""
    path = os.path.join(PKG_DIR, "launch", f"{name}.launch.yaml")
    src_share = SubstitutionContext(find_share=lambda pkg: PKG_DIR)
    with open(path) as f:
        text = f.read()
    missing = [f"{n}.yaml" for e, n in CONFIG_FILES.items()
               if e in text and not os.path.isfile(os.path.join(PKG_DIR, "config", f"{n}.yaml"))]
    if missing:
        pytest.skip(f"config files not written yet by their owners: {missing}")
    plan = load_launch_file(path, {}, src_share)
    assert all(isinstance(p.params[0], ParamFile) for p in plan.processes)

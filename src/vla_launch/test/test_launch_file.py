"""Launch file reading: arguments, lets, conditions, groups, includes, node fields and parameters."""

import textwrap

import pytest
from vla_launch.launch_file import (
    LaunchFileError,
    ParamDict,
    ParamFile,
    declared_arguments,
    load_launch_file,
    normalize_param_value,
)


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
              pkg: vla_panda_bridge
              exec: panda_bridge
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
        "vla_panda_bridge",
        "panda_bridge",
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




# -- the same file succeeds or fails under vla launch and ros2 launch (issue 32 item 10) ----------------
# Each verdict is launch 3.4's (launch/actions/execute_process.py ExecuteProcess.parse and
# launch_yaml/entity.py Entity.get_attr): `respawn`, `if`, `unless` and `on_exit` are read as strings
# (a YAML boolean: TypeError); `respawn_delay`, `sigterm_timeout` and `sigkill_timeout` as floats that
# may also be strings, and then compared with 0.0 (a string: TypeError; an integer fails the type
# check: TypeError); `respawn` text is coerced as YAML ('1'/'0' too).
ROS2_LAUNCH_VERDICTS = [
    ("respawn: true", "must be a string, got the YAML bool True"),
    ("respawn: 'true'", None),
    ("respawn: 'yes'", None),
    ("respawn: '1'", None),
    ("respawn: '$(var flag)'", None),
    ("respawn: 'sometimes'", "must be true or false"),
    ("respawn_delay: '2.0'", "must be a YAML float such as 2.0, got a string"),
    ("respawn_delay: 2", "must be a YAML float such as 2.0, got the YAML int 2"),
    ("respawn_delay: 2.0", None),
    ("respawn_delay: -1.0", "must be >= 0"),
    ("sigterm_timeout: '3'", "got a string"),
    ("sigkill_timeout: 3", "got the YAML int 3"),
    ("sigterm_timeout: 3.0", None),
    ("if: true", "must be a string, got the YAML bool True"),
    ("unless: false", "must be a string, got the YAML bool False"),
    ("if: '$(var flag)'", None),
    ("on_exit: '$(var how)'", "on_exit supports only 'shutdown'"),
]


@pytest.mark.parametrize("attr, refusal", ROS2_LAUNCH_VERDICTS, ids=[v[0] for v in ROS2_LAUNCH_VERDICTS])
def test_process_attributes_are_taken_or_refused_as_ros2_launch_does(tmp_path, attr, refusal):
    text = ("launch:\n  - arg: {name: flag, default: 'true'}\n  - arg: {name: how, default: shutdown}\n"
            f"  - executable: {{cmd: /bin/true, {attr}}}\n")
    if refusal is None:
        proc = load(tmp_path, text).processes[0]
        assert proc.respawn == attr.startswith("respawn:")
    else:
        with pytest.raises(LaunchFileError, match=refusal):
            load(tmp_path, text)

"""Reading ROS 2 YAML launch files (the launch_ros frontend format) into a list of processes to start.

Supported actions: `arg`, `let`, `node`, `executable`, `include` (YAML files), `group` (scoped),
`push_ros_namespace`, `set_env`, `unset_env`, `log`; `if`/`unless` on every action. Attribute types
follow launch's YAML frontend strictly (text attributes must be YAML strings), so a file accepted here
is also accepted by `ros2 launch`. Parameter values follow launch_ros: a text value is read as YAML
after substitution (`'5'` is an int, `"'5'"` a string), list items stay as written.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import yaml

from vla_launch.substitutions import (
    SubstitutionContext,
    SubstitutionError,
    as_condition,
    split_command_line,
    substitute,
)


class LaunchFileError(ValueError):
    """A launch file that cannot be read; the message names the file, the action and the reason."""


@dataclass
class ParamFile:
    """`param: [{from: path}]`: a ROS parameters YAML file, passed with --params-file."""

    path: str


@dataclass
class ParamDict:
    """Inline parameters of one `param` entry: flat dotted names -> typed values."""

    values: dict[str, Any]


@dataclass
class LaunchArgument:
    name: str
    default: str | None = None
    description: str = ""
    choices: list[str] | None = None


@dataclass
class ProcessDescription:
    """One process to start, with every substitution already evaluated."""

    label: str  # how harnesses name the process: exec_name, node name, or executable basename
    executable: str  # executable name inside `pkg`, or a command/path when pkg is None
    exec_name: str | None = None  # the output tag's stem, as ros2 launch (None: the label)
    pkg: str | None = None
    is_node: bool = True
    name: str | None = None
    namespace: str | None = None  # absolute
    params: list[ParamFile | ParamDict] = field(default_factory=list)
    remaps: list[tuple[str, str]] = field(default_factory=list)
    ros_args: list[str] = field(default_factory=list)
    args: list[str] = field(default_factory=list)
    env: dict[str, str | None] = field(default_factory=dict)  # None: unset
    cwd: str | None = None
    launch_prefix: list[str] = field(default_factory=list)
    output: str = "screen"
    on_exit_shutdown: bool = False
    respawn: bool = False
    respawn_delay: float = 0.0
    sigterm_timeout: float | None = None
    sigkill_timeout: float | None = None
    source: str = ""


@dataclass
class LaunchPlan:
    processes: list[ProcessDescription] = field(default_factory=list)
    arguments: list[LaunchArgument] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    temp_files: list[str] = field(default_factory=list)  # the caller deletes them when done


_COMMON = {"if", "unless"}
_PROCESS_ATTRS = _COMMON | {
    "cwd", "env", "output", "launch-prefix", "on_exit", "respawn", "respawn_delay", "sigterm_timeout",
    "sigkill_timeout", "emulate_tty", "name", "args",
}
_ALLOWED = {
    "arg": _COMMON | {"name", "default", "description", "choice"},
    "let": _COMMON | {"name", "value"},
    "node": _PROCESS_ATTRS | {"pkg", "exec", "exec_name", "namespace", "param", "remap", "ros_args"},
    "executable": _PROCESS_ATTRS | {"cmd"},
    "include": _COMMON | {"file", "arg"},
    "group": _COMMON | {"scoped", "forwarding", "children"},
    "push_ros_namespace": _COMMON | {"namespace"},
    "set_env": _COMMON | {"name", "value"},
    "unset_env": _COMMON | {"name"},
    "log": _COMMON | {"message"},
}
_ALIASES = {"push-ros-namespace": "push_ros_namespace", "set-env": "set_env", "unset-env": "unset_env"}


# ---------------------------------------------------------------------------------------- helpers
class _Entity:
    """One action's attributes, with typed, strict access and a location for error messages."""

    def __init__(self, kind: str, attrs: Any, where: str) -> None:
        self.kind, self.attrs, self.where = kind, attrs, where

    def fail(self, msg: str) -> LaunchFileError:
        return LaunchFileError(f"{self.where}: {self.kind}: {msg}")

    def check_known(self) -> None:
        if not isinstance(self.attrs, dict):
            raise self.fail(f"expected a mapping of attributes, got {type(self.attrs).__name__}")
        unknown = sorted(set(self.attrs) - _ALLOWED[self.kind])
        if unknown:
            raise self.fail(f"unsupported attribute(s) {unknown}; allowed: {sorted(_ALLOWED[self.kind])}")
        if "if" in self.attrs and "unless" in self.attrs:
            raise self.fail("'if' and 'unless' are mutually exclusive")

    def text(self, name: str, required: bool = False) -> str | None:
        if name not in self.attrs:
            if required:
                raise self.fail(f"missing attribute '{name}'")
            return None
        v = self.attrs[name]
        if not isinstance(v, str):
            raise self.fail(f"attribute '{name}' must be a string (quote it in YAML), got {v!r}")
        return v

    def flag(self, name: str) -> str | None:
        """A boolean attribute (`if`, `unless`, `respawn`): text, substitutions allowed. launch 3.4 reads
        these as strings and refuses a YAML boolean with a TypeError, so a file that ros2 launch
        refuses is refused here too."""
        v = self.attrs.get(name)
        if v is None or isinstance(v, str):
            return v
        raise self.fail(f"attribute '{name}' must be a string, got the YAML {type(v).__name__} {v!r} "
                        f"(ros2 launch refuses it with a TypeError): write {name}: \"{str(v).lower()}\"")

    def entities(self, name: str) -> list[dict]:
        v = self.attrs.get(name)
        if v is None:
            return []
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise self.fail(f"attribute '{name}' must be a list of mappings")
        return v


def _sub(ent: _Entity, text: str | None, ctx: SubstitutionContext) -> str | None:
    if text is None:
        return None
    try:
        return substitute(text, ctx)
    except SubstitutionError as e:
        raise ent.fail(str(e)) from e


def _split(ent: _Entity, text: str | None, ctx: SubstitutionContext) -> list[str]:
    if text is None:
        return []
    try:
        return split_command_line(text, ctx)
    except SubstitutionError as e:
        raise ent.fail(str(e)) from e


def _float(ent: _Entity, name: str) -> float | None:
    """A time attribute (`respawn_delay`, `sigterm_timeout`, `sigkill_timeout`) as launch 3.4's YAML
    frontend takes it: a YAML float and nothing else. An integer fails its type check and a string its
    comparison with 0.0, both with a TypeError, so no substitution either."""
    v = ent.attrs.get(name)
    if v is None:
        return None
    if not isinstance(v, float):
        what = "a string" if isinstance(v, str) else f"the YAML {type(v).__name__} {v!r}"
        raise ent.fail(f"attribute '{name}' must be a YAML float such as 2.0, got {what} (ros2 launch "
                       "refuses it with a TypeError)")
    if not v >= 0.0:
        raise ent.fail(f"attribute '{name}' must be >= 0, got {v!r}")
    return v


def _bool(ent: _Entity, name: str, ctx: SubstitutionContext) -> bool | None:
    """A boolean process attribute as launch evaluates it (type_utils.coerce_to_type): '1' and '0',
    or what YAML reads as a boolean (true, False, yes, off ...)."""
    v = _sub(ent, ent.flag(name), ctx)
    if v is None:
        return None
    text = {"1": "true", "0": "false"}.get(v, v)
    try:
        value = yaml.safe_load(text) if text else text
    except yaml.YAMLError:
        value = None
    if not isinstance(value, bool):
        raise ent.fail(f"attribute '{name}' must be true or false (or 1, 0), got {v!r}")
    return value


def _condition_ok(ent: _Entity, ctx: SubstitutionContext) -> bool:
    for key, want in (("if", True), ("unless", False)):
        v = ent.flag(key)
        if v is not None:
            try:
                if as_condition(substitute(v, ctx), f"'{key}' condition") != want:
                    return False
            except SubstitutionError as e:
                raise ent.fail(str(e)) from e
    return True


def prefix_namespace(base: str | None, ns: str | None) -> str | None:
    """launch_ros semantics: a relative namespace is appended to the pushed one."""
    if base is None:
        return ns
    if ns is None:
        return base
    if ns.startswith("/"):
        return ns
    return base.rstrip("/") + "/" + ns


def make_namespace_absolute(ns: str | None) -> str | None:
    if ns is None:
        return None
    ns = ns if ns.startswith("/") else "/" + ns
    return ns.rstrip("/") or "/"


def _valid_token(s: str) -> bool:
    return bool(s) and (s[0].isalpha() or s[0] == "_") and all(c.isalnum() or c == "_" for c in s)


def _check_name(ent: _Entity, name: str) -> None:
    if not _valid_token(name):
        raise ent.fail(f"invalid node name {name!r} (letters, digits and '_'; not starting with a digit)")


def _check_namespace(ent: _Entity, ns: str) -> None:
    if ns != "/" and not all(_valid_token(t) for t in ns[1:].split("/")):
        raise ent.fail(f"invalid namespace {ns!r}")


# ------------------------------------------------------------------------------------- parameters
_SCALARS = (bool, int, float, str)


def normalize_param_value(text: str) -> Any:
    """A text parameter value after substitution, read as YAML the way launch_ros does.

    '5' -> 5, 'true' -> True, '[1, 2]' -> (1, 2), "'5'" -> '5'; anything else stays text.
    """
    try:
        v = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(v, _SCALARS):
        return v
    if isinstance(v, list) and v and all(isinstance(x, _SCALARS) for x in v):
        if len({type(x) for x in v}) > 1:
            raise ValueError(f"list parameter {text!r} mixes types; ROS arrays must be uniform")
        return tuple(v)
    return text


def _param_value(ent: _Entity, name: str, value: Any, ctx: SubstitutionContext) -> Any:
    if isinstance(value, str):
        try:
            return normalize_param_value(substitute(value, ctx))
        except (SubstitutionError, ValueError) as e:
            raise ent.fail(f"param '{name}': {e}") from e
    if isinstance(value, _SCALARS):
        return value
    if isinstance(value, list):
        if not value:
            raise ent.fail(f"param '{name}': empty lists have no ROS type; leave the parameter out")
        if not all(isinstance(x, _SCALARS) for x in value):
            raise ent.fail(f"param '{name}': list items must be scalars")
        if len({type(x) for x in value}) > 1:
            raise ent.fail(f"param '{name}': list mixes types {sorted({type(x).__name__ for x in value})}; "
                           "ROS arrays must be uniform (write 1.0 rather than 1 in a float list)")
        try:
            return tuple(substitute(x, ctx) if isinstance(x, str) else x for x in value)
        except SubstitutionError as e:
            raise ent.fail(f"param '{name}': {e}") from e
    raise ent.fail(f"param '{name}': unsupported value {value!r}")


def _nested_params(ent: _Entity, entries: list[dict], prefix: str, ctx: SubstitutionContext,
                   out: dict[str, Any]) -> None:
    for p in entries:
        pe = _Entity("param", p, ent.where)
        unknown = sorted(set(p) - {"name", "value", "param"})
        if unknown:
            raise pe.fail(f"unsupported attribute(s) {unknown} in a named parameter")
        name = _sub(pe, pe.text("name", required=True), ctx)
        full = f"{prefix}.{name}" if prefix else name
        if ("value" in p) == ("param" in p):
            raise pe.fail(f"param '{full}' needs exactly one of 'value' or nested 'param'")
        if "param" in p:
            _nested_params(pe, pe.entities("param"), full, ctx, out)
        else:
            out[full] = _param_value(pe, full, p["value"], ctx)


def _parse_params(ent: _Entity, ctx: SubstitutionContext, base_dir: str,
                  temp_files: list[str]) -> list[ParamFile | ParamDict]:
    result: list[ParamFile | ParamDict] = []
    for p in ent.entities("param"):
        pe = _Entity("param", p, ent.where)
        if "from" in p:
            unknown = sorted(set(p) - {"from", "allow_substs"})
            if unknown:
                raise pe.fail(f"'from' takes no other attribute than allow_substs, got {unknown}")
            path = _sub(pe, pe.text("from"), ctx)
            path = path if os.path.isabs(path) else os.path.join(base_dir, path)
            if not os.path.isfile(path):
                raise pe.fail(f"parameter file not found: {path}")
            if _bool(pe, "allow_substs", ctx):
                result.append(ParamFile(_substituted_param_file(pe, path, ctx, temp_files)))
            else:
                result.append(ParamFile(path))
        elif "name" in p:
            values: dict[str, Any] = {}
            _nested_params(ent, [p], "", ctx, values)
            result.append(ParamDict(values))
        else:
            raise pe.fail("a param entry needs 'name' (with 'value') or 'from'")
    return result


def _substituted_param_file(ent: _Entity, path: str, ctx: SubstitutionContext, temp_files: list[str]) -> str:
    """allow_substs: the file's text goes through substitutions, into a file of its own."""
    import tempfile

    with open(path, encoding="utf-8") as f:
        text = _sub(ent, f.read(), ctx)
    fd, out = tempfile.mkstemp(prefix="vla_launch_params_", suffix=".yaml")
    temp_files.append(out)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    return out


# ----------------------------------------------------------------------------------------- loader
@dataclass
class _State:
    ctx: SubstitutionContext
    env: dict[str, str | None]
    base_dir: str
    depth: int = 0


class LaunchFileLoader:
    """Executes the declarative part of a launch file: arguments, lets, conditions, includes."""

    def __init__(self, plan: LaunchPlan | None = None) -> None:
        self.plan = plan or LaunchPlan()

    # entry point
    def load(self, path: str, arguments: dict[str, str] | None = None,
             ctx: SubstitutionContext | None = None) -> LaunchPlan:
        ctx = ctx or SubstitutionContext()
        ctx.configurations.update(arguments or {})
        self._load_file(path, _State(ctx, {}, os.path.dirname(os.path.abspath(path))), top=True)
        return self.plan

    def _load_file(self, path: str, st: _State, top: bool = False) -> None:
        actions = read_launch_yaml(path)
        st.ctx.current_file = os.path.abspath(path)
        st.base_dir = os.path.dirname(os.path.abspath(path))
        self._run_actions(actions, st, path, top)

    def _run_actions(self, actions: list, st: _State, path: str, top: bool) -> None:
        for i, item in enumerate(actions):
            where = f"{path}: action {i + 1}"
            if not isinstance(item, dict) or len(item) != 1:
                raise LaunchFileError(f"{where}: each action must be a one-key mapping "
                                      "like '- node: {...}'")
            (kind, attrs), = item.items()
            kind = _ALIASES.get(kind, kind)
            if kind not in _ALLOWED:
                raise LaunchFileError(f"{where}: unsupported action '{kind}'; supported: {sorted(_ALLOWED)}")
            if kind == "group" and isinstance(attrs, list):
                attrs = {"children": attrs}
            ent = _Entity(kind, attrs, where)
            ent.check_known()
            if not _condition_ok(ent, st.ctx):
                continue
            getattr(self, f"_do_{kind}")(ent, st, top)

    # actions
    def _do_arg(self, ent: _Entity, st: _State, top: bool) -> None:
        name = ent.text("name", required=True)
        default = ent.text("default")
        choices = None
        if "choice" in ent.attrs:
            choices = [_Entity("choice", c, ent.where).text("value", required=True)
                       for c in ent.entities("choice")]
        if top:
            self.plan.arguments.append(LaunchArgument(name, default, ent.text("description") or "", choices))
        if name not in st.ctx.configurations:
            if default is None:
                raise ent.fail(f"required launch argument '{name}' was not provided (pass {name}:=<value>)")
            st.ctx.configurations[name] = _sub(ent, default, st.ctx)
        value = st.ctx.configurations[name]
        if choices is not None and value not in choices:
            raise ent.fail(f"argument '{name}' got {value!r}; valid choices are {choices}")

    def _do_let(self, ent: _Entity, st: _State, top: bool) -> None:
        name = ent.text("name", required=True)
        st.ctx.configurations[name] = _sub(ent, ent.text("value", required=True), st.ctx)

    def _do_set_env(self, ent: _Entity, st: _State, top: bool) -> None:
        st.env[_sub(ent, ent.text("name", required=True), st.ctx)] = _sub(
            ent, ent.text("value", required=True), st.ctx)

    def _do_unset_env(self, ent: _Entity, st: _State, top: bool) -> None:
        st.env[_sub(ent, ent.text("name", required=True), st.ctx)] = None

    def _do_log(self, ent: _Entity, st: _State, top: bool) -> None:
        self.plan.messages.append(_sub(ent, ent.text("message", required=True), st.ctx))

    def _do_push_ros_namespace(self, ent: _Entity, st: _State, top: bool) -> None:
        ns = _sub(ent, ent.text("namespace", required=True), st.ctx)
        prev = st.ctx.configurations.get("ros_namespace")
        st.ctx.configurations["ros_namespace"] = make_namespace_absolute(prefix_namespace(prev, ns))

    def _do_group(self, ent: _Entity, st: _State, top: bool) -> None:
        children = ent.attrs.get("children")
        if not isinstance(children, list):
            raise ent.fail("a group needs a list of actions (directly or under 'children')")
        scoped = _bool(ent, "scoped", st.ctx)
        if scoped is False:
            self._run_actions(children, st, ent.where, top)
        else:
            scope = _State(st.ctx.child(), dict(st.env), st.base_dir, st.depth)
            self._run_actions(children, scope, ent.where, top)

    def _do_include(self, ent: _Entity, st: _State, top: bool) -> None:
        if st.depth >= 20:
            raise ent.fail("includes nested more than 20 deep (an include loop?)")
        path = _sub(ent, ent.text("file", required=True), st.ctx)
        path = path if os.path.isabs(path) else os.path.join(st.base_dir, path)
        if not os.path.isfile(path):
            raise ent.fail(f"included file not found: {path}")
        child = _State(st.ctx.child(), dict(st.env), st.base_dir, st.depth + 1)
        for a in ent.entities("arg"):
            ae = _Entity("arg", a, ent.where)
            child.ctx.configurations[ae.text("name", required=True)] = _sub(
                ae, ae.text("value", required=True), st.ctx)
        self._load_file(path, child)

    def _do_node(self, ent: _Entity, st: _State, top: bool) -> None:
        ctx = st.ctx
        pkg = _sub(ent, ent.text("pkg"), ctx)
        exe = _sub(ent, ent.text("exec", required=True), ctx)
        name = _sub(ent, ent.text("name"), ctx)
        if name is not None:
            _check_name(ent, name)
        ns = make_namespace_absolute(prefix_namespace(ctx.configurations.get("ros_namespace"),
                                                      _sub(ent, ent.text("namespace"), ctx)))
        if ns is not None:
            _check_namespace(ent, ns)
        remaps = []
        for r in ent.entities("remap"):
            re_ = _Entity("remap", r, ent.where)
            if set(r) != {"from", "to"}:
                raise re_.fail("a remap needs exactly 'from' and 'to'")
            remaps.append((_sub(re_, re_.text("from"), ctx), _sub(re_, re_.text("to"), ctx)))
        exec_name = _sub(ent, ent.text("exec_name"), ctx)
        proc = ProcessDescription(
            label=exec_name or name or os.path.basename(exe), executable=exe, pkg=pkg, is_node=True,
            exec_name=exec_name or os.path.basename(exe), name=name, namespace=ns,
            params=_parse_params(ent, ctx, st.base_dir, self.plan.temp_files), remaps=remaps,
            ros_args=_split(ent, ent.text("ros_args"), ctx), args=_split(ent, ent.text("args"), ctx))
        self._process_common(ent, st, proc)

    def _do_executable(self, ent: _Entity, st: _State, top: bool) -> None:
        cmd = _split(ent, ent.text("cmd", required=True), st.ctx)
        if not cmd:
            raise ent.fail("empty 'cmd'")
        label = _sub(ent, ent.text("name"), st.ctx) or os.path.basename(cmd[0])
        proc = ProcessDescription(label=label, executable=cmd[0], is_node=False,
                                  args=cmd[1:] + _split(ent, ent.text("args"), st.ctx))
        self._process_common(ent, st, proc)

    def _process_common(self, ent: _Entity, st: _State, proc: ProcessDescription) -> None:
        ctx = st.ctx
        proc.env = dict(st.env)
        for e in ent.entities("env"):
            ee = _Entity("env", e, ent.where)
            key = _sub(ee, ee.text("name", required=True), ctx)
            proc.env[key] = _sub(ee, ee.text("value", required=True), ctx)
        cwd = _sub(ent, ent.text("cwd"), ctx)
        proc.cwd = None if cwd is None else os.path.expanduser(cwd)
        proc.launch_prefix = _split(ent, ent.text("launch-prefix"), ctx)
        proc.output = _sub(ent, ent.text("output"), ctx) or "screen"
        on_exit = ent.text("on_exit")  # launch compares the text as written, without substitutions
        if on_exit not in (None, "shutdown"):
            raise ent.fail(f"on_exit supports only 'shutdown', got {on_exit!r}")
        proc.on_exit_shutdown = on_exit == "shutdown"
        proc.respawn = bool(_bool(ent, "respawn", ctx))
        proc.respawn_delay = _float(ent, "respawn_delay") or 0.0
        proc.sigterm_timeout = _float(ent, "sigterm_timeout")
        proc.sigkill_timeout = _float(ent, "sigkill_timeout")
        proc.source = ent.where
        self.plan.processes.append(proc)


def read_launch_yaml(path: str) -> list:
    """The action list of a YAML launch file (`launch:` at the root), with clear errors."""
    if not path.endswith((".yaml", ".yml")):
        raise LaunchFileError(f"{path}: only YAML launch files (*.launch.yaml) are supported here")
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except OSError as e:
        raise LaunchFileError(f"{path}: cannot read: {e.strerror}") from e
    except yaml.YAMLError as e:
        raise LaunchFileError(f"{path}: invalid YAML: {e}") from e
    if not isinstance(data, dict) or set(data) != {"launch"} or not isinstance(data["launch"], list):
        raise LaunchFileError(f"{path}: the root must be a single key 'launch' holding a list of actions")
    return data["launch"]


def declared_arguments(path: str) -> list[LaunchArgument]:
    """The `arg` actions of a file (top level and groups), without evaluating anything."""
    found: list[LaunchArgument] = []

    def walk(actions: list) -> None:
        for item in actions:
            if not isinstance(item, dict) or len(item) != 1:
                continue
            (kind, attrs), = item.items()
            if kind == "arg" and isinstance(attrs, dict) and isinstance(attrs.get("name"), str):
                choices = [c.get("value") for c in attrs.get("choice") or [] if isinstance(c, dict)]
                found.append(LaunchArgument(attrs["name"], attrs.get("default"),
                                            attrs.get("description") or "", choices or None))
            elif kind == "group":
                children = attrs if isinstance(attrs, list) else (attrs or {}).get("children")
                if isinstance(children, list):
                    walk(children)

    walk(read_launch_yaml(path))
    return found


def load_launch_file(path: str, arguments: dict[str, str] | None = None,
                     ctx: SubstitutionContext | None = None) -> LaunchPlan:
    """Evaluate a launch file with `name:=value` arguments into the processes it starts."""
    return LaunchFileLoader().load(path, arguments, ctx)

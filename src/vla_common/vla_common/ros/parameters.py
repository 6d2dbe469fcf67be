"""The parameter table: a node's parameters declared from one list, like moveit_servo's generated
parameters. Each entry gives the default, a description, a numeric range or a list of choices, and
whether it may change at run time. `ParameterTable.declare(node)`:

- declares every parameter with its descriptor (ranges as descriptor ranges, so `ros2 param describe`
  shows them and rclpy refuses values outside; choices in `additional_constraints`; read-only where
  the entry is not `dynamic`), so the node loads `/**` YAML files and `-p name:=value` overrides;
- accepts an integer for a floating-point parameter (`state_rate: 500` in YAML), and a form an entry's
  `convert` turns into its own (an older file's list for a string), at startup and at run time;
- refuses to start (`ConfigError`, exit code 2) on a parameter the node does not declare, from a
  parameter file or `-p`, naming the closest declared one: `velocity_scal: 0.3` must not leave
  `velocity_scale` at 1.0 without a word. The names checked are the overrides rcl gave this node
  (its `/**` and its own fully qualified name's sections, after renaming and namespacing), so a
  file's section for another node is not this node's concern;
- refuses, at startup with `ConfigError` and at run time with a reason, a value outside the choices
  or one the entry's `check` rejects;
- hands each accepted run-time change to the node's `on_change(name, value)`, which either applies
  it or returns a reason to refuse it. A parameter is therefore always either applied or refused.
  In a batch (`set_parameters_atomically`) every value is checked first; a node that refuses one
  in `on_change` keeps the ones before it applied, so nodes apply batches one parameter at a time.
  An exception in `on_change` refuses the change (its type in the reason, the traceback in the
  node's log): a parameter set by any DDS peer never takes the node down.
"""

from __future__ import annotations

import difflib
import math
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from vla_common.priority import INPUT_PRIORITY, MAX_PRIORITY
from vla_common.ros.node_main import ConfigError
from vla_common.ros.parameter_sources import Sources, arguments_of, closest_key, sources_for

_ARRAY_TYPES = {
    "double_array": (ParameterType.PARAMETER_DOUBLE_ARRAY, Parameter.Type.DOUBLE_ARRAY),
    "string_array": (ParameterType.PARAMETER_STRING_ARRAY, Parameter.Type.STRING_ARRAY),
    "integer_array": (ParameterType.PARAMETER_INTEGER_ARRAY, Parameter.Type.INTEGER_ARRAY),
}


@dataclass(frozen=True)
class Param:
    """One parameter. `range` is inclusive; `choices` limits a string; `check(value)` returns a reason
    to refuse (or None); `dynamic` parameters may change at run time, the others are read-only;
    `array` names the element type of a list parameter whose default is empty."""

    name: str
    default: Any
    description: str
    range: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    dynamic: bool = False
    check: Callable[[Any], str | None] | None = None
    array: str | None = None  # "double_array" | "string_array" | "integer_array"
    convert: Callable[[Any], Any] | None = None  # an older form of the value -> the declared one

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(description=self.description, read_only=not self.dynamic)
        if self.choices:
            d.additional_constraints = "one of: " + ", ".join(self.choices)
        if self.range is not None:
            lo, hi = self.range
            if isinstance(self.default, float):
                d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi))]
            elif isinstance(self.default, int) and not isinstance(self.default, bool):
                d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        if self.array is not None:
            d.type = _ARRAY_TYPES[self.array][0]
        return d

    def coerced(self, given: Parameter) -> Parameter:
        """`given` as this parameter's type where it has a form that converts: an integer for a
        double, or what `convert` turns into the declared form; otherwise `given` itself."""
        if isinstance(self.default, float) and given.type_ == Parameter.Type.INTEGER:
            return Parameter(self.name, Parameter.Type.DOUBLE, float(given.value))
        if self.convert is not None and given.type_ != Parameter.Type.NOT_SET:
            value = self.convert(given.value)
            if value is not given.value:
                return Parameter(self.name, value=value)
        return given

    def refusal(self, value: Any) -> str | None:
        """Why `value` is refused, or None (the range is rclpy's to check)."""
        if self.choices is not None and value not in self.choices:
            return f"parameter '{self.name}' must be one of {list(self.choices)}, got {value!r}"
        if isinstance(value, float) and not math.isfinite(value):
            return f"parameter '{self.name}' must be finite, got {value!r}"
        if self.check is not None:
            reason = self.check(value)
            if reason:
                return f"parameter '{self.name}': {reason}"
        return None


class ParameterTable:
    """A node's parameters, declared and guarded from one list of `Param`."""

    def __init__(self, params: Sequence[Param]):
        self.params = {p.name: p for p in params}
        if len(self.params) != len(params):
            raise ValueError("parameter table with a name twice")

    def __iter__(self):
        return iter(self.params.values())

    def declare(self, node: Node,
                on_change: Callable[[str, Any], str | None] | None = None) -> dict[str, Any]:
        """Declare every parameter on `node` and return their values; ConfigError names the first
        refused one. Run-time changes go through the choices/checks, then `on_change`."""
        overrides = getattr(node, "_parameter_overrides", {})
        values: dict[str, Any] = {}
        for p in self.params.values():
            if p.name in overrides:
                overrides[p.name] = p.coerced(overrides[p.name])
            try:
                value = self._declare_one(node, p)
            except Exception as exc:  # out of range or of the wrong type: refuse clearly
                raise ConfigError(f"parameter '{p.name}': {exc}") from exc
            reason = p.refusal(value)
            if reason:
                raise ConfigError(reason)
            values[p.name] = value
        self._refuse_undeclared(node, overrides)
        logger = node.get_logger()
        node.add_pre_set_parameters_callback(self._coerced)
        node.add_on_set_parameters_callback(lambda changes: self._on_set(changes, on_change, logger))
        return values

    def _coerced(self, changes: list[Parameter]) -> list[Parameter]:
        return [self.params[c.name].coerced(c) if c.name in self.params else c for c in changes]

    @staticmethod
    def _refuse_undeclared(node: Node, overrides: dict[str, Parameter]) -> None:
        """ConfigError for an override meant for this node that names none of its parameters (ours, or
        rclpy's own such as use_sim_time); a warning for one given only under a shared section (`/**`),
        which may be another node's, and for a parameter file none of whose sections applies."""
        fqn = node.get_fully_qualified_name()
        argv = arguments_of(node.context)
        sources = sources_for(fqn, argv) if argv is not None else Sources((), ())
        logger = node.get_logger()
        for path, keys in sources.unmatched_files:
            close = closest_key(keys, fqn)
            hint = f" (did you mean '{fqn}' for '{close}'?)" if close else ""
            logger.warning(f"no section of parameter file {path} applies to {fqn}: its keys are "
                           f"{', '.join(repr(k) for k in keys) or 'none'}{hint}; the file is ignored")
        unknown = sorted(n for n in overrides if not node.has_parameter(n))
        if not unknown:
            return
        declared = sorted(node.list_parameters([], 0).names)
        refused = []
        for name in unknown:
            given = [s for s in sources.sections if name in s.names]
            if given and all(s.shared for s in given):
                logger.warning(f"parameter '{name}' given {given[-1].where()} is not a parameter of {fqn}"
                               f"{_did_you_mean(name, declared)}: ignored (a shared section may name "
                               "other nodes' parameters)")
            else:
                refused.append(name)
        if not refused:
            return
        hints = [f"'{name}'{_did_you_mean(name, declared)}" for name in refused]
        unmatched = any(not _did_you_mean(name, declared) for name in refused)
        known = f"; its parameters are {', '.join(declared)}" if unmatched else ""
        raise ConfigError(f"{fqn} has no parameter {', '.join(hints)} (given in "
                          f"a parameter file or with -p; refused rather than ignored){known}")

    @staticmethod
    def _declare_one(node: Node, p: Param) -> Any:
        """Declare `p`; an array whose default is empty is declared by type and then set to [] (rclpy
        cannot infer a type from []), so get_parameter() works whether or not a value was given."""
        if p.array is None or p.default:
            return node.declare_parameter(p.name, p.default, p.descriptor()).value
        rcl_type = _ARRAY_TYPES[p.array][1]
        writable = p.descriptor()
        writable.read_only = False
        value = node.declare_parameter(p.name, rcl_type, writable).value
        if value is None:
            node.set_parameters([Parameter(p.name, rcl_type, [])])
            value = []
        if not p.dynamic:
            node.set_descriptor(p.name, p.descriptor())
        return value

    def _on_set(self, changes: list[Parameter], on_change: Callable[[str, Any], str | None] | None,
                node_logger) -> SetParametersResult:
        ours = [(self.params[c.name], c) for c in changes if c.name in self.params]  # not use_sim_time
        for p, change in ours:  # every value checked before any is applied
            reason = p.refusal(change.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        for p, change in ours:
            try:
                reason = on_change(p.name, change.value) if on_change is not None else None
            except Exception as exc:  # a defect in the node must not take it down: refuse, say so
                node_logger.error(f"parameter '{p.name}': {type(exc).__name__} while applying it:\n"
                                  f"{traceback.format_exc()}")
                reason = (f"parameter '{p.name}' could not be applied ({type(exc).__name__}); the node "
                          "keeps the previous value")
            if reason:  # the node refused it; the changes before it in this batch stay applied
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)


def _did_you_mean(name: str, declared: list[str]) -> str:
    close = difflib.get_close_matches(name, declared, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


# The nodes on the operator's path (station, joystick, controller, bridge) declare this; `run_node`
# applies it once the node is built (vla_common.priority.run_realtime says why it is real time).
# Off by default: a graph that runs beside other work (tests, evaluations) keeps normal scheduling;
# the person's PC sets it (teleop.launch.yaml's thread_priority, e.g. INPUT_PRIORITY).
THREAD_PRIORITY = Param(
    "thread_priority", 0,
    f"SCHED_FIFO priority of this node's threads, the operator's input and the arm's commands first "
    f"(0: normal scheduling; e.g. {INPUT_PRIORITY}). Needs root, CAP_SYS_NICE or an rtprio limit; "
    "without, normal priority and one warning", range=(0, MAX_PRIORITY))

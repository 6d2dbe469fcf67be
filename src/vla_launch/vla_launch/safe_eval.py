"""A small, safe expression evaluator for `$(eval ...)`.

ROS 2 launch hands `$(eval)` to Python's `eval`; a launch file is then arbitrary code. Here only
literals, arithmetic, comparisons, boolean logic, `x if c else y`, `in`, indexing and a few pure
builtins are allowed; names, attributes, lambdas and comprehensions are refused. Every
intermediate result is bounded before it is built, so that `9**9**9`, `'a' * 10**12`,
`str([[0]*90000]*90000)` or `'%900000000d' % 1` fail at once instead of eating the machine: a value's
size counts every element of nested lists (shared ones each time they appear, as str() would print
them), %-format widths and precisions are checked before formatting, and the nesting depth of the
expression is bounded (no RecursionError).
"""
from __future__ import annotations

import ast
import math
import operator
import re

_MAX_EXPONENT = 1024
_MAX_LEN = 100_000       # elements (or characters) in any value, nested lists counted in full
_MAX_DEPTH = 64          # nesting of the expression
_FORMAT_FIELD = re.compile(r"%[-+ #0]*(\*|\d+)?(?:\.(\*|\d+))?")

_BINOPS = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.Pow: operator.pow,
}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg, ast.Not: operator.not_}
_COMPARE = {
    ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
    ast.Gt: operator.gt, ast.GtE: operator.ge, ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
}
_FUNCTIONS = {
    "abs": abs, "min": min, "max": max, "round": round, "int": int, "float": float, "str": str,
    "bool": bool, "len": len,
    "sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "tan": math.tan, "atan2": math.atan2,
    "radians": math.radians, "degrees": math.degrees,
}
_CONSTANTS = {"pi": math.pi, "e": math.e, "True": True, "False": False, "None": None,
              "true": True, "false": False}


class SafeEvalError(ValueError):
    """The expression uses something not allowed, or fails to evaluate."""


def _size(value: object, budget: int = _MAX_LEN) -> int:
    """Elements in `value`, nested sequences counted in full; stops early once past `budget`."""
    if isinstance(value, str):
        return len(value)
    if not isinstance(value, (list, tuple)):
        return 1
    total = len(value)
    for item in value:
        if total > budget:
            break
        if isinstance(item, (str, list, tuple)):
            total += _size(item, budget - total)
    return total


def _check_size(value: object) -> object:
    if isinstance(value, (str, list, tuple)) and _size(value) > _MAX_LEN:
        raise SafeEvalError(f"result larger than {_MAX_LEN} elements")
    return value


def _check_format(template: str) -> None:
    """A %-format may not ask for a field wider or more precise than the size bound (nor `*`)."""
    for width, precision in _FORMAT_FIELD.findall(template):
        for n in (width, precision):
            if n == "*" or (n and int(n) > _MAX_LEN):
                raise SafeEvalError(f"format field {n!r} too large (at most {_MAX_LEN})")


def _eval(node: ast.AST, depth: int = 0) -> object:
    if depth > _MAX_DEPTH:
        raise SafeEvalError(f"expression nested deeper than {_MAX_DEPTH}")
    depth += 1
    if isinstance(node, ast.Expression):
        return _eval(node.body, depth)
    if isinstance(node, ast.Constant):
        if isinstance(node.value, (int, float, str, bool, type(None))):
            return node.value
        raise SafeEvalError(f"constant {node.value!r} not allowed")
    if isinstance(node, ast.Name):
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        raise SafeEvalError(f"name '{node.id}' is not defined (only literals, pi, e, true/false)")
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_eval(e, depth) for e in node.elts]
        return _check_size(items if isinstance(node, ast.List) else tuple(items))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_eval(node.operand, depth))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        return _binop(node, depth)
    if isinstance(node, ast.BoolOp):
        return _boolop(node, depth)
    if isinstance(node, ast.Compare):
        return _compare(node, depth)
    if isinstance(node, ast.Call):
        return _call(node, depth)
    if isinstance(node, ast.IfExp):
        return _eval(node.body, depth) if _eval(node.test, depth) else _eval(node.orelse, depth)
    if isinstance(node, ast.Subscript):
        return _eval(node.value, depth)[_eval(node.slice, depth)]
    raise SafeEvalError(f"{type(node).__name__} not allowed in $(eval)")


def _binop(node: ast.BinOp, depth: int) -> object:
    """Arithmetic, with the size of the result checked before it is built where it can be."""
    left, right = _eval(node.left, depth), _eval(node.right, depth)
    if isinstance(node.op, ast.Pow) and isinstance(right, (int, float)) and abs(right) > _MAX_EXPONENT:
        raise SafeEvalError(f"exponent {right} too large")
    if (isinstance(node.op, ast.Pow) and isinstance(left, int) and isinstance(right, int)
            and left.bit_length() * right > 100_000):
        raise SafeEvalError("power result too large")
    if isinstance(node.op, ast.Mult):
        for seq, n in ((left, right), (right, left)):
            if isinstance(seq, (str, list, tuple)) and isinstance(n, int) and _size(seq) * n > _MAX_LEN:
                raise SafeEvalError(f"result larger than {_MAX_LEN} elements")
    if isinstance(node.op, ast.Mod) and isinstance(left, str):
        _check_format(left)
    return _check_size(_BINOPS[type(node.op)](left, right))


def _boolop(node: ast.BoolOp, depth: int) -> object:
    """`and`/`or`, short-circuiting as Python does."""
    if isinstance(node.op, ast.And):
        value: object = True
        for v in node.values:
            value = _eval(v, depth)
            if not value:
                return value
        return value
    value = False
    for v in node.values:
        value = _eval(v, depth)
        if value:
            return value
    return value


def _compare(node: ast.Compare, depth: int) -> bool:
    left = _eval(node.left, depth)
    for op, comp in zip(node.ops, node.comparators):
        if type(op) not in _COMPARE:
            raise SafeEvalError(f"comparison {type(op).__name__} not allowed")
        right = _eval(comp, depth)
        if not _COMPARE[type(op)](left, right):
            return False
        left = right
    return True


def _call(node: ast.Call, depth: int) -> object:
    """One of the pure functions of `_FUNCTIONS`, positional arguments only."""
    if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS or node.keywords:
        raise SafeEvalError(f"call not allowed; allowed functions: {', '.join(_FUNCTIONS)}")
    args = [_eval(a, depth) for a in node.args]
    if node.func.id == "str" and sum(_size(a) for a in args) > _MAX_LEN // 4:
        raise SafeEvalError(f"str() of a value larger than {_MAX_LEN // 4} elements")
    return _check_size(_FUNCTIONS[node.func.id](*args))


def safe_eval(expression: str) -> object:
    """Evaluate a simple expression: `safe_eval("2 * 0.5 if 'a' == 'a' else 0") == 1.0`."""
    if len(expression) > 10_000:
        raise SafeEvalError("expression too long")
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError as e:
        raise SafeEvalError(f"syntax error: {e.msg}") from e
    except (RecursionError, MemoryError) as e:                 # the parser's own depth limit
        raise SafeEvalError(f"expression nested deeper than {_MAX_DEPTH}") from e
    try:
        return _eval(tree)
    except SafeEvalError:
        raise
    except RecursionError as e:
        raise SafeEvalError("expression nested too deeply") from e
    except (ArithmeticError, TypeError, ValueError, IndexError, KeyError) as e:
        raise SafeEvalError(f"{type(e).__name__}: {e}") from e

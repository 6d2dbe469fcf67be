"""A small, safe expression evaluator for `$(eval ...)`.

ROS 2 launch hands `$(eval)` to Python's `eval`; a launch file is then arbitrary code. Here only
literals, arithmetic, comparisons, boolean logic, `x if c else y`, `in`, indexing and a few pure
builtins are allowed; names, attributes, lambdas and comprehensions are refused. Sizes are bounded
so that `9**9**9` or `'a' * 10**12` fail quickly instead of eating the machine.
"""
from __future__ import annotations

import ast
import math
import operator

_MAX_EXPONENT = 1024
_MAX_LEN = 100_000

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


def _check_size(value: object) -> object:
    if isinstance(value, (str, list, tuple)) and len(value) > _MAX_LEN:
        raise SafeEvalError(f"result longer than {_MAX_LEN}")
    return value


def _eval(node: ast.AST) -> object:
    if isinstance(node, ast.Expression):
        return _eval(node.body)
    if isinstance(node, ast.Constant):
        if isinstance(node.value, (int, float, str, bool, type(None))):
            return node.value
        raise SafeEvalError(f"constant {node.value!r} not allowed")
    if isinstance(node, ast.Name):
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        raise SafeEvalError(f"name '{node.id}' is not defined (only literals, pi, e, true/false)")
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_eval(e) for e in node.elts]
        return _check_size(items if isinstance(node, ast.List) else tuple(items))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_eval(node.operand))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        left, right = _eval(node.left), _eval(node.right)
        if isinstance(node.op, ast.Pow) and isinstance(right, (int, float)) and abs(right) > _MAX_EXPONENT:
            raise SafeEvalError(f"exponent {right} too large")
        if (isinstance(node.op, ast.Pow) and isinstance(left, int) and isinstance(right, int)
                and left.bit_length() * right > 100_000):
            raise SafeEvalError("power result too large")
        if isinstance(node.op, ast.Mult):
            for seq, n in ((left, right), (right, left)):
                if isinstance(seq, (str, list, tuple)) and isinstance(n, int) and len(seq) * n > _MAX_LEN:
                    raise SafeEvalError(f"result longer than {_MAX_LEN}")
        return _check_size(_BINOPS[type(node.op)](left, right))
    if isinstance(node, ast.BoolOp):
        if isinstance(node.op, ast.And):
            value: object = True
            for v in node.values:
                value = _eval(v)
                if not value:
                    return value
            return value
        value = False
        for v in node.values:
            value = _eval(v)
            if value:
                return value
        return value
    if isinstance(node, ast.Compare):
        left = _eval(node.left)
        for op, comp in zip(node.ops, node.comparators):
            if type(op) not in _COMPARE:
                raise SafeEvalError(f"comparison {type(op).__name__} not allowed")
            right = _eval(comp)
            if not _COMPARE[type(op)](left, right):
                return False
            left = right
        return True
    if isinstance(node, ast.IfExp):
        return _eval(node.body) if _eval(node.test) else _eval(node.orelse)
    if isinstance(node, ast.Subscript):
        return _eval(node.value)[_eval(node.slice)]
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS or node.keywords:
            raise SafeEvalError(f"call not allowed; allowed functions: {', '.join(_FUNCTIONS)}")
        return _FUNCTIONS[node.func.id](*[_eval(a) for a in node.args])
    raise SafeEvalError(f"{type(node).__name__} not allowed in $(eval)")


def safe_eval(expression: str) -> object:
    """Evaluate a simple expression: `safe_eval("2 * 0.5 if 'a' == 'a' else 0") == 1.0`."""
    if len(expression) > 10_000:
        raise SafeEvalError("expression too long")
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError as e:
        raise SafeEvalError(f"syntax error: {e.msg}") from e
    try:
        return _eval(tree)
    except SafeEvalError:
        raise
    except (ArithmeticError, TypeError, ValueError, IndexError, KeyError) as e:
        raise SafeEvalError(f"{type(e).__name__}: {e}") from e

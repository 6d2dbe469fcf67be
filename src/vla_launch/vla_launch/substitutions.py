"""Launch substitutions (`$(var x)`, `$(find-pkg-share p)`, `$(env X d)`, `$(eval ...)`, ...).

A hand-written parser for the grammar of ROS 2 launch's frontend (launch/frontend/grammar.lark):
outside a substitution, text is literal and a backslash escapes the next character; inside one,
arguments are separated by spaces and may be single- or double-quoted (then they may hold spaces and
parentheses); substitutions nest. Evaluation never runs Python: `$(eval)` goes through `safe_eval`.
"""
from __future__ import annotations

import os
import re
import secrets
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from vla_launch.safe_eval import SafeEvalError, safe_eval

_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_-]*")


class SubstitutionError(ValueError):
    """A substitution that cannot be parsed or evaluated; the message says which and why."""


@dataclass(frozen=True)
class Substitution:
    name: str
    args: tuple[Template, ...] = ()


# A template is a sequence of literal strings and substitutions, concatenated when evaluated.
Template = tuple  # tuple[str | Substitution, ...]


@dataclass
class SubstitutionContext:
    """What substitutions can see: launch configurations, the file being read, the environment."""

    configurations: dict[str, str] = field(default_factory=dict)
    current_file: str | None = None
    environ: Mapping[str, str] = field(default_factory=lambda: os.environ)
    anon_names: dict[str, str] = field(default_factory=dict)
    find_share: Callable[[str], str] | None = None
    find_prefix: Callable[[str], str] | None = None

    def child(self) -> SubstitutionContext:
        """A scoped copy (group, include): changes to its configurations do not leak back."""
        return SubstitutionContext(
            configurations=dict(self.configurations), current_file=self.current_file,
            environ=self.environ, anon_names=self.anon_names,
            find_share=self.find_share, find_prefix=self.find_prefix)


# ----------------------------------------------------------------------------------------- parsing
class _Parser:
    def __init__(self, text: str) -> None:
        self.text = text
        self.i = 0

    def error(self, what: str) -> SubstitutionError:
        return SubstitutionError(f"{what} at position {self.i} in {self.text!r}")

    def peek(self, k: int = 0) -> str:
        j = self.i + k
        return self.text[j] if j < len(self.text) else ""

    def at_subst(self) -> bool:
        return self.text.startswith("$(", self.i)

    def template(self) -> Template:
        parts: list = []
        buf: list[str] = []
        while self.i < len(self.text):
            c = self.text[self.i]
            if c == "\\" and self.i + 1 < len(self.text):
                buf.append(self.text[self.i + 1])
                self.i += 2
            elif self.at_subst():
                if buf:
                    parts.append("".join(buf))
                    buf = []
                parts.append(self.substitution())
            else:
                buf.append(c)
                self.i += 1
        if buf:
            parts.append("".join(buf))
        return tuple(parts)

    def substitution(self) -> Substitution:
        start = self.i
        self.i += 2  # "$("
        m = _IDENTIFIER.match(self.text, self.i)
        if not m:
            raise self.error("expected a substitution name after '$('")
        name = m.group(0)
        self.i = m.end()
        args: list[Template] = []
        while True:
            c = self.peek()
            if c == "":
                self.i = start
                raise self.error(f"unterminated substitution '$({name}'")
            if c == ")":
                self.i += 1
                return Substitution(name, tuple(args))
            if c not in " \t":
                raise self.error(f"expected ' ' or ')' in '$({name} ...'")
            while self.peek() in (" ", "\t"):
                self.i += 1
            if self.peek() == ")":
                continue
            args.append(self.argument())

    def argument(self) -> Template:
        q = self.peek()
        if q in ("'", '"'):
            return self.quoted(q)
        parts: list = []
        buf: list[str] = []
        while True:
            c = self.peek()
            if c in ("", " ", "\t", ")"):
                break
            if c == "\\" and self.peek(1):
                buf.append(self.peek(1))
                self.i += 2
            elif self.at_subst():
                if buf:
                    parts.append("".join(buf))
                    buf = []
                parts.append(self.substitution())
            elif c == "(":
                raise self.error("unescaped '(' in a substitution argument (quote the argument)")
            else:
                buf.append(c)
                self.i += 1
        if buf:
            parts.append("".join(buf))
        return tuple(parts)

    def quoted(self, q: str) -> Template:
        start = self.i
        self.i += 1
        parts: list = []
        buf: list[str] = []
        while True:
            c = self.peek()
            if c == "":
                self.i = start
                raise self.error(f"unterminated {q}-quoted argument")
            if c == q:
                self.i += 1
                break
            if c == "\\" and self.peek(1):
                buf.append(self.peek(1))
                self.i += 2
            elif self.at_subst():
                if buf:
                    parts.append("".join(buf))
                    buf = []
                parts.append(self.substitution())
            else:
                buf.append(c)
                self.i += 1
        if buf:
            parts.append("".join(buf))
        return tuple(parts)


def parse_template(text: str) -> Template:
    """Parse a launch attribute string into literal text and substitutions."""
    return _Parser(text).template()


def has_substitutions(template: Template) -> bool:
    return any(isinstance(p, Substitution) for p in template)


# -------------------------------------------------------------------------------------- evaluation
def _as_bool(value: str, what: str) -> bool:
    v = value.strip().lower()
    if v in ("true", "1"):
        return True
    if v in ("false", "0"):
        return False
    raise SubstitutionError(f"{what}: expected 'true', 'false', '1' or '0', got {value!r}")


def _default_share(pkg: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return get_package_share_directory(pkg)
    except (PackageNotFoundError, ValueError) as e:
        raise SubstitutionError(f"$(find-pkg-share {pkg}): package '{pkg}' not found") from e


def _default_prefix(pkg: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        return get_package_prefix(pkg)
    except (PackageNotFoundError, ValueError) as e:
        raise SubstitutionError(f"$(find-pkg-prefix {pkg}): package '{pkg}' not found") from e


def _nargs(name: str, args: list[str], lo: int, hi: int) -> None:
    if not lo <= len(args) <= hi:
        want = str(lo) if lo == hi else f"{lo} to {hi}"
        raise SubstitutionError(f"$({name}) takes {want} argument(s), got {len(args)}: {args}")


def _subst_var(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("var", args, 1, 1)
    if args[0] not in ctx.configurations:
        raise SubstitutionError(f"launch configuration '{args[0]}' does not exist (no arg or let sets it)")
    return ctx.configurations[args[0]]


def _subst_env(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("env", args, 1, 2)
    if args[0] in ctx.environ:
        return ctx.environ[args[0]]
    if len(args) == 2:
        return args[1]
    raise SubstitutionError(
        f"environment variable '{args[0]}' is not set (give a default: $(env NAME default))")


def _subst_optenv(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("optenv", args, 1, 2)
    return ctx.environ.get(args[0], args[1] if len(args) == 2 else "")


def _subst_share(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("find-pkg-share", args, 1, 1)
    return (ctx.find_share or _default_share)(args[0])


def _subst_prefix(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("find-pkg-prefix", args, 1, 1)
    return (ctx.find_prefix or _default_prefix)(args[0])


def _subst_eval(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("eval", args, 1, 1)
    try:
        return str(safe_eval(args[0]))
    except SafeEvalError as e:
        raise SubstitutionError(f"$(eval {args[0]!r}): {e}") from e


def _subst_dirname(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("dirname", args, 0, 0)
    if ctx.current_file is None:
        raise SubstitutionError("$(dirname) used outside a launch file")
    return os.path.dirname(os.path.abspath(ctx.current_file))


def _subst_filename(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("filename", args, 0, 0)
    if ctx.current_file is None:
        raise SubstitutionError("$(filename) used outside a launch file")
    return os.path.abspath(ctx.current_file)


def _subst_anon(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("anon", args, 1, 1)
    return ctx.anon_names.setdefault(args[0], f"{args[0]}_{secrets.randbelow(10**9)}")


def _subst_not(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("not", args, 1, 1)
    return str(not _as_bool(args[0], "$(not)")).lower()


def _subst_and(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("and", args, 2, 2)
    return str(_as_bool(args[0], "$(and)") and _as_bool(args[1], "$(and)")).lower()


def _subst_or(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("or", args, 2, 2)
    return str(_as_bool(args[0], "$(or)") or _as_bool(args[1], "$(or)")).lower()


def _subst_equals(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("equals", args, 2, 2)
    return str(args[0] == args[1]).lower()


def _subst_not_equals(ctx: SubstitutionContext, args: list[str]) -> str:
    _nargs("not-equals", args, 2, 2)
    return str(args[0] != args[1]).lower()


_SUBSTITUTIONS: dict[str, Callable[[SubstitutionContext, list[str]], str]] = {
    "var": _subst_var,
    "env": _subst_env,
    "optenv": _subst_optenv,
    "find-pkg-share": _subst_share,
    "find-pkg-prefix": _subst_prefix,
    "eval": _subst_eval,
    "dirname": _subst_dirname,
    "filename": _subst_filename,
    "anon": _subst_anon,
    "not": _subst_not,
    "and": _subst_and,
    "or": _subst_or,
    "equals": _subst_equals,
    "not-equals": _subst_not_equals,
}
SUPPORTED_SUBSTITUTIONS = tuple(_SUBSTITUTIONS)


def evaluate(template: Template, ctx: SubstitutionContext) -> str:
    """Evaluate a parsed template to a string (arguments are evaluated before the substitution)."""
    out: list[str] = []
    for part in template:
        if isinstance(part, str):
            out.append(part)
            continue
        fn = _SUBSTITUTIONS.get(part.name)
        if fn is None:
            raise SubstitutionError(
                f"unsupported substitution '$({part.name})'; supported: {', '.join(SUPPORTED_SUBSTITUTIONS)}")
        out.append(fn(ctx, [evaluate(a, ctx) for a in part.args]))
    return "".join(out)


def substitute(text: str, ctx: SubstitutionContext) -> str:
    """Parse and evaluate one attribute string."""
    return evaluate(parse_template(text), ctx)


def split_command_line(text: str, ctx: SubstitutionContext) -> list[str]:
    """Split an `args`/`ros_args`/`cmd` attribute the way launch does.

    Literal text is split shell-like (quotes group words); the result of a substitution is never
    split, so `$(var path)` stays one argument even if it holds spaces.
    """
    import shlex

    words: list[str] = []
    cur: list[str] | None = None

    def close() -> None:
        nonlocal cur
        if cur is not None:
            words.append("".join(cur))
            cur = None

    for part in parse_template(text):
        if isinstance(part, Substitution):
            cur = (cur or []) + [evaluate((part,), ctx)]
            continue
        if not part.strip():
            close()
            continue
        try:
            tokens = shlex.split(part)
        except ValueError as e:
            raise SubstitutionError(f"cannot split command line {text!r}: {e}") from e
        if part[0].isspace():
            close()
        cur = (cur or []) + [tokens[0]]
        for tok in tokens[1:]:
            close()
            cur = [tok]
        if part[-1].isspace():
            close()
    close()
    return words


def as_condition(value: str, what: str) -> bool:
    """Evaluate an `if`/`unless` value the way launch does ('true'/'1'/'false'/'0', any case)."""
    return _as_bool(value, what)

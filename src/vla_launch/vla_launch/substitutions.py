"""Launch substitutions (`$(var x)`, `$(find-pkg-share p)`, `$(env X d)`, `$(eval e)`, `$(file-content f)`…).

The grammar of ROS 2 launch's frontend (launch/frontend/grammar.lark), written for lark: outside a
substitution, text is literal and a backslash escapes the next character; inside one, arguments are
separated by spaces and may be single- or double-quoted (then they may hold spaces and parentheses);
substitutions nest. Evaluation never runs Python: `$(eval)` goes through `safe_eval`.
"""
from __future__ import annotations

import os
import secrets
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from lark import Lark, Token, Transformer
from lark.exceptions import LarkError, UnexpectedInput

from vla_launch.safe_eval import SafeEvalError, safe_eval

MAX_NESTING = 32  # substitutions inside substitutions; deeper is refused, not a RecursionError


class SubstitutionError(ValueError):
    """A substitution that cannot be parsed or evaluated; the message says which and why."""


@dataclass(frozen=True)
class Substitution:
    name: str
    args: tuple[Template, ...] = ()
    depth: int = field(default=1, compare=False)  # nesting, counted while parsing


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
# Each context (top level, unquoted, '-quoted and "-quoted argument) has its own rules, so that the
# LALR states, and with them the terminals the contextual lexer tries, never mix two contexts.
_GRAMMAR = r"""
    template: (TEXT | ESCAPE | DOLLAR | top_sub)*
    top_sub: "$(" _call ")"
    _call: NAME (_WS argument)* _WS?
    ?argument: unquoted | single | double
    unquoted: (ARG_TEXT | ESCAPE | DOLLAR | unquoted_sub)+
    unquoted_sub: "$(" _call ")"
    single: "'" (SQ_TEXT | ESCAPE | DOLLAR | single_sub)* "'"
    single_sub: "$(" _call ")"
    double: "\"" (DQ_TEXT | ESCAPE | DOLLAR | double_sub)* "\""
    double_sub: "$(" _call ")"

    NAME: /[A-Za-z][A-Za-z0-9_-]*/
    TEXT: /[^\\$]+/
    ARG_TEXT: /[^ \t()\\$'"]+/
    SQ_TEXT: /[^'\\$]+/
    DQ_TEXT: /[^"\\$]+/
    ESCAPE: /\\(.|\n)?/
    DOLLAR: "$"
    _WS: /[ \t]+/
"""


def _literal(tok: Token) -> str:
    return tok[1:] or "\\" if tok.type == "ESCAPE" else str(tok)


def _join(items: list) -> Template:
    """Adjacent literal pieces merged: ("a", "$", "b", Substitution) -> ("a$b", Substitution)."""
    parts: list = []
    for item in items:
        if isinstance(item, Substitution):
            parts.append(item)
        elif parts and isinstance(parts[-1], str):
            parts[-1] += _literal(item)
        else:
            parts.append(_literal(item))
    return tuple(parts)


class _ToTemplate(Transformer):
    """Applied by the LALR parser as it reduces (bottom-up, no recursion over the nesting)."""

    def template(self, items: list) -> Template:
        return _join(items)

    unquoted = single = double = template

    def substitution(self, items: list) -> Substitution:
        name, *args = items
        depth = 1 + max((p.depth for a in args for p in a if isinstance(p, Substitution)), default=0)
        if depth > MAX_NESTING:
            raise SubstitutionError(f"substitutions nested deeper than {MAX_NESTING}")
        return Substitution(str(name), tuple(args), depth)

    top_sub = unquoted_sub = single_sub = double_sub = substitution


_PARSER = Lark(_GRAMMAR, start="template", parser="lalr", lexer="contextual",
               transformer=_ToTemplate(), maybe_placeholders=False)


def _parse_error(text: str, e: UnexpectedInput) -> SubstitutionError:
    token = getattr(e, "token", None)
    pos = getattr(e, "pos_in_stream", None)
    if pos is None or token is not None and token.type == "$END":
        what, pos = "unterminated substitution or quoted argument", len(text)
    elif text.startswith("$(", pos - 2):
        what = "expected a substitution name after '$('"
    elif text[pos] == "(":
        what = "unescaped '(' in a substitution argument (quote the argument)"
    else:
        what = f"unexpected {text[pos]!r}"
    return SubstitutionError(f"{what} at position {pos} in {text!r}")


def parse_template(text: str) -> Template:
    """Parse a launch attribute string into literal text and substitutions."""
    try:
        return _PARSER.parse(text)
    except UnexpectedInput as e:
        raise _parse_error(text, e) from None
    except SubstitutionError as e:  # the nesting bound, raised while reducing
        raise SubstitutionError(f"{e} in {text[:200]!r}") from None
    except LarkError as e:
        raise SubstitutionError(f"cannot parse {text!r}: {e}") from None


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


def _find(kind: str) -> Callable[[str], str]:
    """The ament index lookup of $(find-pkg-share) or $(find-pkg-prefix) (tests pass their own)."""
    def find(pkg: str) -> str:
        from ament_index_python import packages

        try:
            return getattr(packages, f"get_package_{kind}")(pkg)
        except (packages.PackageNotFoundError, ValueError) as e:
            what = f"$(find-pkg-{kind.split('_')[0]} {pkg})"
            raise SubstitutionError(f"{what}: package '{pkg}' not found") from e
    return find


def _var(ctx: SubstitutionContext, name: str) -> str:
    if name not in ctx.configurations:
        raise SubstitutionError(f"launch configuration '{name}' does not exist (no arg or let sets it)")
    return ctx.configurations[name]


def _env(ctx: SubstitutionContext, name: str, *default: str) -> str:
    if name in ctx.environ or default:
        return ctx.environ.get(name, *default)
    raise SubstitutionError(f"environment variable '{name}' is not set (give a default: $(env NAME default))")


def _eval(ctx: SubstitutionContext, expression: str) -> str:
    try:
        return str(safe_eval(expression))
    except SafeEvalError as e:
        raise SubstitutionError(f"$(eval {expression!r}): {e}") from e


def _file(ctx: SubstitutionContext) -> str:
    if ctx.current_file is None:
        raise SubstitutionError("$(dirname)/$(filename) used outside a launch file")
    return os.path.abspath(ctx.current_file)


FILE_CONTENT_MAX = 4 * 1024 * 1024   # bytes: a URDF is tens of kB; /dev/zero must not fill memory


def _file_content(ctx: SubstitutionContext, path: str) -> str:
    """launch's $(file-content PATH) (Jazzy): a regular file's text, read when the file is launched."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise SubstitutionError(f"$(file-content {path}): {e.strerror}") from e
    if not stat.S_ISREG(st.st_mode):
        raise SubstitutionError(f"$(file-content {path}): not a regular file")
    if st.st_size > FILE_CONTENT_MAX:
        raise SubstitutionError(f"$(file-content {path}): {st.st_size} bytes, more than {FILE_CONTENT_MAX}")
    try:
        with open(path, encoding="utf-8") as f:
            return f.read(FILE_CONTENT_MAX + 1)[:FILE_CONTENT_MAX]
    except (OSError, UnicodeDecodeError) as e:
        why = type(e).__name__
        raise SubstitutionError(f"$(file-content {path}): cannot be read as UTF-8 text ({why})") from e


def _bools(name: str, combine: Callable[..., bool]) -> Callable[..., str]:
    return lambda ctx, *a: str(combine(*(_as_bool(v, f"$({name})") for v in a))).lower()


# name -> (fewest arguments, most arguments, function of the context and the evaluated arguments)
_SUBSTITUTIONS: dict[str, tuple[int, int, Callable[..., str]]] = {
    "var": (1, 1, _var),
    "env": (1, 2, _env),
    "optenv": (1, 2, lambda ctx, name, default="": ctx.environ.get(name, default)),
    "find-pkg-share": (1, 1, lambda ctx, p: (ctx.find_share or _find("share_directory"))(p)),
    "find-pkg-prefix": (1, 1, lambda ctx, p: (ctx.find_prefix or _find("prefix"))(p)),
    "eval": (1, 1, _eval),
    "file-content": (1, 1, _file_content),
    "dirname": (0, 0, lambda ctx: os.path.dirname(_file(ctx))),
    "filename": (0, 0, _file),
    "anon": (1, 1, lambda ctx, n: ctx.anon_names.setdefault(n, f"{n}_{secrets.randbelow(10**9)}")),
    "not": (1, 1, _bools("not", lambda a: not a)),
    "and": (2, 2, _bools("and", lambda a, b: a and b)),
    "or": (2, 2, _bools("or", lambda a, b: a or b)),
    "equals": (2, 2, lambda ctx, a, b: str(a == b).lower()),
    "not-equals": (2, 2, lambda ctx, a, b: str(a != b).lower()),
}
SUPPORTED_SUBSTITUTIONS = tuple(_SUBSTITUTIONS)


def evaluate(template: Template, ctx: SubstitutionContext) -> str:
    """Evaluate a parsed template to a string (arguments are evaluated before the substitution)."""
    out: list[str] = []
    for part in template:
        if isinstance(part, str):
            out.append(part)
            continue
        if part.name not in _SUBSTITUTIONS:
            raise SubstitutionError(
                f"unsupported substitution '$({part.name})'; supported: {', '.join(SUPPORTED_SUBSTITUTIONS)}")
        lo, hi, fn = _SUBSTITUTIONS[part.name]
        args = [evaluate(a, ctx) for a in part.args]
        if not lo <= len(args) <= hi:
            want = str(lo) if lo == hi else f"{lo} to {hi}"
            raise SubstitutionError(f"$({part.name}) takes {want} argument(s), got {len(args)}: {args}")
        out.append(fn(ctx, *args))
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

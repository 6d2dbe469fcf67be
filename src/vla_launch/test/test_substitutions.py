"""Substitution parsing and evaluation, following launch's frontend grammar."""
import pytest
from vla_launch.safe_eval import SafeEvalError, safe_eval
from vla_launch.substitutions import (
    Substitution,
    SubstitutionContext,
    SubstitutionError,
    parse_template,
    split_command_line,
    substitute,
)


def ctx(**configs):
    return SubstitutionContext(configurations=dict(configs), current_file="/pkg/launch/x.launch.yaml",
                               environ={"HOME": "/home/u", "EMPTY": ""},
                               find_share=lambda p: f"/share/{p}", find_prefix=lambda p: f"/prefix/{p}")


def test_parse_literal_and_nested():
    assert parse_template("plain text") == ("plain text",)
    t = parse_template("a $(var x) b")
    assert t == ("a ", Substitution("var", (("x",),)), " b")
    t = parse_template("$(find-pkg-share $(var pkg))/config")
    assert t[0] == Substitution("find-pkg-share", ((Substitution("var", (("pkg",),)),),))
    assert t[1] == "/config"


def test_quoted_arguments_keep_spaces_and_parentheses():
    t = parse_template("$(env NAME 'a default (with) spaces')")
    assert t[0].args[1] == ("a default (with) spaces",)
    assert substitute('$(env MISSING "x $(var y) z")', ctx(y="Y")) == "x Y z"


def test_escapes():
    assert substitute(r"cost \$(var x)", ctx(x="1")) == "cost $(var x)"
    assert substitute(r"$(env MISSING a\)b)", ctx()) == "a)b"


@pytest.mark.parametrize("text,err", [
    ("$(var x", "unterminated"),
    ("$(1abc)", "expected a substitution name"),
    ("$(env X 'open)", "unterminated"),
    ("$(env X a(b)", "unescaped '\\('"),
])
def test_parse_errors_are_clear(text, err):
    with pytest.raises(SubstitutionError, match=err):
        parse_template(text)


def test_grammar_details():
    assert parse_template("cost $5 $") == ("cost $5 $",)  # a `$` not followed by `(` is text
    assert parse_template("a\\") == ("a\\",)  # a trailing backslash stays
    assert parse_template("$(var  x  )") == (Substitution("var", (("x",),)),)
    assert parse_template("$(x '' \"\")") == (Substitution("x", ((), ())),)
    assert parse_template('$(v "a $(b c)d" e$f)g') == (
        Substitution("v", (("a ", Substitution("b", (("c",),)), "d"), ("e$f",))), "g")


@pytest.mark.parametrize("text,err", [
    ("$(a b'c)", "unexpected \"'\" at position 5"),  # a quote only opens an argument
    ("$()", "expected a substitution name"),
    ("$(a $(b)", "unterminated"),
])
def test_more_parse_errors(text, err):
    with pytest.raises(SubstitutionError, match=err):
        parse_template(text)


def test_nesting_is_bounded_without_recursion():
    from vla_launch.substitutions import MAX_NESTING

    deep = "$(not " * MAX_NESTING + "true" + ")" * MAX_NESTING
    assert substitute(deep, ctx()) == "true"
    with pytest.raises(SubstitutionError, match=f"nested deeper than {MAX_NESTING}"):
        parse_template("$(not " * 5000 + "true" + ")" * 5000)


def test_a_seeded_fuzzer_of_the_grammar_gives_a_template_or_a_clear_error():
    """Random attribute strings from the grammar's characters: each parses to a template or fails
    with a SubstitutionError that says where, never another exception."""
    import random

    rng = random.Random(21)
    pieces = ["$(", "var", " ", "x", ")", "$", "\\", "'", '"', "(", "\t", "env ", "\n"]
    for _ in range(3000):
        text = "".join(rng.choice(pieces) for _ in range(rng.randint(0, 14)))
        try:
            parse_template(text)
        except SubstitutionError as e:
            assert "position" in str(e) or "nested" in str(e), (text, e)


def test_evaluate_supported_substitutions():
    c = ctx(x="7", flag="true")
    assert substitute("$(var x)", c) == "7"
    assert substitute("$(env HOME)/w", c) == "/home/u/w"
    assert substitute("[$(env EMPTY fallback)]", c) == "[]"  # set but empty: no default
    assert substitute("$(env NOPE fallback)", c) == "fallback"
    assert substitute("$(optenv NOPE)", c) == ""
    assert substitute("$(find-pkg-share vla_x)/config/a.yaml", c) == "/share/vla_x/config/a.yaml"
    assert substitute("$(find-pkg-prefix vla_x)", c) == "/prefix/vla_x"
    assert substitute("$(dirname)", c) == "/pkg/launch"
    assert substitute("$(eval '$(var x) * 2')", c) == "14"
    assert substitute("$(not $(var flag))", c) == "false"
    assert substitute("$(and true 1)", c) == "true"
    assert substitute("$(equals $(var x) 7)", c) == "true"
    a1, a2 = substitute("$(anon node)", c), substitute("$(anon node)", c)
    assert a1 == a2 and a1.startswith("node_")


@pytest.mark.parametrize("text,err", [
    ("$(var missing)", "launch configuration 'missing' does not exist"),
    ("$(env NOPE)", "environment variable 'NOPE' is not set"),
    ("$(command ls)", "unsupported substitution"),
    ("$(var a b)", "takes 1 argument"),
    ("$(not maybe)", "expected 'true'"),
    ("$(eval '__import__(\"os\")')", "call not allowed"),
])
def test_evaluation_errors_are_clear(text, err):
    with pytest.raises(SubstitutionError, match=err):
        substitute(text, ctx())


def test_real_find_pkg_share_uses_the_ament_index():
    share = substitute("$(find-pkg-share vla_bringup)", SubstitutionContext())
    assert share.endswith("share/vla_bringup")
    with pytest.raises(SubstitutionError, match="package 'no_such_pkg' not found"):
        substitute("$(find-pkg-share no_such_pkg)", SubstitutionContext())


def test_split_command_line_like_launch():
    c = ctx(path="/a b/c", empty="")
    assert split_command_line("--n 1 'two words'", c) == ["--n", "1", "two words"]
    # a substitution's value is never split, and glues to adjacent text
    assert split_command_line("--file $(var path) x=$(var path)", c) == ["--file", "/a b/c", "x=/a b/c"]
    assert split_command_line("$(var path) $(var path)", c) == ["/a b/c", "/a b/c"]
    assert split_command_line("", c) == []


def test_safe_eval_allows_simple_expressions():
    assert safe_eval("1 + 2 * 3") == 7
    assert safe_eval("2 ** 10") == 1024
    assert safe_eval("'a' if 1 < 2 <= 2 else 'b'") == "a"
    assert safe_eval("'x' in ['x', 'y'] and not False") is True
    assert safe_eval("max(1, 4) + round(pi, 2)") == pytest.approx(7.14)
    assert safe_eval("true or false") is True


@pytest.mark.parametrize("expr", [
    "().__class__", "__import__('os').system('true')", "open('/etc/passwd')", "[x for x in (1,)]",
    "lambda: 1", "9 ** 9 ** 9", "'a' * 10 ** 9", "os", "1/0", "max(key=len)",
])
def test_safe_eval_refuses_code_and_huge_results(expr):
    with pytest.raises(SafeEvalError):
        safe_eval(expr)


BOMBS = {  # issue 20 item 10: each hung, allocated gigabytes or crashed before
    "nested str": "len(str([[0]*90000]*90000))",
    "format width": "'%900000000d' % 1",
    "format precision": "'%.900000000f' % 1",
    "format star": "'%*d' % (900000000, 1)",
    "deep unary": "-" * 5000 + "1",
    "deep not": "not " * 2400 + "1",
    "nested repeat": "[[[0]*300]*300]*300",
}


def _dry_run_in_384_mib(tmp_path, value: str):
    """`vla launch --dry-run` of a file whose one argument defaults to `value`, as a user runs it, in a
    process limited to 384 MiB of address space."""
    import resource
    import subprocess
    import sys

    launch = tmp_path / "bomb.launch.yaml"
    launch.write_text(f'launch:\n- arg: {{name: x, default: "{value}"}}\n')

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (384 << 20, 384 << 20))

    return subprocess.run([sys.executable, "-m", "vla_launch.cli", "launch", str(launch), "--dry-run"],
                          capture_output=True, text=True, timeout=60, preexec_fn=limit)


@pytest.mark.parametrize("name", sorted(BOMBS) + ["nested substitutions"])
def test_an_eval_bomb_in_a_launch_file_is_a_clean_error_within_bounded_memory(tmp_path, name):
    """Exit code 1 or 2, a message that names the file and says what was refused, no traceback."""
    if name == "nested substitutions":
        value = "$(not " * 3000 + "true" + ")" * 3000
    else:
        value = '$(eval \\"' + BOMBS[name].replace('"', "'") + '\\")'
    out = _dry_run_in_384_mib(tmp_path, value)
    assert out.returncode in (1, 2), (out.returncode, out.stderr[-2000:])
    assert "Traceback" not in out.stderr and "bomb.launch.yaml" in out.stderr, out.stderr[-2000:]
    assert any(w in out.stderr for w in ("larger than", "too large", "nested", "too long")), out.stderr[-800:]


def test_a_seeded_fuzzer_of_eval_never_escapes_a_clean_refusal():
    """Random expressions from the grammar's pieces, bounded in count: each gives a value or a
    SafeEvalError, never another exception, and no value larger than the size bound."""
    import random

    from vla_launch.safe_eval import _MAX_LEN, _size
    rng = random.Random(20)
    atoms = ["0", "1", "9", "-7", "2.5", "'a'", "'%d'", "'%9999999d'", "[0]", "[1, 2]", "(1,)", "pi",
             "true", "None", "[[0]*9]"]
    ops = ["+", "-", "*", "/", "//", "%", "**", " and ", " or ", " in ", " == ", " < "]
    funcs = ["str", "len", "abs", "int", "float", "max", "min", "round", "bool"]

    def expr(depth: int) -> str:
        k = rng.random()
        if depth > 6 or k < 0.3:
            return rng.choice(atoms)
        if k < 0.6:
            return f"({expr(depth + 1)}{rng.choice(ops)}{expr(depth + 1)})"
        if k < 0.75:
            return f"{rng.choice(funcs)}({expr(depth + 1)})"
        if k < 0.85:
            return f"[{expr(depth + 1)}] * {rng.choice(['3', '999', '99999', '10**6'])}"
        if k < 0.93:
            return f"{expr(depth + 1)}[{expr(depth + 1)}]"
        return f"({expr(depth + 1)} if {expr(depth + 1)} else {expr(depth + 1)})"

    for _ in range(3000):
        e = expr(0)
        try:
            value = safe_eval(e)
        except SafeEvalError:
            continue
        assert _size(value) <= _MAX_LEN, e


def test_file_content_reads_a_regular_file_and_refuses_the_rest(tmp_path):
    """launch's $(file-content) (Jazzy): the URDF for robot_state_publisher; bounded, regular files."""
    f = tmp_path / "robot.urdf"
    f.write_text('<robot name="r">\n  <link name="a"/>\n</robot>\n')
    assert substitute(f"$(file-content {f})", ctx()) == f.read_text()
    for path, why in ((tmp_path / "none", "No such file"), (tmp_path, "not a regular file"),
                      ("/dev/zero", "not a regular file")):
        with pytest.raises(SubstitutionError, match=why):
            substitute(f"$(file-content {path})", ctx())
    big = tmp_path / "big"
    with open(big, "wb") as out:
        out.truncate(5 * 1024 * 1024)
    with pytest.raises(SubstitutionError, match="more than"):
        substitute(f"$(file-content {big})", ctx())

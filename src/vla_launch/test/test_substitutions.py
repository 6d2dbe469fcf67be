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

"""The .bg Pygments lexer: token classes, context rules, escaping, CSS."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pygments.token import Comment, Error, Keyword, Name, Number, Operator, Punctuation, String

from bondc.report.lexer import CSS_SCOPE, UNIT, BgLexer, highlight_bg, lexer_css

ROOT = Path(__file__).resolve().parents[1]

SAMPLE = '''\
import "lib/pneumatics.bg"   # shared functions
fn orifice(pu, pd) = if pd/pu < 0.528 then sqrt(pu) else 0
model Demo "A demo \\"model\\""
  param M    = 31.7 [kg] "inertial mass"
  param R    = 4.06e-5
  param Ar   = pi/4*(D^2 - d^2) [m^2]
  input omega [rad/s] = table(t, [0, t1], [0, w]) * step(t, 0.1)
  MSe force  : e = F
  I   mass   : f = p/M
  C   spring : e = k*q, q(0) = 0.01
  R   damper : e = if abs(f) < v0 and not stuck then R*f else C*2
  TF  screw  : r = lead/(2*pi)
  1   j_shaft, j_mass
  0   j_motor
  force -> j_shaft -> mass
  b9: j_shaft -> screw.p1
  output torque [N*m] = coupling.e
  state x [m] "travel" : der(x) = mass.f, x(0) = 0
  experiment cycle
    t_end = 3.6 [s]
    max_step = 1 [min]
    outputs = [torque]
  end
end
'''


def tokens(text: str) -> list[tuple[object, str]]:
    return [(kind, value) for kind, value in BgLexer().get_tokens(text) if value.strip()]


def kinds_of(text: str, value: str) -> list[object]:
    return [kind for kind, v in tokens(text) if v == value]


def test_sample_tokens_are_classified():
    toks = tokens(SAMPLE)
    assert Error not in {kind for kind, _ in toks}
    expect = {
        "import": Keyword, "model": Keyword.Declaration, "Demo": Name.Class, "fn": Keyword.Declaration,
        "orifice": Name.Function, "param": Keyword, "if": Keyword, "then": Keyword, "else": Keyword,
        "and": Operator.Word, "not": Operator.Word, "end": Keyword, "output": Keyword, "state": Keyword,
        "experiment": Keyword.Declaration, "cycle": Name.Class, "input": Keyword,
        "# shared functions": Comment.Single,
        "31.7": Number.Float, "4.06e-5": Number.Float, "0.528": Number.Float, "10": None,
        "[kg]": UNIT, "[m^2]": UNIT, "[rad/s]": UNIT, "[N*m]": UNIT, "[s]": UNIT, "[min]": UNIT, "[m]": UNIT,
        "->": Operator, "pi": Name.Builtin.Pseudo, "sqrt": Name.Builtin, "table": Name.Builtin,
        "step": Name.Builtin, "abs": Name.Builtin, "der": Name.Builtin,
        "MSe": Keyword.Type, "I": Keyword.Type, "TF": Keyword.Type,
        "force": None, "b9": Name.Label, "mass": None,
    }
    for value, kind in expect.items():
        if kind is None:
            continue
        assert kind in kinds_of(SAMPLE, value), (value, kinds_of(SAMPLE, value))


def test_element_kinds_are_keywords_only_at_statement_start():
    # `param R = ...` and `R*f` keep R a name; `R damper :` makes it a kind.
    r_kinds = kinds_of(SAMPLE, "R")
    assert r_kinds.count(Keyword.Type) == 1
    assert r_kinds.count(Name) == 2
    c_kinds = kinds_of(SAMPLE, "C")
    assert c_kinds == [Keyword.Type, Name]           # `C spring :` then `C*2`
    assert kinds_of(SAMPLE, "spring") == [Name.Entity]
    assert kinds_of(SAMPLE, "damper") == [Name.Entity]


def test_junction_kinds_only_at_statement_start():
    text = "  1 j_a, j_b\n0 j_c\n  param k = 1 + 0*x\n  s = f(1,\n    0)\n"
    assert kinds_of(text, "1") == [Keyword.Type, Number.Integer, Number.Integer]
    assert kinds_of(text, "0") == [Keyword.Type, Number.Integer, Number.Integer]
    for name in ("j_a", "j_b", "j_c"):
        assert kinds_of(text, name) == [Name.Entity]
    for name in ("j_shaft", "j_mass", "j_motor"):
        assert kinds_of(SAMPLE, name)[0] is Name.Entity


def test_brackets_after_a_value_are_units_and_lists_are_not():
    toks = tokens("  input w = table(t, [0, t1], [2, w]) [rad/s]\n  outputs = [x]\n  param a = (b + 1) [m/s]\n")
    units = [v for kind, v in toks if kind is UNIT]
    assert units == ["[rad/s]", "[m/s]"]
    assert [v for kind, v in toks if kind is Punctuation and v in "[]"] == ["[", "]", "[", "]", "[", "]"]


def test_builtin_names_are_builtins_only_when_called():
    assert kinds_of("param step = 2\n x = step(t, step)\n", "step") == [Name, Name.Builtin, Name]


def test_strings_with_escapes():
    toks = tokens('R r "a \\" quoted \\\\ text" : e = 1\n')
    assert (String.Escape, '\\"') in toks
    assert (String.Escape, "\\\\") in toks


def test_tokens_reproduce_the_text():
    assert "".join(value for _, value in BgLexer().get_tokens(SAMPLE)) == SAMPLE


def test_every_language_reference_fragment_lexes_without_errors():
    text = (ROOT / "docs" / "language.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```\n(.*?)```", text, flags=re.S)
    assert len(blocks) > 5
    for block in blocks:
        bad = [value for kind, value in BgLexer().get_tokens(block) if kind in Error]
        assert not bad, (block, bad)


@pytest.mark.parametrize("text", [
    'model M "<script>alert(1)</script>"\nend\n',
    "# <script>alert(1)</script> & </pre>\n",
    'R r "</code></pre><script>x</script>" : e = 1\n',
])
def test_html_in_strings_and_comments_is_escaped(text):
    html = highlight_bg(text)
    assert "<script" not in html
    assert "&lt;script&gt;" in html
    body = html.split("<code>", 1)[1]
    assert body.count("</pre>") == 1 and body.count("</code>") == 1


def test_highlight_is_markup_in_a_scoped_block():
    html = highlight_bg("model M\nend\n")
    assert html.__html__() == html            # Markup: templates insert it as it is
    assert html.startswith(f'<div class="{CSS_SCOPE}">')
    assert 'class="linenos"' in html
    assert 'class="linenos"' not in highlight_bg("model M\nend\n", linenos=False)


def test_css_is_scoped_and_styles_every_class_used():
    css = lexer_css()
    rules = [line for line in css.splitlines() if line.strip()]
    assert all(line.startswith(f".{CSS_SCOPE}") for line in rules)
    html = highlight_bg(SAMPLE)
    used = {cls for attr in re.findall(r'class="([^"]+)"', html) for cls in attr.split()}
    used -= {CSS_SCOPE, "w"}                   # whitespace has no style
    styled = set(re.findall(r"\.([A-Za-z][\w-]*)", css))
    assert used <= styled, used - styled


def test_docstring_examples():
    import doctest

    from bondc.report import lexer

    result = doctest.testmod(lexer)
    assert result.attempted > 0 and result.failed == 0

"""Property tests: the front end never crashes, and fmt round-trips generated trees.

(a) any text: ``parse_text`` returns or raises ParseError, whose diagnostics
    point at real lines;
(b) a valid model with lines deleted, inserted and swapped: parse and semantic
    check raise only ``BondcError`` subclasses;
(c) every input is handled within a deadline;
(d) random expression trees and whole models printed by fmt parse back equal,
    and fmt is a fixed point on them; comments added anywhere to valid models
    are kept, in order, and fmt is a fixed point on the result.

``BONDC_FUZZ_EXAMPLES=2000 pytest tests/test_properties.py`` fuzzes longer.
"""

from __future__ import annotations

import importlib
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bondc import ast
from bondc.errors import BondcError, ParseError
from bondc.fmt import fmt, format_expr, format_file
from bondc.parse import KEYWORDS, parse_set_value, parse_text
from bondc.source import Source

try:
    _semantic = importlib.import_module("bondc.semantic")
except ImportError:  # the semantic stage is optional here
    _semantic = None

# ~150 examples a test keeps the file under a minute on two cores; BONDC_FUZZ_EXAMPLES=5000 fuzzes longer.
EXAMPLES = int(os.environ.get("BONDC_FUZZ_EXAMPLES", "150"))
FAST = settings(max_examples=EXAMPLES, deadline=2000, suppress_health_check=[HealthCheck.too_slow])

MODEL = """\
# A small model that checks, used as the seed of mutations.
fn sat(x, lo, hi) = min(max(x, lo), hi)

model Press "a press"
  param m    = 2.0 [kg]
  param k    = 800 [N/m]
  param b    = 12  [N*s/m]
  param lead = 5.0 [mm]
  input F [N] = step(t, 0.1)*10 + table(t, [0, 1], [0, 1])

  MSe force  : e = sat(F, -100, 100)
  I   mass   : f = p/m, p(0) = 0
  C   spring : e = k*q,
      q(0) = 0.01
  R   damper : e = if abs(f) < 0.1 then b*f else b*f^2*sign(f)
  TF  screw  : r = lead/(2*pi)
  1   j
  0   j0

  force -> j
  b5: j -> mass
  j -> spring
  j -> screw.p1
  screw.p2 -> j0 -> damper

  output x [m] = spring.q
  output power [W] = force.e*force.f
  state travel [m] "travel" : der(travel) = mass.f, travel(0) = 0
  experiment step
    t_end = 2 [s]
    rtol  = 1e-6
  end
end
"""

TOKENS = sorted(KEYWORDS) + [
    "Se", "Sf", "MSe", "MSf", "R", "C", "I", "TF", "GY", "0", "1", "->", "(", ")", "[", "]", ",", ":", "=",
    ".", "^", "*", "/", "+", "-", "<", "<=", "==", "!=", ">", "\n", "\n", " ", "  ", "\t", '"', '"doc"',
    '"\\"', "\\", "#", "# c\n", "a", "x1", "e", "f", "q", "p", "der", "t", "3", "0.5", "4.06e-5", "1e", "@",
    "$", "\r\n", ";", "p1", "p2", "[kg]", "[N*m/rad]", "[m^-1]",
]


def _semantic_check(text: str) -> None:
    file = parse_text(text, "m.bg")
    if _semantic is not None and hasattr(_semantic, "build"):
        for model in file.models:
            _semantic.build(file, {"m.bg": Source("m.bg", text)}, model=model.name)


def assert_parse_error_is_well_formed(error: ParseError, text: str) -> None:
    assert error.diagnostics, "a ParseError without diagnostics"
    line_count = text.count("\n") + 1
    for diagnostic in error.diagnostics:
        assert diagnostic.code.startswith("E1")
        assert 1 <= diagnostic.span.line <= line_count + 1, diagnostic
        assert diagnostic.span.column >= 1


# ------------------------------------------------------------- (a) random text

@given(st.one_of(
    st.lists(st.sampled_from(TOKENS), max_size=60).map(" ".join),
    st.lists(st.sampled_from(TOKENS), max_size=60).map("".join),
    st.text(alphabet=st.sampled_from(list("abeftqpRCI01._->()[],:=^*/+<!#\"\\ \t\n\r@")), max_size=120),
))
@FAST
def test_random_text_raises_only_parse_errors(text):
    try:
        parse_text(text, "fuzz.bg")
    except ParseError as error:
        assert_parse_error_is_well_formed(error, text)


@given(st.text(max_size=60))
@FAST
def test_random_set_values_raise_only_parse_errors(text):
    try:
        parse_set_value(text)
    except ParseError as error:
        assert error.diagnostics and all(d.span.line >= 1 for d in error.diagnostics)


@given(st.lists(st.sampled_from(TOKENS), max_size=30).map(" ".join))
@FAST
def test_random_statements_inside_a_model_raise_only_parse_errors(statement):
    text = f"model M\n  param a = 1\n  {statement}\n  R r : e = f\nend\n"
    try:
        file = parse_text(text, "fuzz.bg")
    except ParseError as error:
        assert_parse_error_is_well_formed(error, text)
        return
    # whatever parses also formats, keeping its meaning, stably
    formatted = format_file(file, text)
    again = parse_text(formatted, "fuzz.bg")
    assert again == file
    assert format_file(again, formatted) == formatted


# ------------------------------------------------------------- (b) mutated models

_LINES = MODEL.splitlines()


@st.composite
def mutated_models(draw) -> str:
    lines = list(_LINES)
    for _ in range(draw(st.integers(1, 4))):
        # deletions, swaps and duplicates mostly keep the syntax and reach the semantic checks
        action = draw(st.sampled_from(["delete", "delete", "swap", "swap", "duplicate", "insert", "edit"]))
        index = draw(st.integers(0, len(lines) - 1)) if lines else 0
        if action == "delete" and lines:
            del lines[index]
        elif action == "insert":
            tokens = draw(st.lists(st.sampled_from(TOKENS), min_size=1, max_size=8))
            lines.insert(index, "  " + " ".join(tokens))
        elif action == "swap" and lines:
            other = draw(st.integers(0, len(lines) - 1))
            lines[index], lines[other] = lines[other], lines[index]
        elif action == "duplicate" and lines:
            lines.insert(index, lines[draw(st.integers(0, len(lines) - 1))])
        elif action == "edit" and lines:
            line = lines[index]
            cut = draw(st.integers(0, len(line)))
            lines[index] = line[:cut] + draw(st.sampled_from(TOKENS)) + line[cut:]
    return "\n".join(lines) + "\n"


def test_the_seed_model_is_valid():
    _semantic_check(MODEL)
    assert parse_text(fmt(MODEL)) == parse_text(MODEL)


@pytest.mark.slow
@given(mutated_models())
@FAST
def test_mutated_models_raise_only_bondc_errors(text):
    try:
        _semantic_check(text)
    except ParseError as error:
        assert_parse_error_is_well_formed(error, text)
    except BondcError as error:
        assert error.diagnostics


# ------------------------------------------------------------- (d) fmt round trip

_names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,5}", fullmatch=True).filter(lambda s: s not in KEYWORDS)
_numbers = st.from_regex(r"(\d{1,4}(\.\d{0,3})?|\.\d{1,3})([eE][+-]?\d{1,2})?", fullmatch=True)
_strings = st.text(alphabet=st.sampled_from(list('ab #,()"\\\t\n\x00')), max_size=8)
_leaves = st.one_of(
    _numbers.map(lambda text: ast.Num(float(text), text)),
    _names.map(ast.Name),
    st.lists(_names, min_size=2, max_size=3).map(lambda parts: ast.Ref(tuple(parts))),
    _strings.map(ast.Str),
)
_BINARY_OPS = ["+", "-", "*", "/", "^", "<", "<=", ">", ">=", "==", "!=", "and", "or"]


def _branches(children):
    return st.one_of(
        st.builds(ast.Unary, st.sampled_from(["-", "+", "not"]), children),
        st.builds(ast.Binary, st.sampled_from(_BINARY_OPS), children, children),
        st.builds(ast.If, children, children, children),
        st.builds(ast.Call, _names, st.lists(children, max_size=3).map(tuple)),
        st.builds(ast.ListExpr, st.lists(children, max_size=3).map(tuple)),
    )


expressions = st.recursive(_leaves, _branches, max_leaves=25)


@pytest.mark.slow
@given(expressions)
@FAST
def test_printed_expressions_parse_back_equal(tree):
    text = format_expr(tree)
    assert parse_set_value(f"x = {text}").value == tree, text


def _unit(names):
    return ast.Unit(tuple(ast.UnitFactor(n, 1) for n in names), "*".join(names))


_units = st.one_of(st.none(), st.lists(st.sampled_from(["kg", "m", "s", "N", "rad"]), min_size=1, max_size=3)
                   .map(_unit))
_descriptions = st.one_of(st.none(), _strings)
_laws = st.one_of(
    st.builds(ast.LawAssign, st.sampled_from(["e", "f", "r"]), expressions),
    st.builds(ast.LawCall, st.sampled_from(["q", "p", "der"]), expressions, expressions),
    st.builds(ast.LawState, _names, _units, _descriptions),
)
_statements = st.one_of(
    st.builds(ast.Param, _names, expressions, _units, _descriptions),
    st.builds(ast.Element, st.sampled_from(["R", "C", "I", "MSe", "TF"]), _names, _descriptions,
              st.lists(_laws, max_size=6).map(tuple)),
    st.builds(ast.Junction, st.sampled_from(["0", "1"]), st.lists(_names, min_size=1, max_size=4).map(tuple)),
    st.builds(ast.BondChain, st.one_of(st.none(), _names),
              st.lists(st.builds(ast.Endpoint, _names, st.one_of(st.none(), st.sampled_from(["p1", "p2"]))),
                       min_size=2, max_size=4).map(tuple)),
    st.builds(ast.Input, _names, _units, expressions, _descriptions),
    st.builds(ast.Output, _names, _units, expressions, _descriptions),
    st.builds(ast.StateDecl, _names, _units, _descriptions, st.lists(_laws, max_size=3).map(tuple)),
    st.builds(ast.FnDef, _names, st.lists(_names, max_size=3).map(tuple), expressions, _descriptions),
    st.builds(ast.Experiment, _names, _descriptions, st.lists(
        st.one_of(st.builds(ast.Setting, _names, expressions, _units),
                  st.builds(ast.Param, _names, expressions, _units, _descriptions)), max_size=3).map(tuple)),
)
files = st.builds(ast.File, st.lists(st.one_of(
    st.builds(ast.Model, _names, _descriptions, st.lists(_statements, max_size=8).map(tuple)),
    st.builds(ast.FnDef, _names, st.lists(_names, max_size=2).map(tuple), expressions, _descriptions),
), max_size=3).map(tuple))


@pytest.mark.slow
@given(files)
@settings(max_examples=max(EXAMPLES // 2, 1), deadline=2000,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
def test_printed_files_parse_back_equal_and_format_stably(file):
    text = format_file(file)
    parsed = parse_text(text, "gen.bg")
    assert parsed == file, text
    assert format_file(parsed, text) == text


# ------------------------------------------------------------- (d) comments anywhere (fmt)

MULTILINE = """\
model Lines
  input u [rad/s] = table(t,
      [0, 1,
       2], [0,
       1, 1])
  param k = 1 [N *
      m / rad] "torsion"
  C chamber "air" : state P [Pa], P(0) = 1,

      der(P) = 2*f,
      e = P
  0 a,
    b
  fn g(x,
       y) = x*y
  experiment e
    outputs = [u,
               k]
  end
end
"""


LONG = """\
fn valve_mdot(ps, pc, Ae, kappa, Rg, T, b_cr) = if ps >= pc then orifice_mdot(ps, pc, Ae, kappa, Rg, T, b_cr) else -orifice_mdot(pc, ps, Ae, kappa, Rg, T, b_cr)
model Long "a model whose lines are too long"
  param a_long_parameter_name = (2/(kappa + 1))^(kappa/(kappa - 1)) [1] "a description long enough to pass the limit"
  input omega [rad/s] = table(t, [0, t1, t2, t3, t4, t5, t6, t7, t8, t9], [0, 0, w_max, w_max, 0, 0, -w_max, -w_max, 0, 0]) "speed"
  R friction "cylinder friction, eqs. (14)-(15)" : e = if abs(f) < v_th then c0*f else if f > 0 then a_up*abs(f)^(1 + n_up)*sign(f) else a_dn*abs(f)^(1 + n_dn)*sign(f), f = if e > 0 then e/c0 else -e/c0
  C chamber "rod-side chamber air, adiabatic, eq. (4)" : state P [Pa], P(0) = P0, der(P) = kappa*P/(V0 + Ar*x_piston)*f, e = P
  0 j_one, j_two, j_three, j_four, j_five, j_six, j_seven, j_eight, j_nine, j_ten, j_eleven, j_twelve
  output y = if a then b else c
end
"""


@st.composite
def commented(draw) -> str:
    """A valid model with comments added at line ends and on lines of their own."""
    text = draw(st.sampled_from([MODEL, MULTILINE, LONG]))
    if draw(st.booleans()):  # comments placed in formatted text land in other places
        text = fmt(text)
    lines = text.splitlines()
    out = []
    for index, line in enumerate(lines):
        if draw(st.integers(0, 3)) == 0:
            out.append(" " * draw(st.integers(0, 6)) + f"# own {index}")
            if draw(st.booleans()):
                out.append("")
        out.append(line + (f"  # end {index}" if draw(st.integers(0, 2)) == 0 else ""))
    return "\n".join(out) + "\n"


@pytest.mark.slow
@given(commented())
@FAST
def test_comments_anywhere_are_kept_in_order_and_format_stably(text):
    original = parse_text(text, "c.bg")
    formatted = format_file(original, text)
    again = parse_text(formatted, "c.bg")
    assert again == original  # comments included, in order
    assert [c.text for c in again.comments] == [c.text for c in original.comments]
    assert format_file(again, formatted) == formatted

"""Dimension checking (the language reference, section 14): a corpus of wrong laws, and no false positive.

Each wrong model combines quantities of known, different dimensions once; the
check must report E210 at that line and name both dimensions. Every model in
``models/`` and every fixture that checks must still check.
"""

from pathlib import Path

import pytest

from bondc.errors import ModelError
from bondc.semantic import load

ROOT = Path(__file__).resolve().parent.parent

BASE = """model M
  param m  = 2    [kg]
  param k  = 800  [N/m]
  param b  = 12   [N*s/m]
  param F0 = 10   [N]
  param v0 = 1    [m/s]
  param t0 = 0.1  [s]
  Se force : e = F0
  I  mass : f = p/m
  C  spring : e = k*q
  R  damper : e = b*f
  1  j
  force -> j
  j -> mass
  j -> spring
  j -> damper
{extra}end
"""


def _model(replace=None, extra=""):
    text = BASE.format(extra="".join(f"  {line}\n" for line in extra.splitlines()))
    for old, new in (replace or {}).items():
        assert old in text
        text = text.replace(old, new)
    return text


def _e210(tmp_path, text):
    path = tmp_path / "m.bg"
    path.write_text(text)
    with pytest.raises(ModelError) as caught:
        load(path)
    found = [d for d in caught.value.diagnostics if d.code == "E210"]
    assert found, [(d.code, d.message) for d in caught.value.diagnostics]
    return found


CORPUS = [
    # (what, changes, extra statements, line, words the message must hold)
    ("a law adding a stiffness to a displacement", {"e = k*q": "e = k + q"}, "", 10, ["kg/s^2", "kg*m/s^2"]),
    ("a resistor law giving a stiffness force", {"e = b*f": "e = k*f"}, "", 11, ["kg*m/s^2", "kg*m/s^3"]),
    ("an output in m/s bound to a force", {}, "output v [m/s] = spring.e", 17, ["m/s", "kg*m/s^2"]),
    ("a comparison of a velocity with a force", {}, "output big = if mass.f > F0 then 1 else 0", 17,
     ["compare", "m/s", "kg*m/s^2"]),
    ("an if whose branches differ", {"e = F0": "e = if t < t0 then F0 else v0"}, "", 8, ["branches", "m/s"]),
    ("an input in N defined as a velocity", {"e = F0": "e = u"}, "input u [N] = v0", 17, ["input 'u'", "m/s"]),
    ("a model state whose rate is a force", {}, "state x [m] : der(x) = spring.e, x(0) = 0", 17, ["der(x)"]),
    ("a time in an exponent", {"e = F0": "e = F0*2^(t)"}, "", 8, ["exponent", "s"]),
    ("a sum of a time and a force in an output", {}, "output s = t + F0", 17, ["add", "s", "kg*m/s^2"]),
    ("a table whose breakpoints are not times", {"e = F0": "e = table(t, [0, v0], [F0, F0])"}, "", 8,
     ["table"]),
    ("a spring initial value in newtons", {"e = k*q": "e = k*q, q(0) = F0"}, "", 10, ["initial", "spring.q"]),
    ("min of a force and a velocity", {"e = F0": "e = min(F0, v0)"}, "", 8, ["min", "m/s"]),
]


@pytest.mark.parametrize("what, changes, extra, line, words", CORPUS, ids=[c[0] for c in CORPUS])
def test_every_dimension_error_of_the_corpus_is_reported_at_its_line(tmp_path, what, changes, extra, line, words):
    found = _e210(tmp_path, _model(changes, extra))
    assert line in [d.span.line for d in found], [(d.span.line, d.message) for d in found]
    message = " ".join(d.message for d in found if d.span.line == line)
    for word in words:
        assert word in message, message


def test_a_wrong_transformer_ratio_is_found_across_the_transformer(tmp_path):
    text = """model Screw
  param lead = 5 [mm]
  param T0 = 1 [N*m]
  param m = 3 [kg]
  Se motor : e = T0
  TF screw : r = m
  I mass : f = p/m
  motor -> screw.p1
  screw.p2 -> mass
  output v [m/s] = mass.f
end
"""
    # the torque of the source crosses the ratio: a mass as the ratio makes the velocity kg-valued
    found = _e210(tmp_path, text)
    assert any("m/s" in d.message for d in found)
    right = tmp_path / "right.bg"
    right.write_text(text.replace("r = m", "r = lead"))
    load(right)


@pytest.mark.parametrize("law", [
    "e = 2*f*b", "e = b*f + 10", "e = step(t, 0.1)*10", "e = b*abs(f)^1.7", "e = b*f*exp(-t/t0)",
    "e = F0*sin(2*pi*50*t)", "e = F0*sign(f)", "e = b*f + (if f < 0 then 0 else F0)",
])
def test_free_numbers_and_fitted_powers_are_not_errors(tmp_path, law):
    path = tmp_path / "m.bg"
    path.write_text(_model({"e = b*f": law}))
    load(path)


def test_the_section_14_examples_that_must_check(tmp_path):
    # 2*f, q/1e-9, step(t, 0.1)*10, x(0) = 0 and h < 0 all check (the reference, section 14)
    text = """model Fourteen
  param h0 = 1 [m]
  Se push : e = step(t, 0.1)*10
  C tank : e = q/1e-9
  R loss : e = 2*f
  I body : f = p
  1 j
  push -> j
  j -> tank
  j -> loss
  j -> body
  state h [m] : der(h) = body.f, h(0) = h0
  output low = if h < 0 then 1 else 0
  state x : der(x) = tank.f, x(0) = 0
end
"""
    path = tmp_path / "m.bg"
    path.write_text(text)
    load(path)


def _checkable():
    files = sorted(ROOT.glob("models/*.bg")) + sorted((ROOT / "tests" / "fixtures").rglob("*.bg"))
    return [f for f in files if "lib" not in f.parts and "data" not in f.parts]


@pytest.mark.slow
@pytest.mark.parametrize("path", _checkable(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_false_positive_on_the_shipped_models_and_fixtures(path):
    try:
        load(path)
    except ModelError as error:
        codes = {d.code for d in error.diagnostics}
        assert "E210" not in codes, [d.message for d in error.diagnostics if d.code == "E210"]


def test_the_statements_of_when_clauses_are_checked_against_what_they_replace(tmp_path):
    """reinit(mass.p, x0) sets a momentum (kg*m/s, from the I law) to a length, F_brake = v1 sets a
    force to a speed: an error at each value; the same statements in the right dimensions check."""
    text = """model Drop
  param m = 2 [kg]
  param x0 = 10 [mm]
  param v1 = 3 [m/s]
  discrete F_brake [N] = 0
  Se g : e = -m*9.81
  I mass : f = p/m
  1 j
  g -> j -> mass
  state h [m] : der(h) = mass.f, h(0) = 1
  when h < 0 then reinit(mass.p, x0), F_brake = v1 end
  output F [N] = F_brake
end
"""
    errors = _e210(tmp_path, text)
    assert [(d.span.line, d.span.column) for d in errors] == [(11, 34), (11, 49)]
    assert "reinit(mass.p, ...) in 'when h < 0' sets kg*m/s to m" in errors[0].message
    assert "F_brake = ... in 'when h < 0' sets kg*m/s^2 to m/s" in errors[1].message
    fixed = text.replace("reinit(mass.p, x0)", "reinit(mass.p, -m*v1)").replace("F_brake = v1", "F_brake = m*9.81")
    path = tmp_path / "fixed.bg"
    path.write_text(fixed)
    graph, diagnostics = load(path)
    assert graph is not None and not [d for d in diagnostics if d.code == "E210"]

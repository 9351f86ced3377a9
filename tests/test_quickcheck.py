"""``bondc.quickcheck``: the equations stage's verdict without sympy, checked against the stage.

The reference is the equations stage itself (``bondc.equations.derive``): wherever the quick
verdict answers, the stage must succeed with no diagnostic and keep the same states; where the
stage reports something (E605, E701, W604, ...), the quick verdict must leave it to the stage.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bondc import quickcheck, semantic
from bondc.causality import assign_causality
from bondc.equations import derive
from bondc.errors import BondcError
from bondc.flatten import ports_of
from bondc.parse import parse_text
from bondc.semantic import build

ROOT = Path(__file__).resolve().parent.parent
CORPUS = sorted(p for p in [*ROOT.glob("models/*.bg"), *ROOT.glob("tests/**/*.bg")] if p.is_file())


def _stage(causal):
    """(states, diagnostic codes) of the equations stage, or (None, codes) where it fails."""
    try:
        ss = derive(causal)
    except BondcError as error:
        return None, tuple(d.code for d in error.diagnostics)
    return tuple(s.name for s in ss.states), tuple(d.code for d in ss.diagnostics)


def _causal(text: str):
    graph, _ = build(parse_text(text, "m.bg"))
    return assign_causality(graph)


def _graphs():
    for path in CORPUS:
        try:
            loaded = semantic.load_files(path)
        except BondcError:
            continue
        own = loaded[0][0].models
        for name in [None] if len(own) <= 1 else [m.name for m in own if not ports_of(m)]:
            try:
                graph, _ = semantic.load(path, model=name, loaded=loaded)
                yield path, name, assign_causality(graph)
            except BondcError:
                continue


@pytest.mark.slow
def test_where_the_quick_verdict_answers_the_equations_stage_agrees_on_every_model():
    answered = unsure = 0
    for path, name, causal in _graphs():
        states = quickcheck.verdict(causal)
        if states is None:
            unsure += 1
            continue
        answered += 1
        assert _stage(causal) == (states, ()), (path, name)
    # the quick verdict is there to answer most models (the flagship among them, below)
    assert answered > 2 * unsure > 0


def test_the_flagship_is_checked_without_sympy():
    path = ROOT / "models" / "electro_pneumatic_hybrid.bg"
    graph, _ = semantic.load(path)
    causal = assign_causality(graph)
    assert quickcheck.verdict(causal) == _stage(causal)[0] == (
        "coupling.q", "shaft.p", "nut.q", "mass.p", "chamber.P", "x_piston")


def _spring(law: str, extra: str = "") -> str:
    """A flow source into a spring whose law is ``law`` (a law of q), with parameters a, b, k."""
    return ("model M\n  param a = 2\n  param b = 3\n  param k = 5\n" + extra +
            f"  Sf s : f = 1\n  C c : e = {law}\n  s -> c\nend\n")


@pytest.mark.parametrize("law", [
    "k*q",
    "k*q/(a - b)",                 # a divisor that is not 0 for every value
    "q/(1 + exp(-q))",
    "sqrt(q)*k",                   # no real value for q < 0: sympy's is complex there, no error
    "q*log(a/b)",
    "if q > 0 then k*q else 0",
    "k*q^3 + atan2(q, a)",
    "mod(q, a)*k + floor(q) + table(q, [0, 1], [0, 2])",
])
def test_laws_that_translate_are_answered(law):
    causal = _causal(_spring(law))
    assert quickcheck.verdict(causal) == ("c.q",)
    assert _stage(causal) == (("c.q",), ())


@pytest.mark.parametrize("law, code", [
    ("q/(1e20 + 1 - 1e20)", "E701"),            # 0 only by rounding: the interval holds 0
    ("q/(9007199254740993 - 9007199254740992 - 1)", "E701"),    # 0 in integers, -1 in doubles
    ("q/(exp(q)*exp(-q) - 1)", "E701"),         # 0 by sympy's rules for exp
    ("q/(sqrt(q^2) - abs(q))", "E701"),
    ("q*(a - a)^(-1)", "E701"),
    ("q*log(b - b)", "E701"),
    ("q*mod(q, a - a)", "E701"),
    ("q*1e309", "E701"),
    ("q*10^400.0", "E701"),
    ("q + sqrt(-1)", "E701"),                   # constants with no real value: complex in sympy
    ("q + log(-2)*0", "E701"),                  # (the 0 does not hide it: numpy's log(-2) is nan)
    ("q*(-8)^(1/3)", "E701"),
])
def test_laws_the_stage_rejects_are_left_to_it(law, code):
    # (a divisor like a - a, an unknown name, a function calling itself: the semantic stage
    # rejects them first)
    causal = _causal(_spring(law))
    states, codes = _stage(causal)
    assert states is None and code in codes         # the case is a real error of the stage
    assert quickcheck.verdict(causal) is None


def _conductance(law: str) -> str:
    """A flow source through a resistor written e = law(f): the causality needs f = law^-1(e)."""
    return ("model M\n  param r = 2\n  param c = 3\n"
            f"  Se s : e = 1\n  R res : e = {law}\n  C cap : e = q/c\n"
            "  0 n\n  1 j\n  s -> j\n  j -> res\n  j -> n\n  n -> cap\nend\n")


def test_a_linear_law_inverted_by_the_stage_is_answered():
    causal = _causal(_conductance("r*f + 0.5*c"))
    assert dict(causal.resistors) == {"res": "conductance"}
    assert quickcheck.verdict(causal) == _stage(causal)[0] == ("cap.q",)
    assert _stage(causal)[1] == ()


@pytest.mark.parametrize("law", [
    "r*f - r*f + 1",            # no f left: E605
    "(r - r)*f",                # its coefficient is 0
    "r*f^3",                    # nonlinear: sympy solves it (or cannot)
    "r*abs(f)*f",
])
def test_a_law_that_is_not_plainly_linear_is_left_to_the_stage(law):
    causal = _causal(_conductance(law))
    assert quickcheck.verdict(causal) is None


def test_a_loop_through_a_laws_reference_is_left_to_the_stage():
    # the modulated source reads an output that reads the effort it sets
    text = ("model M\n  param r = 2\n  output y = s.e\n"
            "  MSe s : e = 1 - 0.5*y\n  R res : e = r*f\n  1 j\n  s -> j\n  j -> res\nend\n")
    causal = _causal(text)
    assert quickcheck.verdict(causal) is None
    assert _stage(causal) == ((), ())        # linear: the stage solves it


def test_cycles_of_the_equations_dependencies():
    assert not quickcheck._has_cycle({"a": {"b", "p"}, "b": {"c"}, "c": set()})
    assert quickcheck._has_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()})
    assert quickcheck._has_cycle({"a": {"a"}})


def test_derivative_causality_and_algebraic_loops_are_left_to_the_stage():
    for name in ("W602_derivative_causality.bg", "I603_algebraic_loop.bg"):
        graph, _ = semantic.load(ROOT / "tests" / "golden" / "stages" / name)
        assert quickcheck.verdict(assign_causality(graph)) is None


def test_check_reports_what_the_stage_reports_through_either_path(tmp_path, capsys):
    from bondc.cli import main

    good, bad = tmp_path / "good.bg", tmp_path / "bad.bg"
    good.write_text(_spring("k*q/(a - b)"))
    bad.write_text(_spring("q/(exp(q)*exp(-q) - 1)"))
    assert main(["check", "--no-cache", str(good)]) == 0
    assert main(["check", "--no-cache", str(bad)]) == 1
    out = capsys.readouterr()
    assert "E701" in out.out + out.err and "division by zero" in out.out + out.err


@pytest.mark.slow
def test_on_fuzz_mutants_the_quick_verdict_agrees_with_the_stage(tmp_path):
    """Mutants of every model (the fuzz harness's: extreme numbers, swapped operators, deleted
    lines): wherever the quick verdict answers, the stage agrees; whatever the stage reports, the
    quick verdict left to it."""
    from test_fuzz import SEED, _place, mutants

    answered = left = 0
    for number, (source, text) in enumerate(mutants(600, SEED + 7)):
        path = _place(tmp_path, source, text, number)
        try:
            loaded = semantic.load_files(path)
            own = loaded[0][0].models
            names = [None] if len(own) <= 1 else [m.name for m in own if not ports_of(m)]
            causals = [assign_causality(semantic.load(path, model=n, loaded=loaded)[0]) for n in names]
        except BondcError:
            continue
        for causal in causals:
            states = quickcheck.verdict(causal)
            truth = _stage(causal)
            if states is None:
                left += 1
            else:
                answered += 1
                assert truth == (states, ()), (source, number)
    assert answered > left > 0

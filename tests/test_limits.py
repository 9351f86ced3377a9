"""Expressions of extreme size: functions that call earlier functions twice stay linear, long
chains parse and derive, and a chain beyond Python's depth is a diagnostic (E005), not a traceback."""

from __future__ import annotations

import sys
import time

import pytest
import sympy

from bondc.cli import main
from bondc.pipeline import derive_file

CHAIN_MODEL = "model M\n  param a = {value}\n  Se s : e = a\n  R r : f = e/2\n  s -> r\nend\n"


def test_functions_that_call_earlier_functions_twice_are_translated_once_per_level(tmp_path):
    """f_i(x) = f_{i-1}(x) + f_{i-1}(x) up to f24: inlined naively, a tree of 2^24 calls (minutes);
    each function is translated once per distinct arguments, and sympy adds equal terms."""
    lines = ["fn f0(x) = x + 1"] + [f"fn f{i}(x) = f{i - 1}(x) + f{i - 1}(x)" for i in range(1, 25)]
    path = tmp_path / "doubling.bg"
    path.write_text("\n".join(lines) + "\n" + CHAIN_MODEL.format(value=1).replace("e = a", "e = f24(a)"))
    start = time.perf_counter()
    ss = derive_file(path, cache=False).state_space
    assert time.perf_counter() - start < 30          # (a guard against the exponential tree, not a benchmark)
    effort = dict(ss.assignments)[sympy.Symbol("b1.e", real=True)]
    a = ss.parameters["a"][0]
    assert sympy.expand(effort - 2 ** 24 * (a + 1)) == 0


@pytest.mark.slow
def test_a_sum_of_thousands_of_terms_is_checked_and_derived(tmp_path):
    path = tmp_path / "long.bg"
    path.write_text(CHAIN_MODEL.format(value="+".join(["1"] * 3000)))
    derived = derive_file(path, cache=False)
    assert derived.graph.parameters["a"].value == 3000.0


@pytest.mark.slow
def test_a_chain_beyond_the_call_depth_is_a_diagnostic(tmp_path, capsys):
    path = tmp_path / "huge.bg"
    path.write_text(CHAIN_MODEL.format(value="+".join(["1"] * 200_000)))
    limit = sys.getrecursionlimit()
    try:
        assert main(["check", str(path)]) == 1
    finally:
        sys.setrecursionlimit(limit)
    err = capsys.readouterr().err
    assert "error[E005]" in err and "Traceback" not in err and "internal error" not in err


def test_functions_whose_expansion_explodes_are_a_diagnostic_at_the_law(tmp_path, capsys):
    """f_i(x) = f_{i-1}(x + 1) + f_{i-1}(2*x): 2^30 calls with distinct arguments, an expression no
    simulator can hold. (The bound is enforced; how soon it is reached is benchmarks' business.)"""
    path = tmp_path / "explode.bg"
    path.write_text(_exploding(30) + CHAIN_MODEL.format(value=1).replace("e = a", "e = f30(a)"))
    assert main(["equations", str(path)]) == 1
    err = capsys.readouterr().err
    assert "error[E319]" in err and "expanding f30() here" in err and "more than 10000 operations" in err
    assert "explode.bg:34:14" in err        # the law that calls f30: 31 fn lines, model, param, then the law


def _exploding(levels: int) -> str:
    """Functions that call the one before twice with different arguments: 2^levels bodies."""
    return "\n".join(["fn f0(x) = x*x"] + [f"fn f{i}(x) = f{i - 1}(x + 1) + f{i - 1}(2*x)"
                                           for i in range(1, levels + 1)]) + "\n"


def _doubling(levels: int) -> str:
    """f_i(x) = f_{i-1}(x) + f_{i-1}(x): 2^levels calls with the same arguments."""
    return "\n".join(["fn f0(x) = x"] + [f"fn f{i}(x) = f{i - 1}(x) + f{i - 1}(x)"
                                         for i in range(1, levels + 1)]) + "\n"


@pytest.mark.parametrize("place, line", [
    ("  param b = 1 + f40(a)\n", "param b = 1 + f40(a)"),                # a parameter
    ("  experiment run\n    t_end = f40(a)\n  end\n", "t_end = f40(a)"),  # a setting
])
def test_doubling_functions_in_constants_are_evaluated_once_per_level(tmp_path, capsys, place, line):
    """The constants' evaluator expanded every call: f40(1) was 2^40 evaluations (check ran for
    hours). Each function is now evaluated once per distinct arguments: f40(1e-9) = 2^40 * 1e-9."""
    path = tmp_path / "doubling.bg"
    path.write_text(_doubling(40) + "model M\n  param a = 1e-9\n" + place
                    + "  Se s : e = a\n  R r : f = e/2\n  s -> r\nend\n")
    assert main(["check", str(path)]) == 0
    from bondc import semantic

    graph, _ = semantic.load(path)
    if "param b" in line:
        assert graph.parameters["b"].value == pytest.approx(1 + 2 ** 40 * 1e-9)
    else:
        assert graph.experiments["run"].t_end == pytest.approx(2 ** 40 * 1e-9)


@pytest.mark.parametrize("place, where", [
    ("  param b = 1 + f30(a)\n", "34:17"),                          # a parameter
    ("  experiment run\n    t_end = f30(a)\n  end\n", "35:13"),    # a setting
    ("  I m : f = p/2, p(0) = f30(a)\n  j -> m\n", "34:25"),       # an initial value
])
def test_exploding_functions_in_constants_are_a_diagnostic_at_the_call(tmp_path, capsys, place, where):
    """2^30 evaluations with distinct arguments: E319 at the call (it ran without end)."""
    path = tmp_path / "explode.bg"
    path.write_text(_exploding(30) + "model M\n  param a = 1e-3\n" + place
                    + "  Se s : e = a\n  R r : f = e/2\n  1 j\n  s -> j\n  j -> r\nend\n")
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"explode.bg:{where}: error[E319]: expanding f30() here" in err
    assert "Traceback" not in err


def test_many_constants_calling_expanding_functions_share_one_budget(tmp_path, capsys):
    """300 parameters each calling a function of 2^9 distinct bodies (about 6000 operations each):
    the model's constants may write out a million operations in all; one E319, at the call that
    goes beyond, and nothing for the parameters after it (they have no value either)."""
    path = tmp_path / "many.bg"
    path.write_text(_exploding(9) + "model M\n  param a = 1e-3\n"
                    + "".join(f"  param b{i} = f9(a*{i + 1})\n" for i in range(300))
                    + "  Se s : e = " + " + ".join(f"b{i}" for i in range(300)) + "\n  R r : f = e/2\n"
                    + "  s -> r\nend\n")
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("error[") == 1
    assert "error[E319]: expanding f9() here takes the model's function calls beyond 1000000 operations" in err


def _components(levels: int) -> str:
    """C_i holds two C_{i-1} in series: 2^levels copies of C0."""
    parts = ["model C0\n  port a, b\n  R r : e = 2*f\n  1 j\n  a -> j -> b\n  j -> r\nend\n"]
    for i in range(1, levels + 1):
        parts.append(f"model C{i}\n  port a, b\n  C{i - 1} x\n  C{i - 1} y\n  0 n\n  a -> x.a\n  x.b -> n\n"
                     f"  n -> y.a\n  y.b -> b\nend\n")
    parts.append(f"model Top\n  Se s : e = 1\n  C{levels} c\n  R load : e = f\n  s -> c.a\n  c.b -> load\n"
                 "end\n")
    return "\n".join(parts)


def test_components_whose_flattening_explodes_are_a_diagnostic_at_the_instance(tmp_path, capsys):
    """40 levels of components that each hold two of the one before: 2^40 copies (check ran until
    it ran out of memory). E319 at the instance in the model checked."""
    path = tmp_path / "nested.bg"
    path.write_text(_components(40))
    assert main(["check", "--model", "Top", str(path)]) == 1
    err = capsys.readouterr().err
    assert "nested.bg:451:3: error[E319]: instance 'c' of 'C40' expands to more than 20000 statements" in err
    assert err.count("error[") == 1

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


@pytest.mark.slow
def test_functions_whose_expansion_explodes_are_a_diagnostic_at_the_law(tmp_path, capsys):
    """f_i(x) = f_{i-1}(x + 1) + f_{i-1}(2*x): 2^30 calls with distinct arguments, an expression no
    simulator can hold."""
    lines = ["fn f0(x) = x*x"] + [f"fn f{i}(x) = f{i - 1}(x + 1) + f{i - 1}(2*x)" for i in range(1, 31)]
    path = tmp_path / "explode.bg"
    path.write_text("\n".join(lines) + "\n" + CHAIN_MODEL.format(value=1).replace("e = a", "e = f30(a)"))
    start = time.perf_counter()
    assert main(["equations", str(path)]) == 1
    assert time.perf_counter() - start < 60
    err = capsys.readouterr().err
    assert "error[E701]" in err and "expanding f30() here" in err and "more than 20000 times" in err
    assert "explode.bg:34:14" in err        # the law that calls f30: 31 fn lines, model, param, then the law

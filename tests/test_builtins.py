"""Every built-in function and every element kind is handled by every stage (issue 11, item 1).

The built-ins are described once (:mod:`bondc.builtins`); each is used in an
output of a small model and simulated (sympy translation, dimension check, the
numpy and C code), evaluated as a constant where it may be one, highlighted by
the report's lexer, and printed back by ``bondc fmt`` — each against a Python
reference of the function.
"""

import math

import numpy as np
import pytest

from bondc import causality
from bondc.analysis import energy
from bondc.builtins import BUILTINS
from bondc.errors import ModelError
from bondc.evaluate import evaluate
from bondc.fmt import fmt
from bondc.model import KINDS
from bondc.parse import parse_set_value
from bondc.report import lexer
from bondc.semantic import load
from bondc.pipeline import simulate_file as run


def _pwm(t, f, d):
    phase = t * f - math.floor(t * f)
    return 1.0 if phase < d else 0.0


# name -> (call of t, reference of t, constant call, its value)
CASES = {
    "abs": ("abs(t - 0.5)", lambda t: abs(t - 0.5), "abs(-2.5)", 2.5),
    "sign": ("sign(t - 0.5)", lambda t: float(np.sign(t - 0.5)), "sign(-3)", -1.0),
    "sqrt": ("sqrt(t + 1)", lambda t: math.sqrt(t + 1), "sqrt(16)", 4.0),
    "exp": ("exp(t)", math.exp, "exp(0)", 1.0),
    "log": ("log(t + 1)", lambda t: math.log(t + 1), "log(1)", 0.0),
    "sin": ("sin(t)", math.sin, "sin(0)", 0.0),
    "cos": ("cos(t)", math.cos, "cos(0)", 1.0),
    "tan": ("tan(0.5*t)", lambda t: math.tan(0.5 * t), "tan(0)", 0.0),
    "tanh": ("tanh(t)", math.tanh, "tanh(0)", 0.0),
    "atan": ("atan(t)", math.atan, "atan(1)", math.pi / 4),
    "atan2": ("atan2(t - 0.5, 1)", lambda t: math.atan2(t - 0.5, 1), "atan2(1, 1)", math.pi / 4),
    "min": ("min(t, 0.5, 0.7)", lambda t: min(t, 0.5, 0.7), "min(3, 1, 2)", 1.0),
    "max": ("max(t, 0.5)", lambda t: max(t, 0.5), "max(3, 4)", 4.0),
    "table": ("table(t, [0, 0.5, 1], [0, 2, 1])", lambda t: float(np.interp(t, [0, 0.5, 1], [0, 2, 1])),
              "table(0.25, [0, 0.5], [0, 2])", 1.0),
    "step": ("step(t, 0.5)", lambda t: 1.0 if t >= 0.5 else 0.0, "step(1, 0.5)", 1.0),
    "pwm": ("pwm(t, 2, 0.25)", lambda t: _pwm(t, 2, 0.25), None, None),
    "mod": ("mod(t, 0.3)", lambda t: t - 0.3 * math.floor(t / 0.3), "mod(-1, 0.3)", -1 - 0.3 * math.floor(-1 / 0.3)),
    "floor": ("floor(3*t)", lambda t: float(math.floor(3 * t)), "floor(-2.5)", -3.0),
    # (not at t = 0, where 3*t is a whole number: at a switch the run reports the value just after it)
    "ceil": ("ceil(3*t - 0.1)", lambda t: float(math.ceil(3 * t - 0.1)), "ceil(-2.5)", -2.0),
}
SPECIAL = {"coulomb", "csv"}     # only in an R law / needs a data file: tested in test_engine, test_result_units


def test_every_builtin_has_a_case_here():
    assert set(CASES) | SPECIAL == set(BUILTINS)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_every_builtin_is_simulated_in_numpy_and_c_code(name, tmp_path):
    call, reference, _, _ = CASES[name]
    path = tmp_path / "m.bg"
    path.write_text(f"model B\n  Se s : e = 1\n  C c : e = q\n  s -> c\n  output y = {call}\nend\n")
    grid = np.arange(0.0, 0.99, 0.07)          # no sample falls on a discontinuity
    for native in ("1", "0"):
        with pytest.MonkeyPatch.context() as patch:
            patch.setenv("BONDC_NATIVE", native)
            result = run(path, t_end=0.98, dt=0.07)
        assert result.complete, result.message
        expected = [reference(t) for t in result.t]
        assert np.allclose(result.outputs["y"], expected, rtol=1e-12, atol=1e-12), (name, native)
        assert np.allclose(result.t, grid)


@pytest.mark.parametrize("name", sorted(n for n in CASES if CASES[n][2] is not None))
def test_every_constant_builtin_evaluates_in_a_parameter(name, tmp_path):
    _, _, call, value = CASES[name]
    assert evaluate(parse_set_value(f"x = {call}", "<test>").value) == pytest.approx(value, rel=1e-15, abs=1e-15)
    path = tmp_path / "m.bg"
    path.write_text(f"model B\n  param k = {call}\n  Se s : e = k\n  C c : e = q\n  s -> c\nend\n")
    graph, _ = load(path)
    assert graph.parameters["k"].value == pytest.approx(value, rel=1e-15, abs=1e-15)


@pytest.mark.parametrize("name", sorted(n for n, b in BUILTINS.items() if not b.constant))
def test_a_signal_builtin_in_a_parameter_is_an_error_at_the_call(name, tmp_path):
    args = ", ".join(["1"] * BUILTINS[name].arity[0]) if name != "csv" else '"f.csv", "x"'
    path = tmp_path / "m.bg"
    path.write_text(f"model B\n  param k = {name}({args})\n  Se s : e = k\n  C c : e = q\n  s -> c\nend\n")
    with pytest.raises(ModelError) as caught:
        load(path)
    assert caught.value.diagnostics[0].span.line == 2


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_every_builtin_checks_its_arity_and_is_highlighted_and_formatted(name, tmp_path):
    low, high = BUILTINS[name].arity
    args = ", ".join(["t"] * (low - 1))
    path = tmp_path / "m.bg"
    path.write_text(f"model B\n  Se s : e = 1\n  C c : e = q\n  s -> c\n  output y = {name}({args})\nend\n")
    with pytest.raises(ModelError) as caught:
        load(path)
    assert any(d.code == "E306" and d.span.line == 5 for d in caught.value.diagnostics)
    assert name in lexer.BUILTINS
    text = f"model B\n  output y = 2*{name}({', '.join(['t'] * low)})\nend\n"
    assert fmt(text) == text


def test_every_element_kind_is_known_to_every_stage():
    assert set(KINDS) == set(causality.ROLES) == set(energy.ROLES) == set(lexer.ELEMENT_KINDS)
    for name, kind in KINDS.items():
        assert kind.ports in (1, 2) and kind.laws
        if kind.storage:
            assert kind.state in ("q", "p") and causality.ROLES[name] == "storage"
        if kind.source:
            assert energy.ROLES[name] == "source"

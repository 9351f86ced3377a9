"""bondc.jacobian: the forward-mode chain rule through straight-line assignments, with symbolic
entries (the generated module's Jacobian) and numeric ones (the linearisation), against the
derivative of the fully expanded expression (sympy's diff, an independent computation)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy

from bondc.jacobian import NUMERIC, SYMBOLIC, Sensitivities

x, y, z = STATES = sympy.symbols("x y z", real=True)
OPERATIONS = (lambda a, b: a * b, lambda a, b: a + 2 * b, lambda a, b: sympy.sin(a) - b ** 2,
              lambda a, b: a / (2 + b ** 2), lambda a, b: sympy.exp(-a) * b)


def _program(seed: int, length: int = 12):
    """A random straight-line program over x, y, z: [(symbol, expression of earlier symbols)]."""
    rng = np.random.default_rng(seed)
    known = list(STATES)
    program = []
    for i in range(length):
        a, b = (known[int(k)] for k in rng.integers(0, len(known), size=2))
        symbol = sympy.Symbol(f"a{i}", real=True)
        program.append((symbol, OPERATIONS[int(rng.integers(len(OPERATIONS)))](a, b)))
        known.append(symbol)
    return program


def _rows(program, algebra, partial_of):
    sensitivities = Sensitivities({state: j for j, state in enumerate(STATES)}, algebra)
    for symbol, expr in program:
        ordered = sorted(expr.free_symbols, key=lambda s: s.name)
        sensitivities.rows[symbol] = sensitivities.chain(
            (s, lambda s=s, expr=expr: partial_of(expr, s)) for s in ordered)
    return sensitivities


@pytest.mark.parametrize("seed", range(8))
def test_the_chain_rule_gives_the_derivative_of_the_expanded_program(seed):
    program = _program(seed)
    point = {x: 0.3, y: -0.7, z: 1.1}
    expanded: dict = {}
    for symbol, expr in program:
        expanded[symbol] = expr.xreplace(expanded)
    last, _ = program[-1]
    expected = [float(sympy.diff(expanded[last], state).xreplace(point)) for state in STATES]

    numbers: dict = dict(point)
    for symbol, expr in program:
        numbers[symbol] = float(expr.xreplace(numbers))
    numeric = _rows(program, NUMERIC, lambda expr, s: float(sympy.diff(expr, s).xreplace(numbers)))
    row = numeric.row(last)
    got = [row.get(j, 0.0) for j in range(len(STATES))]
    assert got == pytest.approx(expected, rel=1e-12, abs=1e-12)

    symbolic = _rows(program, SYMBOLIC, lambda expr, s: sympy.diff(expr, s))
    entries = symbolic.row(last)
    substituted = [float(entries[j].xreplace(expanded).xreplace(point)) if j in entries else 0.0
                   for j in range(len(STATES))]
    assert substituted == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_a_partial_is_computed_only_for_a_symbol_that_depends_on_a_column():
    sensitivities = Sensitivities({x: 0}, NUMERIC)
    asked = []

    def partial(name, value):
        def computed():
            asked.append(name)
            return value
        return computed

    row = sensitivities.chain([(x, partial("x", 2.0)), (y, partial("y", 5.0))])
    assert row == {0: 2.0} and asked == ["x"]


def test_numeric_entries_keep_every_partial_so_that_an_infinite_slope_shows():
    """A zero partial times an infinite sensitivity is nan: the linearisation reports it (E941)
    rather than a finite Jacobian; the symbolic algebra drops a partial that is the number 0."""
    numeric = Sensitivities({x: 0}, NUMERIC)
    numeric.rows[y] = {0: math.inf}
    assert math.isnan(numeric.chain([(y, lambda: 0.0)])[0])
    symbolic = Sensitivities({x: 0}, SYMBOLIC)
    assert symbolic.chain([(x, lambda: sympy.Integer(0))]) == {}

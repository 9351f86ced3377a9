"""The built-in functions of the ``.bg`` language, described once (the language reference, sections 7
and 13).

Every stage reads this table: the semantic checks take the arities from it, the
report's lexer highlights its names, and ``tests/test_builtins.py`` checks that
the translator to sympy, the constant evaluator, the dimension check and the
code printers handle every entry. ``constant``: the function may appear in a
parameter, setting or initial value (evaluated when the model is checked);
``signal``: its discontinuities are located as events when it appears in a law.

>>> BUILTINS["atan2"].arity, BUILTINS["min"].arity
((2, 2), (2, None))
>>> sorted(name for name, b in BUILTINS.items() if not b.constant)
['coulomb', 'csv', 'pwm']
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class Builtin:
    name: str
    arity: tuple[int, int | None]       # at least, at most (None: no limit)
    constant: bool                      # allowed in parameters (evaluated at check time)
    discontinuous: bool                 # a switch the simulator locates
    summary: str


def _b(name, low, high, constant, discontinuous, summary) -> tuple[str, Builtin]:
    return name, Builtin(name, (low, high), constant, discontinuous, summary)


BUILTINS: Mapping[str, Builtin] = dict([
    _b("abs", 1, 1, True, True, "absolute value"),
    _b("sign", 1, 1, True, True, "-1, 0 or 1"),
    _b("sqrt", 1, 1, True, False, "square root"),
    _b("exp", 1, 1, True, False, "exponential"),
    _b("log", 1, 1, True, False, "natural logarithm"),
    _b("sin", 1, 1, True, False, "sine (radians)"),
    _b("cos", 1, 1, True, False, "cosine (radians)"),
    _b("tan", 1, 1, True, False, "tangent (radians)"),
    _b("tanh", 1, 1, True, False, "hyperbolic tangent"),
    _b("atan", 1, 1, True, False, "arc tangent"),
    _b("atan2", 2, 2, True, False, "atan2(y, x): the angle of (x, y)"),
    _b("min", 2, None, True, True, "the smallest argument"),
    _b("max", 2, None, True, True, "the largest argument"),
    _b("table", 3, 3, True, True, "table(x, [x0, ...], [v0, ...]): piecewise linear, held at the ends"),
    _b("step", 2, 2, True, True, "step(t, t0): 0 before t0, 1 from it"),
    _b("coulomb", 2, 3, False, True, "coulomb(v, F_slide, F_static): dry friction that sticks"),
    _b("pwm", 3, 3, False, True, "pwm(t, f, d): 1 on [k/f, (k + d)/f), else 0"),
    _b("mod", 2, 2, True, True, "mod(x, y): the remainder with the sign of y"),
    _b("floor", 1, 1, True, True, "the largest integer not above x"),
    _b("ceil", 1, 1, True, True, "the smallest integer not below x"),
    _b("csv", 2, 2, False, False, 'csv("file", "column"): a measured signal of time'),
])

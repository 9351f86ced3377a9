"""Forward-mode derivatives through a straight-line sequence of assignments: the one
implementation of the chain rule behind the generated module's analytic Jacobian
(:mod:`bondc.codegen.jacobian`, whose entries are sympy expressions printed into the module) and
the linearisation (:mod:`bondc.analysis.linearize`, whose entries are numbers at an operating
point).

Each symbol's sensitivity is a sparse row ``{column: d symbol / d column}`` (the columns are the
independent variables: the states, and for the linearisation the inputs too), kept sparse so that
a chain of N sections has rows of a few entries each where dense rows would take N^2. An
assignment ``a = E(s1, s2, ...)`` gets the row ``sum_s dE/ds * row(s)`` (:meth:`Sensitivities.chain`);
an algebraic block ``R(z) = 0`` gets ``dz/dx = -(dR/dz)^-1 dR/dx`` from the rows
``dR/dx`` that :meth:`Sensitivities.chain` gives over its other symbols (the two callers solve
that system their own way: in the generated code, numerically at the point).

Takes the independent variables (``seeds``) and, per assignment in order, its partial derivatives
(computed only for the symbols whose row is not empty); returns the rows.

>>> import sympy
>>> x, y, a, b = sympy.symbols("x y a b", real=True)
>>> symbolic = Sensitivities({x: 0, y: 1}, SYMBOLIC)
>>> symbolic.rows[a] = symbolic.chain([(x, lambda: 2 * x), (y, lambda: sympy.Integer(3))])   # a = x^2 + 3y
>>> symbolic.chain([(a, lambda: sympy.Integer(-1))])                                         # b = -a
{0: -2*x, 1: -3}
>>> numeric = Sensitivities({x: 0, y: 1}, NUMERIC)
>>> numeric.rows[a] = numeric.chain([(x, lambda: 2.0), (y, lambda: 3.0)])
>>> numeric.chain([(a, lambda: -1.0), (b, lambda: 5.0)])       # b has no row: its partial is not computed
{0: -2.0, 1: -3.0}
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Generic, Hashable, Iterable, Mapping, TypeVar

import sympy

Entry = TypeVar("Entry")


@dataclass(frozen=True)
class Algebra(Generic[Entry]):
    """The arithmetic of the entries: the seed's entry, whether a partial is skipped as zero, a
    partial times an entry, and a column's sum so far (None: none yet) plus a term."""

    one: Entry
    is_zero: Callable[[Entry], bool]
    times: Callable[[Entry, Entry], Entry]
    plus: Callable[[Entry | None, Entry], Entry]


def _times(a: sympy.Expr, b: sympy.Expr) -> sympy.Expr:
    """``a * b``; a number (not 0 or 1) times a name is built as the product sympy would build,
    without its flattening (most products of a large model's Jacobian are -1 times a name)."""
    if a.is_Number and b.is_Symbol and a.is_finite and not (a == 0 or a == 1):
        return sympy.Mul._from_args((a, b))
    return a * b


def _symbolic_times(partial: sympy.Expr, entry: sympy.Expr) -> sympy.Expr:
    # (sympy's 0 + x and 1*x are x: skip building them, most partials of a bond graph are 1)
    if partial.is_Number and partial == 1:
        return entry
    if entry.is_Number and entry == 1:
        return partial
    return _times(partial, entry)


#: Entries that are sympy expressions (the generated module's Jacobian): a partial that is the
#: number 0 adds nothing.
SYMBOLIC: Algebra[sympy.Expr] = Algebra(
    one=sympy.Integer(1),
    is_zero=lambda partial: bool(partial.is_Number and partial == 0),
    times=_symbolic_times,
    plus=lambda total, term: term if total is None else total + term)

#: Entries that are floats (the linearisation at a point): every partial counts (a 0 times an
#: infinite entry is nan, which the linearisation reports), and a sum starts from 0.0.
NUMERIC: Algebra[float] = Algebra(
    one=1.0,
    is_zero=lambda partial: False,
    times=lambda partial, entry: partial * entry,
    plus=lambda total, term: (0.0 if total is None else total) + term)


class Sensitivities(Generic[Entry]):
    """Sparse forward-mode sensitivities: ``rows[symbol]`` is ``{column: d symbol / d column}``.

    ``seeds``: each independent variable's column (its row is ``{column: one}``).
    """

    def __init__(self, seeds: Mapping[Hashable, int], algebra: Algebra[Entry]):
        self.algebra = algebra
        self.rows: dict[Any, dict[int, Entry]] = {symbol: {column: algebra.one} for symbol, column in seeds.items()}

    def row(self, symbol: Hashable) -> dict[int, Entry]:
        """The symbol's row ({} for a symbol that depends on no column)."""
        return self.rows.get(symbol, {})

    def chain(self, partials: Iterable[tuple[Hashable, Callable[[], Entry]]]) -> dict[int, Entry]:
        """The row of an expression from ``(symbol, its partial derivative)`` of each symbol it
        reads, in the order given: ``sum over symbols of partial * row(symbol)``, column by column.
        A partial is computed (called) only for a symbol whose row is not empty."""
        algebra = self.algebra
        total: dict[int, Entry] = {}
        for symbol, partial in partials:
            row = self.rows.get(symbol)
            if not row:
                continue
            factor = partial()
            if algebra.is_zero(factor):
                continue
            for column, entry in row.items():
                total[column] = algebra.plus(total.get(column), algebra.times(factor, entry))
        return total

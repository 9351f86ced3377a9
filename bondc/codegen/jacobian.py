"""The generated module's analytic Jacobian: a :class:`~bondc.codegen.plan._Plan`'s frozen
statements -> its Jacobian statements and entries, symbolically, by the forward-mode chain
rule of :mod:`bondc.jacobian` (see :mod:`bondc.codegen.emit`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import sympy

from bondc.codegen.statements import _assign, _copied, _Statement
from bondc.jacobian import SYMBOLIC, Sensitivities
from bondc.symbolic import partial_derivative

if TYPE_CHECKING:
    from bondc.codegen.plan import _Plan


def _ordered(symbols) -> list:
    """``sorted(symbols, key=sympy.default_sort_key)``: by name, which is that order for plain
    symbols, at a tenth of its cost; by sympy's key where two share a name (a Dummy)."""
    ordered = sorted(symbols, key=lambda symbol: symbol.name)
    if any(a.name == b.name for a, b in zip(ordered, ordered[1:])) or any(s.is_Dummy for s in ordered):
        return sorted(symbols, key=sympy.default_sort_key)
    return ordered


def _forward_jacobian(plan: _Plan, state_symbols) -> None:
    """Sparse forward-mode derivatives of the frozen statements (see the module docstring)."""
    column = {s: j for j, s in enumerate(state_symbols)}
    sensitivities = Sensitivities(column, SYMBOLIC)
    rows = sensitivities.rows        # symbol -> {column: expr}
    statements = []
    counter = [0]

    def row_of(expr, exclude=()):
        accumulated = sensitivities.chain(
            (symbol, lambda symbol=symbol: partial_derivative(expr, symbol, secant_kinks=True))
            for symbol in _ordered(expr.free_symbols - set(exclude)))
        return {j: v for j, v in sorted(accumulated.items()) if not (v.is_Number and v == 0)}

    named_as: dict = {}             # expression -> the symbol it was named first

    def name_entries(entries):
        # an entry equal to one named before is that symbol (the statements are straight-line and
        # assign each symbol once, so the same expression has the same value): a chain's sections
        # repeat -k and 1/m, and then the products of those, thousands of times
        named = {}
        for j, value in entries.items():
            if value.is_Number or value.is_Symbol:
                named[j] = value
                continue
            symbol = named_as.get(value)
            if symbol is None:
                symbol = named_as[value] = sympy.Symbol(f"_d{counter[0]}", real=True)
                counter[0] += 1
                statements.append(_assign(symbol, value))
            named[j] = symbol
        return named

    for statement in plan.statements:
        statements.append(statement)
        if statement.kind == "assign":
            (symbol,), (expr,) = statement.defines, statement.exprs
            source = _copied(statement)
            # a copy has its source's row (the same entries row_of would build)
            rows[symbol] = sensitivities.row(source) if source is not None else name_entries(row_of(expr))
        else:   # an algebraic block: dz/dx = -(dR/dz)^-1 dR/dx
            number = statement.data["number"]
            unknowns = statement.defines
            residuals = statement.data["residuals"]
            rz = [[partial_derivative(r, z) for z in unknowns] for r in residuals]
            statement.data["slopes"] = [v for row in rz for v in row]   # dR/dz: the C loop's Newton steps too
            rx = {}
            for i, r in enumerate(residuals):
                for j, value in row_of(r, exclude=unknowns).items():
                    rx[(i, j)] = value
            columns = sorted({j for _, j in rx})
            outputs, cells = {}, {}
            for l, z in enumerate(unknowns):
                rows[z] = {}
                for j in columns:
                    symbol = sympy.Symbol(f"_Dz{number}_{l}_{j}", real=True)
                    outputs[symbol] = f"_Dz{number}[{l}, {j}]"
                    cells[symbol] = (l, j)
                    rows[z][j] = symbol
            exprs = statement.data["slopes"] + [rx[key] for key in sorted(rx)]
            statements.append(_Statement("block_jac", tuple(outputs), exprs, frozenset(),
                                         {"number": number, "size": len(unknowns), "rx_keys": sorted(rx),
                                          "texts": outputs, "cells": cells, "states": len(column)}))
    entries = {}
    for k, expr in enumerate(plan.derivatives):
        for j, value in row_of(expr).items():
            entries[(k, j)] = value
    plan.jacobian_statements = statements
    plan.jacobian_entries = entries

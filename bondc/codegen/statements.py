"""The statements of a generated function body and their common subexpressions: a
:class:`_Statement` per assignment, algebraic loop or loop sensitivity, in causal order, and
:func:`_cse` (sympy's tree cse without its pre-pass, and ``1/x``, ``-x`` of a name kept inline).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import sympy


@dataclass
class _Statement:
    """One step of a generated function body, in causal order."""

    kind: str                        # "assign", "block", "block_jac"
    defines: tuple                   # symbols it defines
    exprs: list                      # expressions that go through cse (reduced in place)
    uses: frozenset = frozenset()    # further symbols it reads outside exprs
    data: dict = field(default_factory=dict)


def _assign(symbol, expr) -> _Statement:
    return _Statement("assign", (symbol,), [expr])


def _copied(statement: _Statement):
    """The symbol a statement only copies (``b3_f = b2_f``), or None."""
    if statement.kind == "assign" and isinstance(statement.exprs[0], sympy.Symbol):
        return statement.exprs[0]
    return None


def _hide_piecewise(expr, pieces: dict):
    """``expr`` with every outermost Piecewise replaced by a placeholder symbol (recorded in ``pieces``)."""
    if isinstance(expr, sympy.Piecewise):
        if expr not in pieces:
            pieces[expr] = sympy.Symbol(f"_pw{len(pieces)}", real=True)
        return pieces[expr]
    if expr.is_Atom or not expr.args:
        return expr
    args = [_hide_piecewise(arg, pieces) if isinstance(arg, sympy.Basic) else arg for arg in expr.args]
    if all(a is b for a, b in zip(args, expr.args)):
        return expr
    return expr.func(*args)


def _kept_inline(expr) -> bool:
    """``1/x`` or ``-x`` of a name: never a temporary of :func:`_cse`."""
    if expr.is_Pow:
        return expr.exp is sympy.S.NegativeOne and expr.base.is_Symbol
    return expr.is_Mul and len(expr.args) == 2 and expr.args[0] is sympy.S.NegativeOne and expr.args[1].is_Symbol


def _cse(exprs: list):
    """Common subexpressions of ``exprs``: sympy's tree cse (``cse_main.tree_cse``, without the
    ``opt_cse`` pre-pass), written again with two differences:

    - a node none of whose arguments changed is kept as it is. sympy's ``_rebuild`` compares the
      list of rebuilt arguments with the tuple of the old ones, which always differ, so it rebuilds
      (and re-evaluates) every node of every expression: on a large model that was most of the pass;
    - the reciprocal of a name (``1/m``) and its negation (``-x``) are never temporaries: ``p/m``
      stays a division and ``vs - x`` a subtraction, as the law writes them. ``p*(1/m)`` differs
      from ``p/m`` in the last bit, and is not finite where ``1/m`` overflows (a mass of 1e-320
      kg) although ``p/m`` may be; a temporary ``-x`` changes the order of a sum's additions.

    The pre-pass (common subsets of sums' and products' arguments, negations) costs more than the
    rest of code generation on a large model and grows faster than linearly; equal subtrees are
    still shared. ``tests/test_codegen.py`` checks that the result is sympy's, reciprocals and
    negations of names put back, on every model of the corpus.
    """
    from sympy.utilities.iterables import iterable

    seen, to_eliminate, excluded = set(), set(), set()

    def find_repeated(expr):
        if not isinstance(expr, sympy.Basic) or isinstance(expr, sympy.RootOf):
            return
        if expr.is_Atom or expr.is_Order:
            if expr.is_Symbol:
                excluded.add(expr.name)
            return
        if not iterable(expr):
            if expr in seen:
                if not _kept_inline(expr):
                    to_eliminate.add(expr)
                return
            seen.add(expr)
        for arg in expr.args:
            find_repeated(arg)

    for expr in exprs:
        find_repeated(expr)
    symbols = (s for s in sympy.numbered_symbols("_c", real=True) if s.name not in excluded)
    replacements: list = []
    subs: dict = {}

    def rebuild(expr):
        if not isinstance(expr, sympy.Basic) or not expr.args:
            return expr
        if not iterable(expr) and expr in subs:
            return subs[expr]
        args = expr.args
        new_args = [rebuild(arg) for arg in args]
        new = expr.func(*new_args) if any(a is not b for a, b in zip(new_args, args)) else expr
        if not iterable(expr) and expr in to_eliminate:
            symbol = next(symbols)
            subs[expr] = symbol
            replacements.append((symbol, new))
            return symbol
        return new

    return replacements, [rebuild(expr) for expr in exprs]

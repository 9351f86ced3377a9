"""The sympy printer of generated modules: sympy expression -> numpy source text.

:class:`BondcPrinter` is a :class:`sympy.printing.numpy.NumPyPrinter` that

- prints every symbol through a name map (a state ``mass.p`` is the local
  variable ``mass_p``, a mode ``m[3]``) and refuses a symbol it does not know;
- prints floats exactly (``repr``), ``numpy`` as ``np``;
- prints powers as ``x**2``, ``1/x``, ``np.sqrt(x)`` and, for a non-integer
  exponent, ``np.power(x, a)`` (nan for a negative base, never a complex number);
- prints the bondc signals ``Table``/``Step``/``Csv``/``External`` as calls of
  ``bondc.runtime``'s ``table``/``step``/``csv_signal``/``external_signal``;
- prints a ``Piecewise`` whose conditions only test modes (the frozen laws)
  as a Python conditional expression, so only the active branch is evaluated;
  any other ``Piecewise`` as nested ``np.where``; ``Min``/``Max`` as
  ``np.minimum``/``np.maximum``.

Dispatch is by sympy's ``_print_<Class>`` methods; an expression the printer
does not know raises ``unsupported`` instead of printing something wrong.

>>> import sympy
>>> x = sympy.Symbol("mass.p", real=True)
>>> BondcPrinter({x: "mass_p"}).doprint(sympy.sqrt(x) + x**2 / 3)
'np.sqrt(mass_p) + (1/3)*mass_p**2'
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import sympy
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.precedence import precedence



class UnsupportedExpression(Exception):
    """An expression the code generator cannot print."""


def negatives_last(expr) -> list:
    """A sum's terms in sympy's own (deterministic) argument order, those that print with a minus
    sign last: ``t - 0.1``. Sorting every sum for display costs most of a large model's printing."""
    return sorted(expr.args, key=lambda term: term.as_coeff_Mul()[0].is_negative is True)


class QuickPrinting:
    """A quick path for sympy printers (see :meth:`quick`); ``_quick_name`` gives a name's text
    or None where the printer would refuse it."""

    def _quick_name(self, symbol):
        return self.names.get(symbol)

    def quick(self, expr):
        """``doprint(expr)`` for the shapes most of a bond graph's laws have, without sympy's
        printing machinery (its per-call setup, dispatch and precedence tests cost more than the rest
        of a large model's code generation); None for any other shape, which ``doprint`` prints.

        The shapes: a name; a finite Integer or Float; a power of a name to an integer; a product
        of those with at most one number in front; a sum of any of these. The text is what sympy's
        code printers write for them (``CodePrinter._print_Mul``, ``StrPrinter._print_Add``, with
        this printer's numbers and powers; sympy's ``StrPrinter._print_Mul`` writes the same for
        them): ``tests/test_codegen.py`` compares the two on every expression of every model of
        the test corpus. In these shapes no factor or term ever needs
        parentheses: names and positive numbers are atoms, a power of a name binds tighter than a
        product, and a product (even with a minus sign) binds tighter than a sum.
        """
        if expr.is_Add:
            parts = []
            for term in negatives_last(expr):
                if term.is_Add:
                    return None
                text = self._quick_factor(term) if not term.is_Mul else self._quick_product(term)
                if text is None:
                    return None
                if text[0] == "-":
                    parts += ("-", text[1:])
                else:
                    parts += ("+", text)
            sign = parts.pop(0)
            return ("" if sign == "+" else "-") + " ".join(parts)
        if expr.is_Mul:
            return self._quick_product(expr)
        return self._quick_factor(expr, nested=False)

    def _quick_factor(self, expr, nested=True):
        if expr.is_Symbol:
            return self._quick_name(expr)
        if expr.is_Integer or (expr.is_Float and expr.is_finite):
            # as doprint would: inside a product or sum the number is printed one level down
            # (sympy's str printer writes a Float's trailing zeros only at the top level)
            self._print_level += nested
            try:
                return self._print(expr)
            finally:
                self._print_level -= nested
        if expr.is_Pow and expr.exp.is_Integer and expr.base.is_Symbol and self._quick_name(expr.base) is not None:
            return self._print_Pow(expr)
        return None

    def _quick_product(self, expr):
        """``CodePrinter._print_Mul`` for a product of names and integer powers of names with an
        Integer or Float in front (the only number a sympy product can hold, always its first
        argument)."""
        factors = list(expr.args)
        sign = ""
        first = factors[0]
        if first is sympy.S.One or any(factor.is_Number for factor in factors[1:]):
            return None     # an unevaluated product: sympy's str printer writes it its own way
        if first.is_Number:
            if not (first.is_Integer or first.is_Float) or not first.is_finite:
                return None
            if first.is_negative:
                sign = "-"
                first = -first
                if first is sympy.S.One:    # -x*y prints as "-x*y", -2*x as "-2*x", -1.0*x as "-1.0*x"
                    del factors[0]
                else:
                    factors[0] = first
        numerator, denominator = [], []
        for factor in factors:
            if factor.is_Pow and factor.exp.is_Integer and factor.exp < 0:
                base = factor.base
                name = self._quick_name(base) if base.is_Symbol else None
                if name is None:
                    return None
                if factor.exp == -1:
                    denominator.append(name)
                else:
                    denominator.append(self._print_Pow(sympy.Pow(base, -factor.exp, evaluate=False)))
            else:
                text = self._quick_factor(factor)
                if text is None:
                    return None
                numerator.append(text)
        if not numerator:
            numerator.append(self._print(sympy.S.One))
        text = sign + "*".join(numerator)
        if not denominator:
            return text
        if len(denominator) == 1:
            return f"{text}/{denominator[0]}"
        return f"{text}/({'*'.join(denominator)})"


class BondcPrinting(QuickPrinting):
    """What bondc's numpy and C printers share: names only from the map, sums in sympy's argument
    order with negative terms last, min/max folded pairwise, relations in parentheses, and a
    refusal (:class:`UnsupportedExpression`) for anything they do not know. ``target`` names the
    code in messages."""

    target = "generated code"
    names: Mapping

    def _as_ordered_terms(self, expr, order=None):
        return negatives_last(expr)

    def _handle_UnevaluatedExpr(self, expr):
        return expr         # bondc never builds UnevaluatedExpr: skip the search for one in every expression

    def _print_Symbol(self, expr):
        try:
            return self.names[expr]
        except KeyError:
            raise UnsupportedExpression(f"unknown symbol {expr.name!r} in {self.target}") from None

    _print_Dummy = _print_Symbol

    def _fold(self, function, args):
        args = [self._print(arg) for arg in args]
        text = args[0]
        for arg in args[1:]:
            text = f"{function}({text}, {arg})"
        return text

    def _print_Relational(self, expr):
        op = {"==": "==", "!=": "!=", "<": "<", "<=": "<=", ">": ">", ">=": ">="}[expr.rel_op]
        return f"({self._print(expr.lhs)} {op} {self._print(expr.rhs)})"

    def _print_Function(self, expr):
        raise UnsupportedExpression(f"unsupported function {type(expr).__name__} in {self.target}")

    def _print_Derivative(self, expr):
        raise UnsupportedExpression(f"unsupported derivative {expr} in {self.target}")

    def _print_DiracDelta(self, expr):
        raise UnsupportedExpression("an impulse (DiracDelta) cannot be simulated")

    def emptyPrinter(self, expr):
        raise UnsupportedExpression(f"unsupported expression {type(expr).__name__} in {self.target}")


class BondcPrinter(BondcPrinting, NumPyPrinter):
    """numpy printer with bondc's names, exact floats, signals and frozen conditionals."""

    printmethod = "_bondccode"
    # order "none": sums print in sympy's own (canonical, deterministic) argument order; sorting
    # every sum's terms for display costs more than the rest of the printing of a large model
    _default_settings = {**NumPyPrinter._default_settings, "allow_unknown_functions": False, "order": "none"}

    def __init__(self, names: Mapping[sympy.Symbol, str], *, mode_symbols=frozenset(),
                 data_paths: Mapping[str, str] | None = None, settings=None):
        super().__init__(settings or {})
        self.printmethod = "_bondccode"     # NumPyPrinter sets "_numpycode", which Csv answers
        self.names = dict(names)
        self.mode_symbols = frozenset(mode_symbols)
        self.data_paths = dict(data_paths or {})

    # -- names and numbers

    def _module_format(self, fqn, register=True):
        text = super()._module_format(fqn, register)
        return "np." + text[len("numpy."):] if text.startswith("numpy.") else text

    def _print_Float(self, expr):
        value = float(expr)
        if value != value:
            return "np.nan"
        if value in (float("inf"), float("-inf")):
            return "np.inf" if value > 0 else "(-np.inf)"
        return repr(value)

    def _print_Integer(self, expr):
        return str(int(expr))

    def _print_Rational(self, expr):
        return f"{expr.p}/{expr.q}"

    def _print_NaN(self, expr):
        return "np.nan"

    def _print_Infinity(self, expr):
        return "np.inf"

    def _print_NegativeInfinity(self, expr):
        return "(-np.inf)"

    def _print_BooleanTrue(self, expr):
        return "True"

    def _print_BooleanFalse(self, expr):
        return "False"

    # -- powers

    def _print_Pow(self, expr, rational=False):
        base, exponent = expr.args
        if exponent.is_Integer:
            n = int(exponent)
            if n >= 0:
                return f"{self.parenthesize(base, precedence(expr), strict=False)}**{n}"
            denominator = base if n == -1 else sympy.Pow(base, -n, evaluate=False)
            return f"1/{self.parenthesize(denominator, precedence(sympy.Mul(2, 3, evaluate=False)) + 1, strict=True)}"
        if exponent == sympy.S.Half:
            return f"np.sqrt({self._print(base)})"
        if exponent == -sympy.S.Half:
            return f"1/np.sqrt({self._print(base)})"
        return f"np.power({self._print(base)}, {self._print(exponent)})"

    # -- discontinuous functions (unfrozen forms; frozen laws do not contain them)

    def _print_Abs(self, expr):
        return f"np.abs({self._print(expr.args[0])})"

    def _print_sign(self, expr):
        return f"np.sign({self._print(expr.args[0])})"

    def _print_Heaviside(self, expr):
        x = self._print(expr.args[0])
        h0 = self._print(expr.args[1]) if len(expr.args) > 1 else "0.5"
        return f"np.heaviside({x}, {h0})"

    def _print_Min(self, expr):
        return self._fold("np.minimum", expr.args)

    def _print_Max(self, expr):
        return self._fold("np.maximum", expr.args)

    # -- conditions

    def _is_frozen(self, condition) -> bool:
        return condition.free_symbols <= self.mode_symbols

    def _print_Piecewise(self, expr):
        pieces = list(expr.args)
        if all(self._is_frozen(cond) for _, cond in pieces):
            text = "np.nan"
            if pieces and pieces[-1][1] == sympy.true:
                text = self._print(pieces.pop()[0])
            for value, cond in reversed(pieces):
                text = f"({self._print(value)} if {self._print(cond)} else {text})"
            return text
        text = "np.nan"
        if pieces and pieces[-1][1] == sympy.true:
            text = self._print(pieces.pop()[0])
        for value, cond in reversed(pieces):
            text = f"np.where({self._vector_condition(cond)}, {self._print(value)}, {text})"
        return text

    def _vector_condition(self, cond):
        if isinstance(cond, (sympy.And, sympy.Or)):
            function = "np.logical_and" if isinstance(cond, sympy.And) else "np.logical_or"
            parts = [self._vector_condition(arg) for arg in cond.args]
            text = parts[0]
            for part in parts[1:]:
                text = f"{function}({text}, {part})"
            return text
        if isinstance(cond, sympy.Not):
            return f"np.logical_not({self._vector_condition(cond.args[0])})"
        return self._print(cond)

    def _print_And(self, expr):
        return "(" + " and ".join(self._print(arg) for arg in expr.args) + ")"

    def _print_Or(self, expr):
        return "(" + " or ".join(self._print(arg) for arg in expr.args) + ")"

    def _print_Not(self, expr):
        return f"(not {self._print(expr.args[0])})"

    # -- bondc signals

    def _print_Table(self, expr):
        xs = ", ".join(self._print(v) for v in expr.breakpoints)
        vs = ", ".join(self._print(v) for v in expr.values)
        comma = "," if len(expr.breakpoints) == 1 else ""
        return f"table({self._print(expr.argument)}, ({xs}{comma}), ({vs}{comma}))"

    def _print_Step(self, expr):
        return f"step({self._print(expr.args[0])}, {self._print(expr.args[1])})"

    def _print_Csv(self, expr):
        path = self.data_paths.get(expr.path, expr.path)
        scales = f", {expr.time_scale!r}, {expr.value_scale!r}" if len(expr.args) > 3 else ""
        return f"csv_signal({self._print(expr.args[0])}, DATA_DIR, {path!r}, {expr.column!r}{scales})"

    def _print_External(self, expr):
        # the host's table or function of t, from the module's EXTERNAL_INPUTS; the default otherwise
        return (f"external_signal({self._print(expr.args[0])}, EXTERNAL_INPUTS, {expr.name!r}, "
                f"{self._print(expr.default)})")



def relative_data_path(path: str, module_dir: str | Path) -> str:
    """A csv path as the generated module refers to it: relative to the module, '/'-separated."""
    import os

    relative = os.path.relpath(path, module_dir)
    return relative.replace(os.sep, "/")

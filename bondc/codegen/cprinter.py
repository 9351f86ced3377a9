"""The C printer of native model code: sympy expression -> C99 source text.

:class:`NativePrinter` is sympy's :class:`~sympy.printing.c.C99CodePrinter`
with the rules of :class:`bondc.codegen.printer.BondcPrinter`, so that the
compiled functions compute what the numpy module computes:

- symbols only through a name map (C identifiers made by :func:`c_name`, never
  text from the model file); an unknown symbol refuses to print;
- floats exactly (``repr``: 17 significant digits), integers and rationals as
  double literals (``1/2`` is ``1.0/2.0``: never C's integer division);
- a non-integer power is ``pow`` (nan for a negative base, as ``np.power``);
- every ``Piecewise`` is a conditional expression: C evaluates only the chosen
  branch, which is what the frozen laws need;
- ``Min``/``Max``/``sign``/``Heaviside``/``table``/``step`` call small helpers
  of :data:`PRELUDE` with numpy's semantics (a nan argument gives nan).

What it cannot print (a measured ``csv`` signal, an unknown function) raises
:class:`~bondc.codegen.printer.UnsupportedExpression`; the model then runs on
its numpy code.

>>> import sympy
>>> x = sympy.Symbol("mass.p", real=True)
>>> NativePrinter({x: "v_mass_p"}).doprint(sympy.sqrt(x) + x**2 / 3)
'sqrt(v_mass_p) + (1.0/3.0)*pow(v_mass_p, 2)'
"""

from __future__ import annotations

import re
from typing import Mapping

import sympy
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import precedence

from bondc.codegen.printer import BondcPrinting, UnsupportedExpression

#: Helpers every native module starts with (numpy's semantics for nan and the ends of a table).
PRELUDE = r"""#include <math.h>
#include <string.h>

static double bondc_sign(double x) { return x > 0 ? 1.0 : (x < 0 ? -1.0 : (x == 0 ? 0.0 : x)); }
static double bondc_min(double a, double b) { return (a != a || b != b) ? NAN : (a < b ? a : b); }
static double bondc_max(double a, double b) { return (a != a || b != b) ? NAN : (a > b ? a : b); }
static double bondc_heaviside(double x, double h0) { return x > 0 ? 1.0 : (x < 0 ? 0.0 : (x == 0 ? h0 : x)); }
static double bondc_step(double x, double x0) { return x >= x0 ? 1.0 : 0.0; }
static double bondc_table(double x, int n, const double *xs, const double *vs)
{
    /* np.interp: piecewise linear, held at the ends */
    if (x != x) return NAN;
    if (x <= xs[0]) return vs[0];
    if (x >= xs[n - 1]) return vs[n - 1];
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (xs[mid] <= x) lo = mid; else hi = mid;
    }
    double span = xs[hi] - xs[lo];
    if (span == 0) return vs[hi];
    double slope = (vs[hi] - vs[lo]) / span;
    return slope * (x - xs[lo]) + vs[lo];
}
"""

#: Helpers of a model with a nonlinear algebraic loop: an LU factorisation with partial pivoting of
#: a small dense matrix (the loop's dR/dz, row-major, overwritten) and its solve, for the loop's
#: Newton steps and its sensitivities dz/dx. bondc_lu returns -1 where a pivot is 0 or not finite.
LOOP_PRELUDE = r"""
static int bondc_lu(int n, double *a, int *piv)
{
    for (int k = 0; k < n; k++) {
        int best = k;
        for (int i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[best * n + k])) best = i;
        piv[k] = best;
        if (!(fabs(a[best * n + k]) > 0.0) || !isfinite(a[best * n + k])) return -1;
        if (best != k)
            for (int j = 0; j < n; j++) { double s = a[k * n + j]; a[k * n + j] = a[best * n + j]; a[best * n + j] = s; }
        for (int i = k + 1; i < n; i++) {
            double f = a[i * n + k] /= a[k * n + k];
            for (int j = k + 1; j < n; j++) a[i * n + j] -= f * a[k * n + j];
        }
    }
    return 0;
}
static void bondc_lu_solve(int n, const double *a, const int *piv, double *b)
{
    for (int k = 0; k < n; k++) {
        if (piv[k] != k) { double s = b[k]; b[k] = b[piv[k]]; b[piv[k]] = s; }
        for (int i = k + 1; i < n; i++) b[i] -= a[i * n + k] * b[k];
    }
    for (int k = n - 1; k >= 0; k--) {
        for (int j = k + 1; j < n; j++) b[k] -= a[k * n + j] * b[j];
        b[k] /= a[k * n + k];
    }
}
"""

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def c_name(python_name: str, index: int) -> str:
    """A C identifier for a generated module's local name: ``v_<name>``, or ``w<index>`` when the
    name is not plain ASCII (the two forms cannot collide, and neither is a C keyword or a libm name)."""
    if _IDENTIFIER.match(python_name):
        return "v_" + python_name
    return f"w{index}"


def c_double(value: float) -> str:
    """A C double literal of ``value``, exactly (``repr``: 17 significant digits), or NAN/INFINITY."""
    if value != value:
        return "NAN"
    if value in (float("inf"), float("-inf")):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    text = repr(value)
    return text if any(c in text for c in ".en") else text + ".0"


class NativePrinter(BondcPrinting, C99CodePrinter):
    """C99 printer with bondc's names, exact doubles and numpy-compatible helpers."""

    target = "native code"

    _default_settings = {**C99CodePrinter._default_settings, "allow_unknown_functions": False,
                         "order": "none"}

    def __init__(self, names: Mapping[sympy.Symbol, str], settings=None):
        super().__init__(settings or {})
        self.names = dict(names)

    # -- names and numbers

    def _print_Float(self, expr):
        return c_double(float(expr))

    def _print_Integer(self, expr):
        return f"{int(expr)}.0" if abs(int(expr)) < 2 ** 53 else repr(float(expr))

    def _print_Rational(self, expr):
        return f"{expr.p}.0/{expr.q}.0"

    def _print_NaN(self, expr):
        return "NAN"

    def _print_ComplexInfinity(self, expr):     # x/0 as sympy writes it: numpy gives inf or nan, run there
        raise UnsupportedExpression("a division by zero (complex infinity) has no native form")

    def _print_Infinity(self, expr):
        return "INFINITY"

    def _print_NegativeInfinity(self, expr):
        return "(-INFINITY)"

    def _print_Exp1(self, expr):
        return repr(float(sympy.E))

    def _print_Pi(self, expr):
        return repr(float(sympy.pi))

    def _print_BooleanTrue(self, expr):
        return "1"

    def _print_BooleanFalse(self, expr):
        return "0"

    # -- powers

    def _print_Pow(self, expr, rational=False):
        base, exponent = expr.args
        if exponent == sympy.S.Half:
            return f"sqrt({self._print(base)})"
        if exponent == -sympy.S.Half:
            return f"(1.0/sqrt({self._print(base)}))"
        if exponent == -1:
            return f"(1.0/{self.parenthesize(base, precedence(sympy.Mul(2, 3, evaluate=False)) + 1, strict=True)})"
        if exponent.is_Integer and int(exponent) < 0:
            return f"(1.0/pow({self._print(base)}, {-int(exponent)}))"
        if exponent.is_Integer:
            return f"pow({self._print(base)}, {int(exponent)})"
        return f"pow({self._print(base)}, {self._print(exponent)})"

    # -- discontinuous functions

    def _print_Abs(self, expr):
        return f"fabs({self._print(expr.args[0])})"

    def _print_sign(self, expr):
        return f"bondc_sign({self._print(expr.args[0])})"

    def _print_Heaviside(self, expr):
        h0 = self._print(expr.args[1]) if len(expr.args) > 1 else "0.5"
        return f"bondc_heaviside({self._print(expr.args[0])}, {h0})"

    def _print_Min(self, expr):
        return self._fold("bondc_min", expr.args)

    def _print_Max(self, expr):
        return self._fold("bondc_max", expr.args)

    def _print_floor(self, expr):
        return f"floor({self._print(expr.args[0])})"

    def _print_ceiling(self, expr):
        return f"ceil({self._print(expr.args[0])})"

    # -- conditions

    def _print_Piecewise(self, expr):
        pieces = list(expr.args)
        text = "NAN"
        if pieces and pieces[-1][1] == sympy.true:
            text = self._print(pieces.pop()[0])
        for value, cond in reversed(pieces):
            text = f"({self._print(cond)} ? {self._print(value)} : {text})"
        return text

    def _print_And(self, expr):
        return "(" + " && ".join(self._print(arg) for arg in expr.args) + ")"

    def _print_Or(self, expr):
        return "(" + " || ".join(self._print(arg) for arg in expr.args) + ")"

    def _print_Not(self, expr):
        return f"(!{self._print(expr.args[0])})"

    # -- bondc signals

    def _print_Table(self, expr):
        xs = ", ".join(self._print(v) for v in expr.breakpoints)
        vs = ", ".join(self._print(v) for v in expr.values)
        n = len(expr.breakpoints)
        return (f"bondc_table({self._print(expr.argument)}, {n}, (const double[]){{{xs}}}, "
                f"(const double[]){{{vs}}})")

    def _print_Step(self, expr):
        return f"bondc_step({self._print(expr.args[0])}, {self._print(expr.args[1])})"

    def _print_Csv(self, expr):
        raise UnsupportedExpression("a measured csv signal has no native form")

    def _print_External(self, expr):
        raise UnsupportedExpression(f"the external input '{expr.name}' is supplied by the host at run time, "
                                    "which the numpy code reads (no native form yet)")

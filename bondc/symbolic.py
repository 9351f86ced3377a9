"""AST expressions -> sympy, and the sympy vocabulary of bondc's signals.

The equations stage (:mod:`bondc.equations`) turns every law, input, output
and rate of a :class:`~bondc.model.BondGraph` into sympy by walking the AST
with :class:`Translator` (one method per node class, ``_Num``, ``_Name``,
``_Binary``, ...). Text is never evaluated: no ``sympify``, no ``eval``.

Translation rules:

- numbers: integer literals become sympy Integers, others Floats;
- ``if c then a else b`` -> ``Piecewise((a, c), (b, True))``; comparisons and
  ``and``/``or``/``not`` become sympy relationals and booleans;
- ``abs`` -> ``Abs``, ``sign`` -> ``sign``, ``min``/``max`` -> ``Min``/``Max``,
  ``^`` -> ``Pow``, the other built-ins to their sympy functions;
- ``table(x, [..], [..])`` -> :class:`Table`, ``step(x, t0)`` -> :class:`Step`,
  ``csv("file", "col")`` -> :class:`Csv` (carrying the resolved absolute path):
  opaque functions the code generator prints as runtime calls;
- calls of ``fn`` functions are inlined: the body is translated with the
  parameters bound to the translated arguments.

Laws are never passed through ``simplify``/``powsimp``/``nsimplify``: sympy may
rewrite ``abs(v)^0.27*sign(v)`` into a form that is nan for ``v < 0``.

>>> import sympy
>>> from bondc.parse import parse_set_value
>>> q = sympy.Symbol("spring.q", real=True)
>>> tr = Translator(lambda name, node: {"q": q, "k": sympy.Symbol("k", real=True)}[name])
>>> tr(parse_set_value("x = if abs(q) < 1 then k*q else k*q^3").value)
Piecewise((k*spring.q, Abs(spring.q) < 1), (k*spring.q**3, True))
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Mapping

import sympy
from sympy.core.symbol import Str as _SymStr

from bondc import ast
from bondc.errors import Diagnostic, EquationError
from bondc.evaluate import ExpansionBudget, Exploded
from bondc import codes

# ------------------------------------------------------------ signal functions


class Table(sympy.Function):
    """``table(x, [x0, x1, ...], [v0, v1, ...])``: piecewise linear, held at the ends.

    ``args`` are ``(x, Tuple(breakpoints), Tuple(values))``; breakpoints and
    values are expressions of parameters.
    """

    nargs = 3
    is_real = True

    @property
    def argument(self):
        return self.args[0]

    @property
    def breakpoints(self) -> tuple:
        return tuple(self.args[1])

    @property
    def values(self) -> tuple:
        return tuple(self.args[2])

    def fdiff(self, argindex=1):
        if argindex != 1:
            raise sympy.ArgumentIndexError(self, argindex)
        # The slope, piecewise constant; 0 outside the breakpoints (held ends).
        x, xs, vs = self.argument, self.breakpoints, self.values
        pieces = [(sympy.Integer(0), x < xs[0])]
        for i in range(len(xs) - 1):
            pieces.append(((vs[i + 1] - vs[i]) / (xs[i + 1] - xs[i]), x < xs[i + 1]))
        pieces.append((sympy.Integer(0), True))
        return sympy.Piecewise(*pieces)

    def _eval_derivative(self, symbol):
        # Breakpoints and values are constants (parameters): only the argument varies.
        return sympy.diff(self.argument, symbol) * self.fdiff(1)

    def _latex(self, printer):
        points = ", ".join(printer._print(x) for x in self.breakpoints)
        values = ", ".join(printer._print(v) for v in self.values)
        return r"\operatorname{table}\left(%s;\ \left[%s\right],\ \left[%s\right]\right)" % (
            printer._print(self.argument), points, values)

    def _eval_evalf(self, prec):
        x = self.argument
        if not (x.is_number and all(v.is_number for v in self.breakpoints + self.values)):
            return None
        value = table_value(float(x), [float(v) for v in self.breakpoints], [float(v) for v in self.values])
        return sympy.Float(value, prec)


class _PiecewiseConstant(sympy.Function):
    """A signal that is constant between jumps: its derivative is 0 wherever it exists (the
    jumps are Dirac impulses, which no ODE can carry). ``_latex`` prints ``name(args)``."""

    is_real = True
    latex_name = ""

    def fdiff(self, argindex=1):
        return sympy.Integer(0)

    def _eval_derivative(self, symbol):
        return sympy.Integer(0)

    def _latex(self, printer):
        return r"\operatorname{%s}\left(%s\right)" % (self.latex_name,
                                                       ", ".join(printer._print(a) for a in self.args))


class Step(_PiecewiseConstant):
    """``step(x, x0)``: 0 before ``x0``, 1 from it."""

    nargs = 2
    latex_name = "step"

    def _eval_evalf(self, prec):
        x, x0 = self.args
        if not (x.is_number and x0.is_number):
            return None
        return sympy.Float(step_value(float(x), float(x0)), prec)


class Coulomb(sympy.Function):
    """``coulomb(v, F_slide, F_static)``: dry friction, ``F_slide*sign(v)`` while sliding.

    At ``v = 0`` it sticks while the holding force is at most ``F_static``
    (the simulator solves for that force); both limits are magnitudes.
    """

    nargs = 3
    is_real = True

    def fdiff(self, argindex=1):
        # away from v = 0 the force is F_slide(v)*sign(v): sign's impulse at 0 no ODE can carry
        if argindex == 2:
            return sympy.sign(self.args[0])
        return sympy.Integer(0)

    def _latex(self, printer):
        return r"\operatorname{coulomb}\left(%s\right)" % ", ".join(printer._print(a) for a in self.args)

    def _eval_evalf(self, prec):
        v, slide = self.args[0], self.args[1]
        if not (v.is_number and slide.is_number):
            return None
        return sympy.Float(coulomb_value(float(v), float(slide)), prec)


class Pwm(_PiecewiseConstant):
    """``pwm(x, f, d)``: 1 on ``[k/f, (k + d)/f)`` for every integer k, else 0 (a duty ``d`` in [0, 1])."""

    nargs = 3
    latex_name = "pwm"

    def _eval_evalf(self, prec):
        if not all(a.is_number for a in self.args):
            return None
        x, f, d = (float(a) for a in self.args)
        return sympy.Float(pwm_value(x, f, d), prec)


class Csv(sympy.Function):
    """``csv("file", "column")``: a measured signal of time, linearly interpolated.

    ``args`` are ``(t, Str(absolute path), Str(column))``, and when the file's
    header gives units (``t [ms]``, ``omega [rpm]``) the two SI scales
    ``(time_scale, value_scale)`` after them; use :attr:`path`, :attr:`column`,
    :attr:`time_scale` and :attr:`value_scale`.
    """

    nargs = (3, 5)
    is_real = True

    @property
    def time_scale(self) -> float:
        return float(self.args[3]) if len(self.args) > 3 else 1.0

    @property
    def value_scale(self) -> float:
        return float(self.args[4]) if len(self.args) > 4 else 1.0

    @property
    def path(self) -> str:
        return self.args[1].name

    @property
    def column(self) -> str:
        return self.args[2].name

    def fdiff(self, argindex=1):
        raise EquationError(Diagnostic(
            "error", codes.E703,
            f"the time derivative of the measured signal csv(\"{Path(self.path).name}\", \"{self.column}\") "
            "is needed (derivative causality) but a measured signal cannot be differentiated"))

    def _eval_derivative(self, symbol):
        if symbol not in self.args[0].free_symbols:
            return sympy.Integer(0)
        return self.fdiff(1)

    def _eval_evalf(self, prec):
        x = self.args[0]
        if not x.is_number:
            return None
        return sympy.Float(csv_value(float(x), self.path, self.column, self.time_scale, self.value_scale), prec)

    def _sympystr(self, printer):
        return f'csv({printer._print(self.args[0])}, "{Path(self.path).name}", "{self.column}")'

    def _latex(self, printer):
        return r"\operatorname{csv}_{\mathrm{%s}}\left(%s\right)" % (
            self.column.replace("_", r"\_"), printer._print(self.args[0]))

    def _numpycode(self, printer):
        scales = f", {self.time_scale!r}, {self.value_scale!r}" if len(self.args) > 3 else ""
        return f"Csv({printer._print(self.args[0])}, {self.path!r}, {self.column!r}{scales})"

    _pythoncode = _numpycode


class External(sympy.Function):
    """An external input (``input u [V] external = default``): a signal of time the host running
    the model supplies (a table of times and values, a function of ``t``, a CSV file), ``default``
    (a constant) where nothing supplies it.

    ``args`` are ``(t, Str(name), default)``; use :attr:`name` and :attr:`default`. Evaluated at a
    number (``bondc check``, linearisation) it is its default; the generated module reads the
    host's signal (``bondc.runtime.external_signal``).
    """

    nargs = 3
    is_real = True

    @property
    def name(self) -> str:
        return self.args[1].name

    @property
    def default(self) -> sympy.Expr:
        return self.args[2]

    def fdiff(self, argindex=1):
        raise EquationError(Diagnostic(
            "error", codes.E703,
            f"the time derivative of the external input '{self.name}' is needed (derivative causality) but "
            "a signal the host supplies cannot be differentiated"))

    def _eval_derivative(self, symbol):
        if symbol not in self.args[0].free_symbols:
            return sympy.Integer(0)
        return self.fdiff(1)

    def _eval_evalf(self, prec):
        if not self.default.is_number:
            return None
        return self.default.evalf(prec)

    def _sympystr(self, printer):
        return f"external({self.name}, default {printer._print(self.default)})"

    def _latex(self, printer):
        return r"\operatorname{%s}\left(%s\right)" % (self.name.replace("_", r"\_"), printer._print(self.args[0]))

    def _numpycode(self, printer):
        return f"External({printer._print(self.args[0])}, {self.name!r}, {printer._print(self.default)})"

    _pythoncode = _numpycode


# --------------------------------------------------- numeric implementations

def as_sympy(value: object) -> sympy.Basic:
    """A sympy object for a value that is already sympy or a Python number.

    bondc never turns model text into sympy by parsing it: laws are translated
    from the AST (:class:`Translator`). This is the one place other stages
    convert numbers and sympy objects, and it refuses text outright.

    >>> as_sympy(2) + as_sympy(sympy.Symbol("x"))
    x + 2
    >>> as_sympy("x + 1")
    Traceback (most recent call last):
    TypeError: bondc does not turn text into sympy expressions ('x + 1')
    """
    if isinstance(value, (str, bytes)):
        raise TypeError(f"bondc does not turn text into sympy expressions ({value!r})")
    return sympy.sympify(value)  # safe: text is refused above


# bondc's numeric functions live in a module without sympy (a cached run reads them without it)
from bondc.numeric import coulomb_value, csv_scales, csv_value, pwm_value, step_value, table_value  # noqa: E402


# ----------------------------------------------------------------- translator

BUILTINS: Mapping[str, Callable] = {
    "abs": sympy.Abs,
    "sign": sympy.sign,
    "sqrt": sympy.sqrt,
    "exp": sympy.exp,
    "log": sympy.log,
    "sin": sympy.sin,
    "cos": sympy.cos,
    "tan": sympy.tan,
    "tanh": sympy.tanh,
    "atan": sympy.atan,
    "atan2": sympy.atan2,
    "min": sympy.Min,
    "max": sympy.Max,
}

BUILTIN_ARITY = {"atan2": 2, "step": 2, "table": 3, "csv": 2}

_COMPARISONS = {
    "<": sympy.StrictLessThan,
    "<=": sympy.LessThan,
    ">": sympy.StrictGreaterThan,
    ">=": sympy.GreaterThan,
    "==": sympy.Eq,
    "!=": sympy.Ne,
}


def _require_finite(value, node) -> None:
    """A constant that is not a finite double (``10^309``, ``1/0``, ``0/0``) is an error at ``node``."""
    try:
        number = float(value)
    except (OverflowError, TypeError):
        number = math.inf
    if not math.isfinite(number):
        what = "is not a number" if value is sympy.nan else "is not a finite number"
        raise _fail(node, f"this constant {what} ({_short_number(value)})",
                    hint="a division by zero, or a value beyond a double's range (about 1.8e308)")


def _require_real(value, node):
    """``value``, unless it is a constant with no real value (``sqrt(-1)``, ``log(-2)``,
    ``(-8)^(1/3)``: sympy's principal values are complex), an error at ``node``: laws are
    evaluated as real numbers, and such a constant has none."""
    if isinstance(value, sympy.Expr) and value.is_number and value.is_extended_real is False:
        raise _fail(node, "this constant has no real value",
                    hint="it is a square root or a log of a negative number, or a negative number raised to a "
                         "fractional power, and laws are evaluated as real numbers (an odd root of x that keeps "
                         "its sign is sign(x)*abs(x)^(1/3))")
    return value


def _short_number(value) -> str:
    if value is sympy.zoo:
        return "a division by zero"
    text = str(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} digits)"


#: What the translations of one model's laws may spend on function bodies in all (sympy builds
#: an expression from each operation: slower than evaluating a constant; see ExpansionBudget).
TRANSLATION_IN_ALL = 50_000


def _fail(node, message: str, hint: str | None = None) -> EquationError:
    return EquationError(Diagnostic("error", codes.E701, message, getattr(node, "span", None) or _no_span(), hint=hint))


def _no_span():
    from bondc.source import NO_SPAN

    return NO_SPAN


def _as_value(expr):
    """A boolean used as a number is 1 or 0 (``(x > 0)*k``)."""
    if isinstance(expr, sympy.logic.boolalg.Boolean) and not isinstance(expr, sympy.Symbol):
        return sympy.Piecewise((sympy.Integer(1), expr), (sympy.Integer(0), True))
    return expr


def _as_condition(expr):
    """A number used as a condition is true when non-zero."""
    if isinstance(expr, sympy.logic.boolalg.Boolean):
        return expr
    return sympy.Ne(expr, 0)


class Translator:
    """Translates AST expressions to sympy.

    ``resolve_name(name, node)`` returns the sympy value of a bare name (and
    raises for an unknown one); ``resolve_ref(node)`` that of a dotted
    reference. ``functions`` are the model's ``fn`` definitions (anything with
    ``params`` and ``body``), inlined at each call, within ``budget`` (E319 beyond it; by
    default, a budget of this translator's own). ``base_dir`` resolves csv paths of nodes
    without a source file.
    """

    def __init__(self, resolve_name: Callable, resolve_ref: Callable | None = None,
                 functions: Mapping[str, object] | None = None, base_dir: Path | None = None,
                 time: sympy.Symbol | None = None, budget: ExpansionBudget | None = None):
        self.resolve_name = resolve_name
        self.resolve_ref = resolve_ref
        self.functions = functions or {}
        self.base_dir = base_dir
        self.time = time if time is not None else sympy.Symbol("t", real=True)
        self._bound: list[Mapping[str, object]] = []    # fn parameters, innermost last
        self._calls: list[str] = []
        self._applied: dict = {}        # (function, argument values) -> value
        self.budget = budget if budget is not None else ExpansionBudget(in_all=TRANSLATION_IN_ALL)
        self._spent = 0                 # operations of function bodies translated (the law's size, in a way)

    def __call__(self, node):
        return _as_value(self.translate(node))

    def translate(self, node):
        method = getattr(self, "_" + type(node).__name__, None)
        if method is None:
            raise _fail(node, f"unsupported expression {type(node).__name__}")
        result = method(node)
        if isinstance(result, sympy.Number) or result is sympy.zoo:
            _require_finite(result, node)
        return result

    # -- leaves

    def _Num(self, node: ast.Num):
        text = node.text.strip()
        if text.isdigit() and math.isfinite(node.value):
            return sympy.Integer(int(text))
        # (an integer beyond a double's range, as 1e309: infinite, E701; Python would not even
        # convert its digits past 4300)
        return sympy.Float(node.value)

    def _Str(self, node: ast.Str):
        raise _fail(node, "a string is not a value here", hint="strings are only used by csv(\"file\", \"column\")")

    def _Name(self, node: ast.Name):
        if self._bound and node.name in self._bound[-1]:
            return self._bound[-1][node.name]
        if node.name == "pi":
            try:
                return self.resolve_name(node.name, node)
            except EquationError:
                return sympy.pi
        return self.resolve_name(node.name, node)

    def _Ref(self, node: ast.Ref):
        if self.resolve_ref is None:
            raise _fail(node, f"'{node.dotted}' cannot be used here")
        return self.resolve_ref(node)

    def _ListExpr(self, node: ast.ListExpr):
        raise _fail(node, "a list is only allowed as an argument of table()")

    # -- operators

    def _Unary(self, node: ast.Unary):
        operand = self.translate(node.operand)
        if node.op == "not":
            return sympy.Not(_as_condition(operand))
        operand = _as_value(operand)
        return -operand if node.op == "-" else operand

    def _Binary(self, node: ast.Binary):
        left, right = self.translate(node.left), self.translate(node.right)
        op = node.op
        if op == "and":
            return sympy.And(_as_condition(left), _as_condition(right))
        if op == "or":
            return sympy.Or(_as_condition(left), _as_condition(right))
        left, right = _as_value(left), _as_value(right)
        if op in _COMPARISONS:
            return _COMPARISONS[op](left, right)
        if op == "+":
            return left + right
        if op == "-":
            return left - right
        if op == "*":
            return left * right
        if op == "/":
            if right.is_zero:
                raise _fail(node, "a division by zero: the divisor is 0", hint="the divisor is 0 for every value "
                                                                              "of the variables")
            return left / right
        if op == "^":
            value = sympy.Pow(left, right)
            if value.has(sympy.zoo, sympy.nan):
                raise _fail(node, "0 raised to a negative power", hint="the base is 0 for every value")
            return _require_real(value, node)
        raise _fail(node, f"unsupported operator '{op}'")

    def _If(self, node: ast.If):
        cond = _as_condition(self.translate(node.cond))
        then, orelse = _as_value(self.translate(node.then)), _as_value(self.translate(node.orelse))
        return sympy.Piecewise((then, cond), (orelse, True))

    # -- calls

    def _Call(self, node: ast.Call):
        name = node.func
        if name in self.functions:
            return self._inline(node, self.functions[name])
        special = getattr(self, "_call_" + name, None)
        if special is not None:
            return special(node)
        if name in BUILTINS:
            arity = BUILTIN_ARITY.get(name, None if name in ("min", "max") else 1)
            if arity is not None and len(node.args) != arity:
                raise _fail(node, f"{name}() takes {arity} argument{'s' if arity > 1 else ''}, "
                                  f"got {len(node.args)}")
            if name in ("min", "max") and len(node.args) < 2:
                raise _fail(node, f"{name}() takes at least 2 arguments")
            return _require_real(BUILTINS[name](*[self(arg) for arg in node.args]), node)
        raise _fail(node, f"unknown function '{name}'")

    def _inline(self, node: ast.Call, function):
        if len(node.args) != len(function.params):
            raise _fail(node, f"{function.name}() takes {len(function.params)} arguments, got {len(node.args)}")
        if function.name in self._calls:
            raise _fail(node, f"function '{function.name}' calls itself")
        bound = {param: self(arg) for param, arg in zip(function.params, node.args)}
        # a function's value depends on its arguments only: translated once per distinct arguments,
        # so functions that call earlier ones twice (f1(x) = f0(x) + f0(x), ...) stay linear in size
        key: tuple | None = (function.name, tuple(bound.values()))
        try:
            known = self._applied.get(key)
        except TypeError:       # an argument that cannot be a key: translate as it is
            key, known = None, None
        if known is not None:
            return known
        cost = self.budget.size(function.body)
        self._spent += cost
        outermost = not self._calls
        beyond = self.budget.spend(cost, self._spent)
        self._bound.append(bound)
        self._calls.append(function.name)
        try:
            if beyond is not None:
                raise Exploded(beyond)
            value = self.translate(function.body)
        except Exploded as exploded:
            if not outermost:
                raise
            # reported at the call in the law itself, with the function it starts from
            raise EquationError(self.budget.diagnostic(exploded.which, function.name, node.span)) from None
        finally:
            self._bound.pop()
            self._calls.pop()
        if key is not None:
            self._applied[key] = value
        return value

    def _list(self, node) -> sympy.Tuple:
        if not isinstance(node, ast.ListExpr):
            raise _fail(node, "table() needs lists: table(t, [t0, t1, ...], [v0, v1, ...])")
        return sympy.Tuple(*[self(item) for item in node.items])

    def _call_table(self, node: ast.Call):
        if len(node.args) != 3:
            raise _fail(node, "table() takes 3 arguments: table(t, [t0, t1, ...], [v0, v1, ...])")
        xs, vs = self._list(node.args[1]), self._list(node.args[2])
        if len(xs) != len(vs) or len(xs) == 0:
            raise _fail(node, f"table() needs as many values as breakpoints (got {len(xs)} and {len(vs)})")
        return Table(self(node.args[0]), xs, vs)

    def _call_step(self, node: ast.Call):
        if len(node.args) != 2:
            raise _fail(node, "step() takes 2 arguments: step(t, t0)")
        return Step(self(node.args[0]), self(node.args[1]))

    def _call_coulomb(self, node: ast.Call):
        if len(node.args) not in (2, 3):
            raise _fail(node, "coulomb() takes 2 or 3 arguments: coulomb(v, F_slide, F_static)")
        velocity, slide = self(node.args[0]), self(node.args[1])
        if len(node.args) == 3:
            static = self(node.args[2])
        else:   # the static limit defaults to the sliding force at v = 0
            static = slide.xreplace({velocity: sympy.Integer(0)}) if velocity.is_Symbol else slide
        return Coulomb(velocity, slide, static)

    def _call_pwm(self, node: ast.Call):
        if len(node.args) != 3:
            raise _fail(node, "pwm() takes 3 arguments: pwm(t, frequency, duty)")
        return Pwm(*[self(arg) for arg in node.args])

    def _call_mod(self, node: ast.Call):
        if len(node.args) != 2:
            raise _fail(node, "mod() takes 2 arguments: mod(x, y)")
        x, y = self(node.args[0]), self(node.args[1])
        if y.is_number and y == 0:
            raise _fail(node.args[1], "mod(x, 0): the divisor is zero")
        # the remainder with the sign of y, as written (no evaluation of a symbolic Mod)
        return x - y * sympy.floor(x / y)

    def _call_floor(self, node: ast.Call):
        if len(node.args) != 1:
            raise _fail(node, "floor() takes 1 argument")
        return sympy.floor(self(node.args[0]))

    def _call_ceil(self, node: ast.Call):
        if len(node.args) != 1:
            raise _fail(node, "ceil() takes 1 argument")
        return sympy.ceiling(self(node.args[0]))

    def _call_csv(self, node: ast.Call):
        file_arg, column = node.args if len(node.args) == 2 else (None, None)
        if not (isinstance(file_arg, ast.Str) and isinstance(column, ast.Str)):
            raise _fail(node, 'csv() takes 2 strings: csv("file.csv", "column")')
        path = self._resolve_path(file_arg)
        try:
            scales = csv_scales(path, column.value)
        except (OSError, ValueError):        # reported by the semantic stage; the reader says it again
            scales = (1.0, 1.0)
        if scales == (1.0, 1.0):
            return Csv(self.time, _SymStr(path), _SymStr(column.value))
        return Csv(self.time, _SymStr(path), _SymStr(column.value), sympy.Float(scales[0]), sympy.Float(scales[1]))

    def _resolve_path(self, node: ast.Str) -> str:
        path = Path(node.value)
        if not path.is_absolute():
            origin = node.span.file if node.span and node.span.line > 0 else None
            base = Path(origin).parent if origin and Path(origin).exists() else self.base_dir
            path = (base or Path.cwd()) / path
        return str(path.resolve())


# --------------------------------------------------------------- inspection

def discontinuities(expr) -> list:
    """Expressions of ``expr`` whose zero crossings are potential discontinuities.

    If/Piecewise conditions as ``lhs - rhs``, arguments of Abs/sign/Heaviside,
    Min/Max argument differences, table breakpoints as ``x - x_i`` and step
    times as ``x - x0``; in order of first appearance (pre-order), without
    duplicates.

    >>> x = sympy.Symbol("x", real=True)
    >>> discontinuities(sympy.Piecewise((1, x < 2), (sympy.Abs(x), True)))
    [x - 2, x]
    """
    found: list = []

    def add(candidate):
        candidate = as_sympy(candidate)
        if candidate.is_number:
            return
        if candidate not in found and -candidate not in found:
            found.append(candidate)

    def conditions(cond):
        if isinstance(cond, sympy.core.relational.Relational):
            add(cond.lhs - cond.rhs)
        elif isinstance(cond, (sympy.And, sympy.Or, sympy.Not, sympy.Xor)):
            for arg in cond.args:
                conditions(arg)

    def visit(node):
        if isinstance(node, sympy.Piecewise):
            for _, cond in node.args:
                conditions(cond)
        elif isinstance(node, (sympy.Abs, sympy.sign, sympy.Heaviside, Coulomb)):
            add(node.args[0])
        elif isinstance(node, (sympy.Min, sympy.Max)):
            args = list(node.args)
            for i in range(len(args)):
                for j in range(i + 1, len(args)):
                    add(args[i] - args[j])
        elif isinstance(node, Table):
            for breakpoint in node.breakpoints:
                add(node.argument - breakpoint)
        elif isinstance(node, Step):
            add(node.args[0] - node.args[1])
        elif isinstance(node, sympy.core.relational.Relational):
            conditions(node)
        for arg in node.args:
            if isinstance(arg, sympy.Basic):
                visit(arg)

    visit(as_sympy(expr))
    return found


def strip_impulses(expr):
    """Drop Dirac impulses that differentiating sign/Heaviside/Piecewise produces."""
    if expr.has(sympy.DiracDelta):
        expr = expr.replace(sympy.DiracDelta, lambda *args: sympy.Integer(0))
    return expr


# ------------------------------------------------------------------ derivatives

def partial_derivative(expr, symbol, leaf=None, secant_kinks=False):
    """``d expr / d symbol`` with bondc's opaque signals (free of ``symbol``) held as constants.

    Sums and products are taken apart here (the sum rule, and a product with one factor that
    depends on ``symbol``) before sympy's ``diff`` sees the rest: a large model's Jacobian is
    tens of thousands of such small derivatives, and this is most of them. ``leaf``
    differentiates what is left (default: sympy's ``diff`` with tables and csv signals held).

    ``secant_kinks``: a kink ``sign(a)*r`` (``r`` vanishes at ``a = 0``, and depends on
    ``symbol`` only through ``a``) gets its secant through the kink, ``r/abs(a) * da/dsymbol``,
    instead of its tangent: the Newton matrix of an implicit solver (codegen's Jacobian). A
    turbulent orifice's ``sign(a)*sqrt(abs(a))`` has an infinite tangent at ``a = 0``, and Newton's
    method with the tangent steps from ``a`` to ``-a`` and back without end (the solver then cuts its
    step to nothing); with the secant it lands on the kink in one iteration, and the residual it
    converges on is the law as written.

    >>> a, c = sympy.symbols("a c", real=True)
    >>> partial_derivative(c*sympy.sign(a)*sympy.sqrt(sympy.Abs(a)), a, secant_kinks=True)
    Piecewise((c/sqrt(Abs(a)), Ne(a, 0)), (0, True))
    """
    if expr == symbol:
        return sympy.Integer(1)
    if symbol not in expr.free_symbols:
        return sympy.Integer(0)
    if expr.is_Add:
        return sympy.Add(*[partial_derivative(arg, symbol, leaf, secant_kinks) for arg in expr.args])
    if expr.is_Mul:
        if secant_kinks:
            secant = _kink_secant(expr, symbol, leaf)
            if secant is not None:
                return secant
        depending = [arg for arg in expr.args if symbol in arg.free_symbols]
        if len(depending) == 1:
            rest = sympy.Mul(*[arg for arg in expr.args if arg is not depending[0]])
            return rest * partial_derivative(depending[0], symbol, leaf, secant_kinks)
    return (leaf or _held_diff)(expr, symbol)


def _kink_secant(product, symbol, leaf):
    """The secant slope of a kink ``sign(a)*r`` through its kink (see :func:`partial_derivative`),
    or None when ``product`` is not one whose ``r`` depends on ``symbol`` only through ``a``."""
    for factor in product.args:
        if not isinstance(factor, sympy.sign) or symbol not in factor.free_symbols:
            continue
        argument = factor.args[0]
        rest = sympy.Mul(*[arg for arg in product.args if arg is not factor])
        through = sympy.Dummy("a", real=True)
        if symbol in rest.xreplace({argument: through}).free_symbols:
            return None
        # at the kink itself the secant's limit (infinite for a square root) is left out: 0 there,
        # and the solver's next Jacobian, away from the kink, has the secant
        secant = sympy.Piecewise((rest / sympy.Abs(argument), sympy.Ne(argument, 0)), (0, True))
        return secant * partial_derivative(argument, symbol, leaf)
    return None


def _held_diff(expr, symbol):
    opaque = sorted(expr.atoms(Table, Csv, External), key=sympy.default_sort_key)
    if not opaque:
        return strip_impulses(sympy.diff(expr, symbol))
    held = {f: sympy.Symbol(f"_held{i}", real=True) for i, f in enumerate(opaque)}
    if any(symbol in f.free_symbols for f in opaque):
        raise ValueError(f"cannot differentiate a signal of {symbol}")
    derivative = sympy.diff(expr.xreplace(held), symbol)
    return strip_impulses(derivative.xreplace({v: k for k, v in held.items()}))


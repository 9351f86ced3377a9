"""Numeric evaluation of constant expressions: an AST expression -> a float.

The semantic stage uses this to compute parameters, experiment settings,
initial values and table breakpoints in SI. It walks the AST (one method per
node class) and never evaluates text: no ``eval``, ``exec`` or ``sympify``.

Values of names come from a mapping (parameters already evaluated, function
arguments, optionally ``t``); ``pi`` is always known. Calls may name the
built-ins of the language (including ``step`` and ``table``) or ``fn``
functions. Truth values are 1.0 and 0.0; ``and``, ``or`` and ``if`` evaluate
only what they need, so ``if x > 0 then log(x) else 0`` is fine for ``x = 0``.

A math domain error (log of a negative number, division by zero, overflow)
raises :class:`EvaluationError` carrying one ``E311`` diagnostic whose span is
the sub-expression that failed, never a bare Python exception.

>>> from bondc.parse import parse_set_value
>>> round(evaluate(parse_set_value("x = pi/4*(D^2 - d^2)").value, {"D": 0.05, "d": 0.02}), 10)
0.0016493361
>>> try:
...     evaluate(parse_set_value("x = log(a - 1)").value, {"a": 1.0})
... except EvaluationError as error:
...     print(error.diagnostic.code, error.diagnostic.message)
E311 cannot evaluate: log of 0 (its argument must be positive)
"""

from __future__ import annotations

from collections import ChainMap
import math
import operator
from typing import Callable, Mapping, Protocol, Sequence

from bondc import ast
from bondc.errors import Diagnostic, ModelError, Related
from bondc.source import Span
from bondc import codes

CODE = codes.E311
#: The code of an expansion of ``fn`` calls beyond :class:`ExpansionBudget`'s limits.
EXPANSION_CODE = codes.E319

# Deeper nesting of function calls than this is a runaway (recursion is
# reported by the semantic stage; this only keeps the evaluator safe).
MAX_CALL_DEPTH = 100


class ExpansionBudget:
    """How much writing out ``fn`` calls may cost, so that no model file makes bondc work without
    end: functions that call earlier ones twice with different arguments (``f1(x) = f0(x + 1) +
    f0(2*x)``, ... ``f40``) would expand to 2^40 bodies.

    The cost of an expansion is the number of expression nodes of the function body written out
    (a call with arguments already expanded costs nothing: its value is reused). One expression
    (a parameter, a law) may spend ``per_expression``; all the expressions sharing this budget (a
    model's constants, a model's laws) ``in_all``. The evaluator of constants and the translator
    to sympy each keep one for a model.
    """

    PER_EXPRESSION = 10_000
    IN_ALL = 1_000_000

    def __init__(self, per_expression: int = PER_EXPRESSION, in_all: int = IN_ALL):
        self.per_expression = per_expression
        self.in_all = in_all
        self.spent = 0
        self.said = False       # whether an expression beyond the budget in all was reported
        self._sizes: dict[int, tuple[object, int]] = {}

    @classmethod
    def for_sources(cls, sources: Mapping[str, object], in_all: int = IN_ALL) -> "ExpansionBudget":
        """A model's budget: ``in_all``, or ten operations per character of its files where that is
        more (a model of 120 000 statements calls functions in proportion; only what a small text
        expands to without end is cut)."""
        size = sum(len(getattr(source, "text", "")) for source in sources.values())
        return cls(in_all=max(in_all, 10 * size))

    def size(self, body) -> int:
        """The number of nodes of a function body (counted once per body)."""
        known = self._sizes.get(id(body))
        if known is None or known[0] is not body:
            known = (body, sum(1 for _ in ast.walk(body)))
            self._sizes[id(body)] = known
        return known[1]

    def spend(self, cost: int, expression_spent: int) -> str | None:
        """Add ``cost``; None, or which limit the expression (having spent ``expression_spent``
        with this) or the budget is now beyond: "expression" or "model"."""
        self.spent += cost
        if expression_spent > self.per_expression:
            return "expression"
        if self.spent > self.in_all:
            return "model"
        return None

    def diagnostic(self, which: str, function_name: str, span: Span) -> Diagnostic:
        """E319 at the call written in the expression, whose expansion went beyond ``which``."""
        if which == "expression":
            message = (f"expanding {function_name}() here writes out more than {self.per_expression} "
                       f"operations of function bodies (the functions call one another at every level, "
                       f"with different arguments)")
        else:
            message = (f"expanding {function_name}() here takes the model's function calls beyond "
                       f"{self.in_all} operations of function bodies written out in all")
        return Diagnostic("error", EXPANSION_CODE, message, span,
                          hint="compute the repeated part once: make it a parameter, an input or a model "
                               "variable, or simplify the functions")


class Exploded(Exception):
    """An expansion beyond the budget (``which``: "expression" or "model"), raised from the
    innermost call; the outermost call of the expression turns it into the E319 diagnostic."""

    def __init__(self, which: str):
        super().__init__(which)
        self.which = which


class FunctionLike(Protocol):
    """An ``fn`` definition: :class:`bondc.ast.FnDef` or :class:`bondc.model.Function` (read-only:
    both are frozen)."""

    @property
    def name(self) -> str: ...

    @property
    def params(self) -> tuple[str, ...]: ...

    @property
    def body(self) -> ast.Expr: ...

    @property
    def span(self) -> Span: ...


class EvaluationError(ModelError):
    """An expression that has no value: carries one E311 diagnostic."""

    def __init__(self, diagnostic: Diagnostic):
        super().__init__(diagnostic)
        self.diagnostic = diagnostic
        self.repeated = False   # the same failure as one reported before (E319 for the budget in all)


def _number(value: float) -> str:
    return f"{value:g}"


def _fail(node, reason: str, hint: str | None = None) -> EvaluationError:
    return EvaluationError(Diagnostic("error", CODE, f"cannot evaluate: {reason}", node.span, hint=hint))


# ------------------------------------------------------------------ built-ins

def _log(x: float) -> float:
    if x <= 0:
        raise ValueError(f"log of {_number(x)} (its argument must be positive)")
    return math.log(x)


def _sqrt(x: float) -> float:
    if x < 0:
        raise ValueError(f"sqrt of the negative number {_number(x)}")
    return math.sqrt(x)


def _sign(x: float) -> float:
    return float((x > 0) - (x < 0))


def _step(x: float, x0: float) -> float:
    return 1.0 if x >= x0 else 0.0


def _mod(x: float, y: float) -> float:
    """The remainder with the sign of ``y`` (as numpy's ``mod``)."""
    if y == 0:
        raise ValueError("mod(x, 0) is undefined")
    return x - y * math.floor(x / y)


MATH_BUILTINS: Mapping[str, Callable[..., float]] = {
    "abs": abs,
    "sign": _sign,
    "sqrt": _sqrt,
    "exp": math.exp,
    "log": _log,
    "sin": math.sin,
    "cos": math.cos,
    "tan": math.tan,
    "tanh": math.tanh,
    "atan": math.atan,
    "atan2": math.atan2,
    "min": min,
    "max": max,
    "floor": lambda x: float(math.floor(x)),
    "ceil": lambda x: float(math.ceil(x)),
    "mod": lambda x, y: _mod(x, y),
}

_BINARY: Mapping[str, Callable[[float, float], float]] = {
    "+": operator.add,
    "-": operator.sub,
    "*": operator.mul,
    "<": lambda a, b: float(a < b),
    "<=": lambda a, b: float(a <= b),
    ">": lambda a, b: float(a > b),
    ">=": lambda a, b: float(a >= b),
    "==": lambda a, b: float(a == b),
    "!=": lambda a, b: float(a != b),
}


def interpolate(x: float, xs: Sequence[float], ys: Sequence[float]) -> float:
    """Piecewise-linear ``table``: linear between breakpoints, held at the ends.

    >>> interpolate(1.5, [0, 1, 2], [0, 10, 10]), interpolate(-1, [0, 1], [5, 6]), interpolate(9, [0, 1], [5, 6])
    (10.0, 5, 6)
    """
    if x <= xs[0]:
        return ys[0]
    if x >= xs[-1]:
        return ys[-1]
    for index in range(1, len(xs)):
        if x <= xs[index]:
            x0, x1, y0, y1 = xs[index - 1], xs[index], ys[index - 1], ys[index]
            if x1 == x0:
                return y1
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return ys[-1]


# ------------------------------------------------------------------ evaluator

class _Evaluator:
    """Walks an expression; one ``_eval_<Class>`` method per AST node class."""

    def __init__(self, values: Mapping[str, float], functions: Mapping[str, FunctionLike], depth: int = 0,
                 constants: Mapping[str, float] | None = None, budget: ExpansionBudget | None = None,
                 expansion: "_Expansion | None" = None):
        self.values = values
        self.functions = functions
        self.depth = depth
        # what a function body may use besides its arguments: the model's parameters (a function
        # declared inside a model may use them; the semantic stage keeps file-level ones to arguments)
        self.constants = values if constants is None else constants
        self.budget = budget if budget is not None else ExpansionBudget()
        # shared by the evaluators of one expression: the calls already evaluated, the cost so far
        self.expansion = expansion if expansion is not None else _Expansion()

    def __call__(self, node) -> float:
        method = getattr(self, f"_eval_{type(node).__name__}", None)
        if method is None:
            raise _fail(node, f"unsupported expression node {type(node).__name__}")
        value = method(node)
        if isinstance(value, complex) or not math.isfinite(value):
            raise _fail(node, "the result is not a finite number (overflow)")
        return value

    def _eval_Num(self, node: ast.Num) -> float:
        return node.value

    def _eval_Str(self, node: ast.Str) -> float:
        raise _fail(node, f'the string "{node.value}" is not a number')

    def _eval_ListExpr(self, node: ast.ListExpr) -> float:
        raise _fail(node, "a list is not a number")

    def _eval_Name(self, node: ast.Name) -> float:
        if node.name in self.values:
            return float(self.values[node.name])
        if node.name == "pi":
            return math.pi
        raise _fail(node, f"'{node.name}' has no value here")

    def _eval_Ref(self, node: ast.Ref) -> float:
        raise _fail(node, f"'{node.dotted}' is a variable of the simulation and has no constant value")

    def _eval_Unary(self, node: ast.Unary) -> float:
        value = self(node.operand)
        if node.op == "-":
            return -value
        if node.op == "not":
            return float(not value)
        return value

    def _eval_Binary(self, node: ast.Binary) -> float:
        if node.op == "and":
            return float(bool(self(node.left)) and bool(self(node.right)))
        if node.op == "or":
            return float(bool(self(node.left)) or bool(self(node.right)))
        left, right = self(node.left), self(node.right)
        if node.op == "/":
            if right == 0:
                raise _fail(node, f"division by zero ({_number(left)}/0)")
            return left / right
        if node.op == "^":
            return self._power(node, left, right)
        try:
            return _BINARY[node.op](left, right)
        except KeyError:
            raise _fail(node, f"unsupported operator '{node.op}'") from None
        except OverflowError:
            raise _fail(node, "the result is too large (overflow)") from None

    def _power(self, node: ast.Binary, base: float, exponent: float) -> float:
        if base == 0 and exponent < 0:
            raise _fail(node, f"0 raised to the negative power {_number(exponent)}")
        if base < 0 and exponent != int(exponent):
            raise _fail(node, f"the negative number {_number(base)} raised to the non-integer power "
                              f"{_number(exponent)}")
        try:
            return base ** exponent
        except OverflowError:
            raise _fail(node, f"{_number(base)}^{_number(exponent)} is too large (overflow)") from None

    def _eval_If(self, node: ast.If) -> float:
        return self(node.then) if self(node.cond) else self(node.orelse)

    def _eval_Call(self, node: ast.Call) -> float:
        if node.func in self.functions:
            return self._call_function(node, self.functions[node.func])
        if node.func == "table":
            return self._table(node)
        if node.func == "csv":
            raise _fail(node, "csv(...) is a measured signal and has no constant value")
        args = [self(arg) for arg in node.args]
        if node.func == "step":
            builtin: Callable[..., float] | None = _step
        else:
            builtin = MATH_BUILTINS.get(node.func)
        if builtin is None:
            raise _fail(node, f"unknown function '{node.func}'")
        try:
            return float(builtin(*args))
        except ValueError as error:
            reason = str(error)
            if reason == "math domain error":
                reason = f"{node.func}({', '.join(_number(a) for a in args)}) is outside the function's domain"
            raise _fail(node, reason) from None
        except OverflowError:
            raise _fail(node, f"{node.func}({', '.join(_number(a) for a in args)}) is too large (overflow)") from None
        except TypeError:
            raise _fail(node, f"wrong number of arguments to {node.func}()") from None

    def _call_function(self, node: ast.Call, function: FunctionLike) -> float:
        if len(node.args) != len(function.params):
            raise _fail(node, f"'{function.name}' takes {len(function.params)} arguments, {len(node.args)} given")
        if self.depth >= MAX_CALL_DEPTH:
            raise _fail(node, f"calls nested more than {MAX_CALL_DEPTH} deep (is '{function.name}' recursive?)")
        args = {name: self(arg) for name, arg in zip(function.params, node.args)}
        # a function's value depends on its arguments only (and the constants, fixed during one
        # evaluation): evaluated once per distinct arguments, so that f1(x) = f0(x) + f0(x), ...
        # stays linear in size
        key = (function.name, tuple(args.values()))
        known = self.expansion.values.get(key)
        if known is not None:
            return known
        cost = self.budget.size(function.body)
        self.expansion.spent += cost
        beyond = self.budget.spend(cost, self.expansion.spent)
        inner = _Evaluator(ChainMap(args, self.constants), self.functions, self.depth + 1, self.constants,
                           self.budget, self.expansion)
        try:
            if beyond is not None:
                raise Exploded(beyond)
            value = inner(function.body)
        except Exploded as exploded:
            if self.depth > 0:
                raise
            # reported at the call written in the expression, with the function it starts from; the
            # model's budget spent is said once (the expressions after it have no value either)
            error = EvaluationError(self.budget.diagnostic(exploded.which, function.name, node.span))
            error.repeated = exploded.which == "model" and self.budget.said
            self.budget.said = self.budget.said or exploded.which == "model"
            raise error from None
        except EvaluationError as error:
            # Point at the call the user wrote, and show where in the function it failed.
            cause = error.diagnostic
            related = (Related(cause.span, f"in function '{function.name}'"),) + cause.related
            raise EvaluationError(Diagnostic("error", cause.code, cause.message, node.span, hint=cause.hint,
                                             related=related)) from None
        self.expansion.values[key] = value
        return value

    def _table(self, node: ast.Call) -> float:
        if len(node.args) != 3:
            raise _fail(node, "table() takes a value and two lists")
        value, breakpoints, values = node.args
        if not isinstance(breakpoints, ast.ListExpr) or not isinstance(values, ast.ListExpr):
            raise _fail(node, "table() takes a value and two lists")
        xs = [self(item) for item in breakpoints.items]
        ys = [self(item) for item in values.items]
        if len(xs) != len(ys) or not xs:
            raise _fail(node, "table() needs two lists of the same, non-zero length")
        return float(interpolate(self(value), xs, ys))


class _Expansion:
    """What the evaluators of one expression share: the values of the calls evaluated so far, by
    (function, arguments), and the cost of the function bodies evaluated."""

    def __init__(self):
        self.values: dict[tuple, float] = {}
        self.spent = 0


def evaluate(expr: ast.Expr, values: Mapping[str, float] | None = None,
             functions: Mapping[str, FunctionLike] | None = None,
             budget: ExpansionBudget | None = None) -> float:
    """The value of ``expr`` given the values of its names; raises :class:`EvaluationError` (E311,
    or E319 where calls of ``functions`` would expand beyond ``budget``: by default, a budget of
    this expression's own)."""
    return _Evaluator(values or {}, functions or {}, budget=budget)(expr)

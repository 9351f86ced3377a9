"""What the equations stage would report, decided without sympy where that is certain.

``bondc check`` runs the equations stage for what only it finds: a law that cannot be inverted
(E605), an algebraic loop (W604, E702), derivative causality (E703, W704) and the laws that do not
translate (E701: a divisor or a base that is 0 for every value, a constant beyond a double's range,
an unknown name, a function that calls itself). Importing sympy costs about as much as the rest of
``check``; this module decides, without it, the common case in which the stage has nothing to say,
and gives the states it keeps. Where it cannot be certain it answers None, and the stage runs.

It is certain when

- the causality has no storage element in derivative causality and no algebraic loop, every
  resistor's law is written for the variable its causality sets (nothing to invert), and the
  equations' dependencies through the laws' references have no cycle either;
- no two quantities share a name;
- every translated expression (the laws used, the rates, the inputs, outputs, initial values and
  ``when`` clauses) is one the translator accepts: known names and functions, right arities, no
  function calling itself, and no division, power or ``mod`` by something that is 0 for every value,
  nor a constant that is not a finite double.

The last is the only part that is not syntax. The translator rejects ``x/(a - a)`` because sympy
folds ``a - a`` to 0. Here every expression is evaluated at a few points (each name a fixed
pseudo-random value) in interval arithmetic rounded outwards: where the divisor's interval excludes
0 at some point, the divisor is not 0 for every value, so sympy cannot have folded it to 0. Every
interval holds the exact value and the value of any rounding of the same operations, so a divisor
that cancels (exactly, or only by rounding like ``1e20 + 1 - 1e20``) holds 0 at every point, and
the answer is None. So is the answer when a sub-expression has no real value at any of the points
(``log(-x^2 - 1)``), when a constant is beyond 1e300, and for the functions whose value is not
modelled here (``coulomb``, ``pwm``, ``csv``) wherever a divisor or a base contains them.

``tests/test_quickcheck.py`` checks every model of ``models/`` and ``tests/fixtures`` against the
equations stage itself: where this module answers, the stage reports nothing and keeps the same
states.
"""

from __future__ import annotations

import math
import zlib
from typing import Mapping

from bondc import ast
from bondc.causality import CONDUCTANCE, ROLES, CausalGraph

#: The points at which every expression is evaluated: at the first, each parameter has its own
#: value; at the first two, every other name is positive; at the others, of either sign.
POINTS = 4
#: Operations of function bodies expanded per expression before the answer is None (the
#: translator's own limit, E319, is ExpansionBudget.PER_EXPRESSION; an expression this large is
#: left to it).
MAX_EXPANSIONS = 10_000
#: Magnitudes beyond this are treated as overflow (a double's range ends at about 1.8e308).
HUGE = 1e300

_UP, _DOWN = math.inf, -math.inf


#: A point at which an expression has no real value for a reason that is no zero and no pole
#: (``sqrt`` or ``log`` of a negative interval): the translator accepts it (sympy's value is
#: complex there), unlike a point whose value is unknown (None: a divisor holding 0, an overflow).
DOMAIN = "no real value"


class _Unsure(Exception):
    """The equations stage must decide."""


def equations_findings(causal: CausalGraph) -> tuple:
    """What the equations stage finds, for ``check``: ((the names of the states it keeps, or None
    where it fails; its diagnostics), whether a parameter's value decided anything). Without sympy
    where :func:`verdict` is certain; the stage itself otherwise."""
    states = verdict(causal)
    if states is not None:
        return (states, ()), False
    from bondc.equations import derive
    from bondc.errors import BondcError

    try:
        state_space = derive(causal)
    except BondcError as error:
        if error.stage in ("usage",):
            raise
        return (None, tuple(error.diagnostics)), True
    return (tuple(s.name for s in state_space.states), tuple(state_space.diagnostics)), state_space.values_consulted


def verdict(causal: CausalGraph) -> tuple[str, ...] | None:
    """The names of the states the equations stage keeps, when it certainly reports nothing and
    succeeds; None when only the stage itself can tell."""
    try:
        return _Verdict(causal).run()
    except _Unsure:
        return None
    except (KeyError, AttributeError, TypeError, ValueError, ArithmeticError, RecursionError):
        return None         # anything unexpected: the stage decides, and reports it properly


# ------------------------------------------------------------------ intervals

def _lo(x: float) -> float:
    return math.nextafter(x, _DOWN)


def _hi(x: float) -> float:
    return math.nextafter(x, _UP)


def _widen(lo: float, hi: float, ulps: int = 1):
    for _ in range(ulps):
        lo, hi = _lo(lo), _hi(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)) or max(-lo, hi) > HUGE:
        return None
    return lo, hi


def _exact(value: float):
    return (value, value) if math.isfinite(value) and abs(value) <= HUGE else None


def _add(a, b):
    return _widen(a[0] + b[0], a[1] + b[1])


def _neg(a):
    return -a[1], -a[0]


def _mul(a, b):
    products = (a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1])
    if any(math.isnan(p) for p in products):
        return None
    return _widen(min(products), max(products))


def _has_zero(a) -> bool:
    return a[0] <= 0.0 <= a[1]


def _div(a, b):
    if _has_zero(b):
        return None
    return _mul(a, (_lo(1.0 / b[1]), _hi(1.0 / b[0])))


def _monotone(function, a):
    """An increasing function: its values at the ends, widened by libm's error."""
    try:
        low, high = function(a[0]), function(a[1])
    except (ValueError, OverflowError, ZeroDivisionError):
        return None
    if math.isnan(low) or math.isnan(high):
        return None
    return _widen(low, high, 4)


def _log(a):
    """log: no real value left of 0 (sympy's is complex there); a zero is log's pole."""
    if a[1] < 0.0:
        return DOMAIN
    return None if a[0] <= 0.0 else _monotone(math.log, a)


def _sqrt(a):
    return DOMAIN if a[0] < 0.0 else _monotone(math.sqrt, a)


def _sin_cos(function, a):
    """sin or cos: their slope is at most 1, so the value at the middle +- half the width."""
    middle = function(0.5 * (a[0] + a[1]))
    half = 0.5 * (a[1] - a[0])
    return _widen(middle - half, middle + half, 4)


def _tan(a):
    """tan, increasing between its poles: None where a pole may lie in the interval."""
    cos = _sin_cos(math.cos, a)
    if cos is None or _has_zero(cos):
        return None
    return _monotone(math.tan, a)


def _power(base, exponent):
    if exponent[0] == exponent[1] and float(exponent[0]).is_integer() and abs(exponent[0]) <= 64:
        n = int(exponent[0])
        if n == 0:
            return 1.0, 1.0
        result = (1.0, 1.0)
        for _ in range(abs(n)):
            result = _mul(result, base)
            if result is None:
                return None
        return result if n > 0 else _div((1.0, 1.0), result)
    if base[0] <= 0.0:      # a real power of a negative number: no real value here
        return DOMAIN if base[1] < 0.0 else None
    candidates = []
    for b in base:
        for e in exponent:
            try:
                candidates.append(math.pow(b, e))
            except (OverflowError, ValueError):
                return None
    return _widen(min(candidates), max(candidates), 4)


def _atan2(y, x):
    if x[0] <= 0.0 and _has_zero(y):
        return None         # across the branch cut or at the origin
    candidates = [math.atan2(yy, xx) for yy in y for xx in x]
    return _widen(min(candidates), max(candidates), 4)


def _step_value(x, x0):
    if x[0] >= x0[1]:
        return 1.0, 1.0
    if x[1] < x0[0]:
        return 0.0, 0.0
    return None


def _floor(a, ceil: bool = False):
    f = math.ceil if ceil else math.floor
    low, high = f(a[0]), f(a[1])
    return (float(low), float(low)) if low == high else None


def _sign(a):
    if a[0] > 0:
        return 1.0, 1.0
    if a[1] < 0:
        return -1.0, -1.0
    return (0.0, 0.0) if a == (0.0, 0.0) else None


#: The elementary functions on an interval.
_ELEMENTARY = {
    "exp": lambda a: _monotone(math.exp, a),
    "tanh": lambda a: _monotone(math.tanh, a),
    "atan": lambda a: _monotone(math.atan, a),
    "log": _log,
    "sqrt": _sqrt,
    "sin": lambda a: _sin_cos(math.sin, a),
    "cos": lambda a: _sin_cos(math.cos, a),
    "tan": _tan,
}

#: Functions whose value is not modelled: a pseudo-random value of their arguments, marked opaque.
_OPAQUE = ("coulomb", "pwm", "csv")

#: The translator's arities for the functions it checks itself (``Translator._Call``).
_ARITY = {"atan2": 2}


class _Value:
    """An expression's intervals at the points (None where it has no real value there), and
    whether a function whose value is not modelled contributed to it."""

    __slots__ = ("at", "opaque")

    def __init__(self, at, opaque: bool = False):
        self.at, self.opaque = tuple(at), opaque

    def key(self):
        return self.at, self.opaque


def _combine(function, *values: _Value) -> _Value:
    at = []
    for point in range(POINTS):
        args = [v.at[point] for v in values]
        if any(a is None for a in args):
            at.append(None)
        elif any(a is DOMAIN for a in args):
            at.append(DOMAIN)
        else:
            at.append(function(*args))
    if all(a is DOMAIN for a in at) and all(len(set(v.at)) == 1 for v in values):
        # arguments alike at every point (a constant, or names that cancel) with no real value: the
        # translator rejects a constant that has none (E701)
        raise _Unsure("a constant with no real value (E701)")
    return _Value(at, any(v.opaque for v in values))


def _symbol_value(name: str) -> _Value:
    """A fixed pseudo-random value per name and point, an exact binary fraction in [0.5, 1.5);
    positive at the first two points, of either sign at the others."""
    at = []
    for point in range(POINTS):
        h = zlib.crc32(f"{point}:{name}".encode())
        value = (2 ** 19 + h % 2 ** 20) / 2 ** 20
        if point >= 2 and h & (1 << 30):
            value = -value
        at.append((value, value))
    return _Value(at)


# ------------------------------------------------------------------ the walk

class _Verdict:
    def __init__(self, causal: CausalGraph):
        self.causal = causal
        self.graph = causal.graph
        self.scope = getattr(self.graph, "scope", None)
        self.functions = self.graph.functions or {}
        self.symbols: dict[str, _Value] = {}

    def symbol(self, key: str) -> _Value:
        """A name's values at the points; a parameter takes its own value at the first point
        (laws are often real only near it: a ratio of specific heats above 1)."""
        if key not in self.symbols:
            value = _symbol_value(key)
            kind, _, name = key.partition(":")
            parameter = self.graph.parameters.get(name) if kind == "param" else None
            own = _exact(float(parameter.value)) if parameter is not None and parameter.value is not None else None
            if own is not None:
                value = _Value((own,) + value.at[1:])
            self.symbols[key] = value
        return self.symbols[key]

    # -- the graph

    def run(self) -> tuple[str, ...]:
        graph, causal = self.graph, self.causal
        if causal.derivative_storage or causal.algebraic_loops:
            raise _Unsure("derivative causality or an algebraic loop")
        names = ["t"] + list(graph.parameters) + list(graph.inputs) + list(graph.outputs)
        names += [s.qualified for s in graph.states]
        names += [f"{b.name}.{v}" for b in graph.bonds for v in "ef"]
        if len(set(names)) != len(names):
            raise _Unsure("two quantities of one name (E701)")

        deps: dict[tuple, set] = {}

        def add(target, found: set) -> None:
            if target in deps:
                raise _Unsure("two equations for one variable")
            deps[target] = found

        for name, signal in graph.inputs.items():
            add(("in", name), self.refs(signal.expr, None))
        for element in graph.elements.values():
            getattr(self, "_" + ROLES[element.kind])(element, add)
        for junction in graph.junctions.values():
            self._junction(junction, add)
        for state in graph.model_states:
            if state.rate is not None:
                self.refs(state.rate, None)
        for name, output in graph.outputs.items():
            add(("out", name), self.refs(output.expr, None))
        for state in graph.states:
            if state.initial is not None:
                owner = graph.elements.get(state.owner) if state.owner else None
                if self.refs(state.initial, owner, initial=True):
                    raise _Unsure("an initial value that uses a variable")
        for when in getattr(graph, "whens", ()):
            for _, target, value in when.actions:
                if isinstance(target, ast.Ref):
                    found = causal.reference(target.parts, None)
                    if found is None or found[0] != "state":
                        raise _Unsure("a when clause sets something that is not a state (E701)")
                self.refs(value, None)
            self.refs(when.condition, None)
        if _has_cycle(deps):
            raise _Unsure("an algebraic loop through the laws' references")
        return tuple(s.qualified for s in graph.states)

    def law(self, element, name: str) -> set:
        if name not in element.laws:
            raise _Unsure(f"no law {name} to use as written (E605 or an inversion)")
        return self.refs(element.laws[name], element)

    def _source(self, element, add) -> None:
        bond = element.bond
        if self.causal.sets_effort(bond, element.name):
            add(("e", bond), self.law(element, "e"))
        else:
            add(("f", bond), self.law(element, "f"))

    def _storage(self, element, add) -> None:
        bond = element.bond
        computed = element.kind_info.law_variable      # what its law computes: e (C) or f (I)
        for state in element.states:
            if state.rate is not None:
                self.refs(state.rate, element)
        add((computed, bond), self.law(element, computed))

    def _resistor(self, element, add) -> None:
        bond = element.bond
        wanted = "f" if self.causal.resistors[element.name] == CONDUCTANCE else "e"
        if wanted in element.laws:
            add((wanted, bond), self.law(element, wanted))
            return
        # the law of the other variable, inverted: certain (no E605, no diagnostic) when it is
        # linear in the wanted variable, whose coefficient is not 0 for every value
        given = "e" if wanted == "f" else "f"
        if given not in element.laws:
            raise _Unsure("a resistor without a law")
        expr = element.laws[given]
        if _degree(expr, wanted, self.functions) != 1:
            raise _Unsure(f"a law not linear in {wanted}: sympy inverts it, or cannot (E605)")
        walks = [_Walk(self, element, dummy=(wanted, at)) for at in (None, 0.0, 1.0)]
        values = [walk.value(expr) for walk in walks]
        coefficient = _combine(lambda a, b: _add(a, _neg(b)), values[2], values[1])
        walks[0].nonzero(coefficient, f"the coefficient of {wanted}")
        add((wanted, bond), walks[0].found | {(given, bond)})

    def _two_port(self, element, add, first, otherwise) -> None:
        """``first`` or ``otherwise`` (whether the element sets its first bond's effort): pairs of
        (variable, port) it sets and (variable, port) that variable reads, besides its law."""
        bonds, r = element.bonds, self.law(element, "r")
        sets_first = self.causal.sets_effort(bonds[0], element.name)
        if not sets_first:      # the equations divide by r (E606 where it is 0 for every value)
            walk = _Walk(self, element)
            walk.nonzero(walk.value(element.laws["r"]), "the ratio r, which the equations divide by,")
        for (kind, i), (read, j) in (first if sets_first else otherwise):
            add((kind, bonds[i]), r | {(read, bonds[j])})

    def _transformer(self, element, add) -> None:
        # p1.e = r*p2.e, p2.f = r*p1.f (the equations stage's _transformer)
        self._two_port(element, add, ((("e", 0), ("e", 1)), (("f", 1), ("f", 0))),
                       ((("e", 1), ("e", 0)), (("f", 0), ("f", 1))))

    def _gyrator(self, element, add) -> None:
        # p1.e = r*p2.f, p2.e = r*p1.f (the equations stage's _gyrator)
        self._two_port(element, add, ((("e", 0), ("f", 1)), (("e", 1), ("f", 0))),
                       ((("f", 1), ("e", 0)), (("f", 0), ("e", 1))))

    def _junction(self, junction, add) -> None:
        if not junction.bonds:
            return
        strong = self.causal.strong_bond(junction.name)
        common, summed = junction.kind_info.common, junction.kind_info.summed
        for bond in junction.bonds:
            if bond != strong:
                add((common, bond), {(common, strong)})
        add((summed, strong), {(summed, b) for b in junction.bonds if b != strong})

    # -- expressions

    def refs(self, expr, owner, initial: bool = False) -> set:
        """The equations' variables ``expr`` reads, after checking that it translates."""
        walk = _Walk(self, owner, initial)
        walk.value(expr)
        return walk.found


class _Walk:
    """One expression: its value at the points (checked as the translator checks it) and the
    variables it reads."""

    def __init__(self, verdict: _Verdict, owner, initial: bool = False, dummy: tuple | None = None):
        """``dummy``: (name, value or None): the law's own variable ``name`` replaced by a symbol
        of its own (as the equations stage does to invert a law), fixed to ``value`` if given."""
        self.verdict, self.owner, self.initial = verdict, owner, initial
        self.found: set = set()
        self.bound: list[Mapping[str, _Value]] = []
        self.calls: list[str] = []
        self.applied: dict = {}
        self.expansions = 0
        self.local: dict[str, tuple] = {}
        if owner is not None:
            if len(owner.bonds) == 1:
                self.local["e"] = ("e", owner.bond)
                self.local["f"] = ("f", owner.bond)
            for state in owner.states:
                self.local.setdefault(state.name, ("state", state.qualified))
        self.fixed = None
        if dummy is not None:
            self.local[dummy[0]] = ("dummy", dummy[0])
            if dummy[1] is not None:
                self.fixed = _Value([(dummy[1], dummy[1])] * POINTS)

    def value(self, node) -> _Value:
        method = getattr(self, "_" + type(node).__name__, None)
        if method is None:
            raise _Unsure(f"an expression of kind {type(node).__name__}")
        result = method(node)
        if not any(_real(a) for a in result.at) and None in result.at:
            raise _Unsure("no value at any point: a zero, a pole or a constant beyond a double's range")
        return result

    def variable(self, kind: str, what) -> _Value:
        if kind == "dummy" and self.fixed is not None:
            return self.fixed
        if kind in ("e", "f", "in", "out"):
            self.found.add((kind, what))
        if self.initial and kind not in ("param", "dummy"):
            self.found.add((kind, what))
        return self.verdict.symbol(f"{kind}:{what}")

    # -- leaves

    def _Num(self, node) -> _Value:
        value = float(node.value)
        at = _exact(value)
        if at is None:
            raise _Unsure("a constant beyond a double's range (E701)")
        text = node.text.strip()
        if text.isdigit() and int(text) != value:       # sympy's Integer is exact; the double is not
            at = _widen(value, value, 2)
        return _Value([at] * POINTS)

    def _Name(self, node) -> _Value:
        name = node.name
        if self.bound and name in self.bound[-1]:
            return self.bound[-1][name]
        if name in self.local:
            return self.variable(*self.local[name])
        if name == "t":
            return self.variable("t", "t")
        verdict = self.verdict
        graph = verdict.graph
        category = verdict.scope.category(name) if verdict.scope is not None else None
        if category == "parameter" or (category is None and name in graph.parameters):
            return self.variable("param", name)
        if category == "input" or (category is None and name in graph.inputs):
            return self.variable("in", name)
        if category == "output" or (category is None and name in graph.outputs):
            return self.variable("out", name)
        if category in ("state", "discrete"):
            return self.variable("state", name)
        if category is None:
            for state in graph.model_states:
                if state.name == name:
                    return self.variable("state", state.qualified)
        if name == "pi":
            return _Value([_widen(math.pi, math.pi)] * POINTS)
        raise _Unsure(f"unknown name {name!r} (E701)")

    def _Ref(self, node) -> _Value:
        target = self.verdict.causal.reference(node.parts, self.owner.name if self.owner is not None else None)
        if target is None:
            raise _Unsure(f"{node.dotted!r} names no variable (E701)")
        kind, what = target
        return self.variable(kind, what)

    # -- operators

    def _Unary(self, node) -> _Value:
        operand = self.value(node.operand)
        if node.op == "not":
            return _Value([_not(a) if _real(a) else None for a in operand.at], operand.opaque)
        return _combine(_neg, operand) if node.op == "-" else operand

    def _Binary(self, node) -> _Value:
        left, right = self.value(node.left), self.value(node.right)
        op = node.op
        if op in ("and", "or"):
            return _combine(_AND if op == "and" else _OR, left, right)
        if op in _COMPARE:
            return _combine(_COMPARE[op], left, right)
        if op == "+":
            return _combine(_add, left, right)
        if op == "-":
            return _combine(lambda a, b: _add(a, _neg(b)), left, right)
        if op == "*":
            return _combine(_mul, left, right)
        if op == "/":
            self.nonzero(right, "a divisor")
            return _combine(_div, left, right)
        if op == "^":
            self.nonzero(left, "the base of a power")
            return _combine(_power, left, right)
        raise _Unsure(f"operator {op!r}")

    def nonzero(self, value: _Value, what: str) -> None:
        """Certain that ``value`` is not 0 for every value of the names: its interval excludes 0
        at one point at least (and no function whose value is not modelled is in it)."""
        if value.opaque or not any(_real(a) and not _has_zero(a) for a in value.at):
            raise _Unsure(f"{what} that may be 0 for every value (E701)")

    def _If(self, node) -> _Value:
        cond = self.value(node.cond)
        then, orelse = self.value(node.then), self.value(node.orelse)
        at = []
        for c, a, b in zip(cond.at, then.at, orelse.at):
            truth = _truth(c) if _real(c) else None
            at.append(a if truth is True else b if truth is False else None)
        return _Value(at, cond.opaque or then.opaque or orelse.opaque)

    # -- calls

    def _Call(self, node) -> _Value:
        name, args = node.func, node.args
        functions = self.verdict.functions
        if name in functions:
            return self.inline(node, functions[name])
        if name == "table":
            return self.table(node)
        if name == "csv":
            if len(args) != 2 or not all(isinstance(a, ast.Str) for a in args):
                raise _Unsure("csv() arguments (E701)")
            self.variable("t", "t")
            return self.opaque("csv:" + args[0].value + ":" + args[1].value, [])
        arity = {"step": (2, 2), "coulomb": (2, 3), "pwm": (3, 3), "mod": (2, 2), "floor": (1, 1),
                 "ceil": (1, 1), "min": (2, None), "max": (2, None)}.get(name, (_ARITY.get(name, 1),) * 2)
        if name not in ("step", "coulomb", "pwm", "mod", "floor", "ceil") and name not in _KNOWN:
            raise _Unsure(f"unknown function {name!r} (E701)")
        if len(args) < arity[0] or (arity[1] is not None and len(args) > arity[1]):
            raise _Unsure(f"{name}() arity (E701)")
        values = [self.value(a) for a in args]
        if name in ("log", "tan", "atan2") and any(v.opaque for v in values):
            raise _Unsure(f"{name}() of a value not modelled: it may be at a pole")
        if name in _OPAQUE:
            return self.opaque(name, values)
        if name == "step":
            return _combine(_step_value, *values)
        if name == "mod":
            x, y = values
            self.nonzero(y, "the divisor of mod()")
            return _combine(lambda a, b: _mod(a, b), x, y)
        if name in ("floor", "ceil"):
            return _combine(lambda a: _floor(a, name == "ceil"), values[0])
        if name in ("min", "max"):
            pick = min if name == "min" else max
            return _combine(lambda *a: (pick(x[0] for x in a), pick(x[1] for x in a)), *values)
        if name == "abs":
            return _combine(_abs, values[0])
        if name == "sign":
            return _combine(_sign, values[0])
        if name == "atan2":
            return _combine(_atan2, *values)
        return _combine(_ELEMENTARY[name], values[0])

    def opaque(self, name: str, values) -> _Value:
        """A function whose value is not modelled: pseudo-random per distinct arguments."""
        key = repr((name, [v.key() for v in values]))
        symbol = _symbol_value(key)
        return _Value(symbol.at, opaque=True)

    def table(self, node) -> _Value:
        args = node.args
        if len(args) != 3 or not all(isinstance(a, ast.ListExpr) for a in args[1:]):
            raise _Unsure("table() arguments (E701)")
        xs, vs = args[1].items, args[2].items
        if len(xs) != len(vs) or not xs:
            raise _Unsure("table() lists (E701)")
        x = self.value(args[0])
        for item in list(xs) + list(vs):
            self.value(item)
        return self.opaque("table", [x])

    def inline(self, node, function) -> _Value:
        if len(node.args) != len(function.params):
            raise _Unsure(f"{function.name}() arity (E701)")
        if function.name in self.calls:
            raise _Unsure(f"{function.name}() calls itself (E701)")
        bound = {param: self.value(arg) for param, arg in zip(function.params, node.args)}
        key = (function.name, tuple(v.key() for v in bound.values()))
        if key in self.applied:
            return self.applied[key]
        self.expansions += sum(1 for _ in ast.walk(function.body))
        if self.expansions > MAX_EXPANSIONS:
            raise _Unsure("too many function expansions")
        self.bound.append(bound)
        self.calls.append(function.name)
        try:
            value = self.value(function.body)
        finally:
            self.bound.pop()
            self.calls.pop()
        self.applied[key] = value
        return value


_KNOWN = frozenset(("abs", "sign", "sqrt", "exp", "log", "sin", "cos", "tan", "tanh", "atan", "atan2",
                    "min", "max"))


def _real(a) -> bool:
    return a is not None and a is not DOMAIN


def _abs(a):
    if a[0] >= 0:
        return a
    if a[1] <= 0:
        return _neg(a)
    return 0.0, max(-a[0], a[1])


def _mod(x, y):
    quotient = _div(x, y)
    if quotient is None:
        return None
    whole = _floor(quotient)
    if whole is None:
        return None
    product = _mul(y, whole)
    return None if product is None else _add(x, _neg(product))


def _truth(a):
    """True, False, or None where the interval holds both 0 and something else."""
    if a == (0.0, 0.0):
        return False
    if _has_zero(a):
        return None
    return True


def _not(a):
    truth = _truth(a)
    return None if truth is None else (0.0, 0.0) if truth else (1.0, 1.0)


def _logical(combine):
    def function(a, b):
        x, y = _truth(a), _truth(b)
        if x is None or y is None:
            return None
        return (1.0, 1.0) if combine(x, y) else (0.0, 0.0)
    return function


_AND = _logical(lambda x, y: x and y)
_OR = _logical(lambda x, y: x or y)


def _compare(test):
    """A comparison of intervals: decided where every pair of values gives the same answer."""
    def function(a, b):
        answers = {test(x, y) for x in a for y in b}
        if len(answers) != 1 or (a[0] != a[1] or b[0] != b[1]) and _overlap(a, b):
            return None
        return (1.0, 1.0) if answers.pop() else (0.0, 0.0)
    return function


def _overlap(a, b) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


_COMPARE = {
    "<": _compare(lambda x, y: x < y),
    "<=": _compare(lambda x, y: x <= y),
    ">": _compare(lambda x, y: x > y),
    ">=": _compare(lambda x, y: x >= y),
    "==": _compare(lambda x, y: x == y),
    "!=": _compare(lambda x, y: x != y),
}


def _degree(node, name: str, functions, bound: frozenset = frozenset()) -> int:
    """The degree of ``node`` in the variable ``name``, 0 or 1 (linear with a coefficient free of
    it, so that its derivative is free of it); raises _Unsure for anything else. Inside a
    function's body its parameters shadow the name."""
    def degree(n) -> int:
        return _degree(n, name, functions, bound)

    kind = type(node).__name__
    if kind in ("Num", "Str", "Ref", "ListExpr"):
        return 0
    if kind == "Name":
        return int(node.name == name and node.name not in bound)
    if kind == "Unary":
        d = degree(node.operand)
        if node.op == "not" and d:
            raise _Unsure("the variable in a condition")
        return d
    if kind == "Binary":
        left, right = degree(node.left), degree(node.right)
        if node.op in ("+", "-"):
            return max(left, right)
        if node.op == "*" and left + right <= 1:
            return left + right
        if node.op == "/" and not right:
            return left
        if left or right:
            raise _Unsure(f"the variable under {node.op!r}")
        return 0
    if kind == "If":
        if degree(node.cond) or degree(node.then) or degree(node.orelse):
            raise _Unsure("the variable in a conditional")
        return 0
    if kind == "Call":
        if any(degree(a) for a in node.args):
            raise _Unsure("the variable in a function's argument")
        function = functions.get(node.func)
        if function is not None and _degree(function.body, name, functions, frozenset(function.params)):
            raise _Unsure("the variable in a function's body")
        return 0
    raise _Unsure(f"an expression of kind {kind}")


def _has_cycle(deps: Mapping[tuple, set]) -> bool:
    """Whether the equations' dependencies (target -> the targets it reads) have a cycle: Kahn's
    algorithm leaves the targets on a cycle."""
    needs = {target: {d for d in found if d in deps} for target, found in deps.items()}
    users: dict = {}
    for target, found in needs.items():
        for d in found:
            users.setdefault(d, []).append(target)
    ready = [t for t, found in needs.items() if not found]
    done = 0
    while ready:
        target = ready.pop()
        done += 1
        for user in users.get(target, ()):
            needs[user].discard(target)
            if not needs[user]:
                ready.append(user)
    return done != len(needs)

"""Dimension checking (LANGUAGE.md section 14): laws, outputs, inputs and bindings are consistent.

Every quantity has one of three kinds of dimension:

- **known**: a vector of exponents over the SI base dimensions (angles count
  as dimensionless), possibly still containing unknowns (below);
- **free**: a number without a unit, a parameter declared without a unit, and
  what is built from them (``2*f``, ``q/1e-9``, ``step(t, 1)*10``, a quantity
  raised to a power that is not a constant simple fraction (denominator at
  most 4), as in an empirical fit ``a*abs(v)^0.27``): it takes whatever dimension makes its expression
  consistent, so it is never an error;
- **unknown**: a measured signal (``csv``), whose dimension is not checked.

The efforts and flows of the bonds are the unknowns. All bonds at a junction
share the dimension of their efforts and of their flows; a transformer or
gyrator relates the two sides by the dimension of its ratio; a storage
element's ``q`` is its flow times seconds and ``p`` its effort times seconds.
Each law, sum, comparison and declared unit is an equation between
dimensions, linear in the exponents. They are solved in tiers — sources and
ratios first, then storage elements, then resistors, then the rest, and the
statements of `when` clauses last (a reinit or an assignment only checks) — each
equation with one unknown left fixing it, so that an inconsistent law is
reported where it is written and not where the domain was first inferred.
Whatever stays unknown is not checked. Every equation whose two sides are
then known and differ is an error (E210) naming both dimensions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import functools
from fractions import Fraction
from typing import Callable, Mapping, Union

from bondc import ast
from bondc.errors import Diagnostic, Related
from bondc.model import BondGraph
from bondc.source import Span
from bondc.units import BASE_DIMENSIONS, SIUnit
from bondc import codes

_N = len(BASE_DIMENSIONS) - 1          # the angle pseudo-dimension is dropped: angles are dimensionless
FREE, UNKNOWN = "free", "unknown"


#: An exponent of a base dimension: an int when whole (fast), else a Fraction.
Exponent = Union[int, Fraction]


def _exponent(value) -> Exponent:
    """An exponent as an int when it is whole (ints add 50 times faster than Fractions, and compare
    and hash equal to them), else the Fraction."""
    value = Fraction(value)
    return int(value) if value.denominator == 1 else value


def _vec(dims) -> tuple[Exponent, ...]:
    return tuple(_exponent(d) for d in dims[:_N])


_ZERO = (0,) * _N
_SECOND = tuple(1 if name == "s" else 0 for name in BASE_DIMENSIONS[:_N])


@dataclass(frozen=True)
class Form:
    """A dimension: ``const`` plus a combination of unknowns (exponent vectors add: ``a*b`` -> ``a + b``)."""

    const: tuple[Exponent, ...]
    terms: tuple[tuple[int, Exponent], ...] = ()

    @staticmethod
    def of(dims) -> "Form":
        return Form(_vec(dims))

    @staticmethod
    def var(index: int) -> "Form":
        return Form(_ZERO, ((index, 1),))

    def plus(self, other: "Form", sign: int = 1) -> "Form":
        terms = dict(self.terms)
        for index, coefficient in other.terms:
            terms[index] = terms.get(index, 0) + (coefficient if sign == 1 else -coefficient)
        return Form(_add(self.const, other.const, sign), tuple(sorted((i, c) for i, c in terms.items() if c != 0)))

    def times(self, factor: Fraction) -> "Form":
        return Form(tuple(_exponent(a * factor) for a in self.const),
                    tuple((i, c * factor) for i, c in self.terms if c * factor))


Dim = object     # Form | FREE | UNKNOWN


def _add(a: tuple, b: tuple, factor=1) -> tuple:
    """a + factor*b for exponent vectors (Fractions are slow: nothing is computed for a zero b,
    the common dimensionless or already-substituted case)."""
    if b == _ZERO:
        return a
    if factor == 1:
        return tuple(x + y for x, y in zip(a, b))
    if factor == -1:
        return tuple(x - y for x, y in zip(a, b))
    return tuple(x + factor * y for x, y in zip(a, b))


@functools.lru_cache(maxsize=4096)
def _text(vector: tuple) -> str:
    return SIUnit(1.0, vector + (Fraction(0),), "").dimension_text()


def text(vector) -> str:
    return _text(tuple(vector))


def _mul(a, b, sign: int = 1):
    if a == FREE or b == FREE:
        return FREE
    if a == UNKNOWN or b == UNKNOWN:
        return UNKNOWN
    return a.plus(b, sign)


@dataclass
class _Equation:
    left: Form
    right: Form
    span: Span
    kind: str           # "law", "sum", "compare", "output", "input", "binding", "branch", "argument", ...
    what: str           # for the message: "e of R 'valve'", "the output 'v'", ...
    tier: int


@dataclass(frozen=True)
class Context:
    """What the checker needs from the semantic stage."""

    graph: BondGraph
    unit_of: Callable[[ast.Unit | None], SIUnit | None]
    params: Mapping[str, ast.Param]
    inputs: Mapping[str, ast.Input]
    outputs: Mapping[str, ast.Output]
    discretes: Mapping[str, ast.Discrete]
    state_units: Mapping[str, ast.Unit | None]           # qualified state name -> declared unit
    functions: Mapping[str, object]                      # name -> FnDef/Function (params, body)
    values: Mapping[str, float]                          # parameter SI values (constant exponents)


@dataclass
class _Checker:
    ctx: Context
    equations: list[_Equation] = field(default_factory=list)
    names: list[str] = field(default_factory=list)      # unknown index -> what it is
    effort: dict[int, int] = field(default_factory=dict)
    flow: dict[int, int] = field(default_factory=dict)
    state: dict[str, int] = field(default_factory=dict)
    memo: dict = field(default_factory=dict)
    tier: int = 3

    # -- unknowns

    def new(self, what: str) -> Form:
        self.names.append(what)
        return Form.var(len(self.names) - 1)

    def declared(self, unit) -> Form | None:
        resolved = self.ctx.unit_of(unit) if unit is not None else None
        return None if resolved is None else Form.of(resolved.dims)

    # -- expressions

    def dim(self, node, local: Mapping[str, object], owner=None):
        method = getattr(self, "_" + type(node).__name__)
        return method(node, local, owner)

    def _Num(self, node, local, owner):
        return FREE

    def _Str(self, node, local, owner):
        return UNKNOWN

    def _ListExpr(self, node, local, owner):
        return self.agree([self.dim(item, local, owner) for item in node.items], node.items, "list")

    def _Name(self, node, local, owner):
        name = node.name
        if name in local:
            return local[name]
        if name == "t":
            return Form(_SECOND)
        if name == "pi":
            return FREE
        ctx = self.ctx
        if name in ctx.params:
            return self.declared(ctx.params[name].unit) or FREE
        if name in ctx.inputs:
            item = ctx.inputs[name]
            return self.declared(item.unit) or self.signal(("input", name), item.value)
        if name in ctx.outputs:
            item = ctx.outputs[name]
            return self.declared(item.unit) or self.signal(("output", name), item.value)
        if name in ctx.discretes:
            item = ctx.discretes[name]
            return self.declared(item.unit) or self.signal(("discrete", name), item.value)
        if name in self.state:
            return Form.var(self.state[name])
        return UNKNOWN

    def signal(self, key, expr):
        """The dimension of a named expression (an input or output without a unit), once."""
        if key in self.memo:
            return self.memo[key]
        self.memo[key] = UNKNOWN           # a cycle (reported elsewhere) stays unchecked
        value = self.dim(expr, {}) if expr is not None else UNKNOWN
        self.memo[key] = value
        return value

    def _Ref(self, node, local, owner):
        from bondc.causality import resolve_reference

        target = resolve_reference(self.ctx.graph, {}, node.parts, owner)
        if target is None:
            return UNKNOWN
        kind, what = target
        if kind == "state":
            return Form.var(self.state[what]) if what in self.state else UNKNOWN
        return Form.var(self.effort[what] if kind == "e" else self.flow[what])

    def _Unary(self, node, local, owner):
        value = self.dim(node.operand, local, owner)
        return FREE if node.op == "not" else value

    def _Binary(self, node, local, owner):
        op = node.op
        if op in ("and", "or"):
            self.dim(node.left, local, owner)
            self.dim(node.right, local, owner)
            return FREE
        left = self.dim(node.left, local, owner)
        if op == "^":
            return self.power(left, node.right, local, owner)
        right = self.dim(node.right, local, owner)
        if op == "*":
            return _mul(left, right)
        if op == "/":
            return _mul(left, right, -1)
        kind = "sum" if op in ("+", "-") else "compare"
        self.equal(left, right, node.span, kind, f"'{op}'")
        if kind == "compare":
            return FREE
        return right if left == FREE or left == UNKNOWN else left

    def power(self, base, exponent_node, local, owner):
        exponent = self.dim(exponent_node, local, owner)
        if isinstance(exponent, Form):
            self.equal(exponent, Form(_ZERO), exponent_node.span, "exponent", "an exponent")
        if base == FREE or base == UNKNOWN:
            return base
        value = self.constant(exponent_node)
        if value is None:
            return Form(_ZERO) if not base.terms and base.const == _ZERO else FREE
        fraction = Fraction(value).limit_denominator(4)     # 2, -1, 1/2, 1/3, 3/4: exact; 1.7: a fit
        if abs(float(fraction) - value) > 1e-12:
            return FREE if base.terms or base.const != _ZERO else base
        return base.times(fraction)

    def constant(self, node) -> float | None:
        """The value of a constant exponent (numbers and parameters), else None."""
        from bondc.evaluate import EvaluationError, evaluate

        if any(isinstance(n, (ast.Ref, ast.Call)) or (isinstance(n, ast.Name) and n.name not in self.ctx.values
                                                       and n.name != "pi") for n in ast.walk(node)):
            return None
        try:
            return float(evaluate(node, self.ctx.values, {}))
        except (EvaluationError, TypeError, ValueError, ZeroDivisionError, OverflowError):
            return None

    def _If(self, node, local, owner):
        self.dim(node.cond, local, owner)
        then = self.dim(node.then, local, owner)
        orelse = self.dim(node.orelse, local, owner)
        self.equal(then, orelse, node.span, "branch", "the branches of 'if'")
        return orelse if then in (FREE, UNKNOWN) else then

    def agree(self, values, nodes, what):
        """The common dimension of arguments that must agree (each pair checked)."""
        known = None
        for value, node in zip(values, nodes):
            if value in (FREE, UNKNOWN):
                continue
            if known is None:
                known = value
            else:
                self.equal(known, value, node.span, "argument", what)
        return known if known is not None else (UNKNOWN if UNKNOWN in values else FREE)

    def _Call(self, node, local, owner):
        func, args = node.func, node.args
        if func in self.ctx.functions:
            return self.call(func, [self.dim(a, local, owner) for a in args])
        if func == "csv":
            return UNKNOWN
        values = [self.dim(a, local, owner) for a in args]
        if func in ("abs", "floor", "ceil"):
            return values[0] if values else FREE
        if func in ("min", "max", "mod"):
            return self.agree(values, args, f"the arguments of '{func}'")
        if func == "sqrt":
            return values[0].times(Fraction(1, 2)) if isinstance(values[0], Form) else values[0]
        if func == "table" and len(args) == 3:
            x = values[0]
            xs = values[1]
            if isinstance(x, Form) and isinstance(xs, Form):
                self.equal(x, xs, args[1].span, "argument", "the breakpoints and the value of 'table'")
            return values[2]
        if func == "step" and len(args) == 2:
            self.agree(values, args, "the arguments of 'step'")
            return FREE
        if func == "atan2":
            self.agree(values, args, "the arguments of 'atan2'")
            return FREE
        if func == "coulomb":
            return self.agree(values[1:], args[1:], "the friction limits of 'coulomb'")
        return FREE           # sign, pwm, exp, log, sin, cos, tan, tanh, atan: numbers

    def call(self, name, arguments):
        function = self.ctx.functions[name]
        key = (name, tuple(repr(a) for a in arguments))
        if key in self.memo:
            return self.memo[key]
        self.memo[key] = UNKNOWN            # recursion (an error elsewhere) stays unchecked
        body = getattr(function, "body")
        value = self.dim(body, dict(zip(function.params, arguments)))
        self.memo[key] = value
        return value

    # -- equations

    def equal(self, left, right, span: Span, kind: str, what: str) -> None:
        if isinstance(left, Form) and isinstance(right, Form):
            self.equations.append(_Equation(left, right, span, kind, what, self.tier))


def _substitute(form: Form, known: Mapping[int, tuple]) -> Form:
    const = form.const
    terms = []
    for index, coefficient in form.terms:
        if index in known:
            const = _add(const, known[index], coefficient)
        else:
            terms.append((index, coefficient))
    return Form(const, tuple(terms))


def _solve(equations: list[_Equation], source: dict[int, _Equation] | None = None) -> dict[int, tuple]:
    """Fix every unknown that some equation determines, tier by tier (``source``: which one).

    Passes over the equations in order, as often as one fixes an unknown; each equation's
    difference ``left - right`` is kept with the known unknowns substituted, updated only when one
    of its own unknowns became known, and left out once it has none (it cannot change again)."""
    known: dict[int, tuple] = {}
    source = {} if source is None else source
    forms: dict[int, Form] = {}         # id(equation) -> its difference, known unknowns substituted
    settled: set[int] = set()           # equations without unknowns
    for tier in sorted({e.tier for e in equations}):
        active = [e for e in equations if e.tier <= tier]
        changed = True
        while changed:
            changed = False
            for equation in active:
                key = id(equation)
                if key in settled:
                    continue
                difference = forms.get(key)
                if difference is None:
                    difference = _substitute(equation.left.plus(equation.right, -1), known)
                elif any(index in known for index, _ in difference.terms):
                    difference = _substitute(difference, known)
                forms[key] = difference
                if len(difference.terms) == 1:
                    index, coefficient = difference.terms[0]
                    known[index] = tuple(_exponent(Fraction(-c) / coefficient) for c in difference.const)
                    source[index] = equation
                    changed = True
                elif not difference.terms:
                    settled.add(key)
    return known


def check(ctx: Context) -> list[Diagnostic]:
    """E210 for every equation between dimensions whose two sides are known and differ."""
    return analyse(ctx)[0]


def analyse(ctx: Context) -> tuple[list[Diagnostic], dict[str, str]]:
    """The E210 diagnostics, and the SI unit of every state and bond variable whose dimension is
    known: ``{"mass.p": "kg*m/s", "b3.e": "kg/(m*s^2)", ...}`` (for result files)."""
    graph = ctx.graph
    c = _Checker(ctx)
    # unknowns: one effort and one flow dimension per set of bonds joined at junctions
    parent = {b.number: b.number for b in graph.bonds}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for junction in graph.junctions.values():
        for a, b in zip(junction.bonds, junction.bonds[1:]):
            parent[find(a)] = find(b)
    roots: dict[int, tuple[int, int]] = {}
    for bond in graph.bonds:
        root = find(bond.number)
        if root not in roots:
            roots[root] = (c.new(f"effort of bond {bond.name}").terms[0][0],
                           c.new(f"flow of bond {bond.name}").terms[0][0])
        c.effort[bond.number], c.flow[bond.number] = roots[root]
    for state in graph.states:
        unit = ctx.state_units.get(state.qualified)
        declared = c.declared(unit)
        index = c.new(f"state {state.qualified}").terms[0][0]
        c.state[state.qualified] = index
        if declared is not None:
            c.tier = 0
            c.equal(Form.var(index), declared, state.span, "state", f"state '{state.qualified}'")

    for element in graph.elements.values():
        kind, info = element.kind, element.kind_info
        c.tier = info.tier
        local: dict[str, Form] = {}
        if len(element.bonds) == 1:
            local["e"], local["f"] = Form.var(c.effort[element.bond]), Form.var(c.flow[element.bond])
        for state in element.states:
            own = Form.var(c.state[state.qualified])
            local[state.name] = own
            if state.rate is None and info.integrates:    # the default state: q integrates f, p integrates e
                integral = local[info.integrates].plus(Form(_SECOND))
                c.equal(own, integral, state.span, "state", f"'{state.qualified}'")
        for target, expr in element.laws.items():
            span = element.law_spans.get(target, element.span) if element.law_spans else element.span
            value = c.dim(expr, local, element.name)
            if target in ("e", "f") and len(element.bonds) == 1:
                c.equal(local[target], value, span, "law", f"{target} of {kind} '{element.name}'")
            elif target == "r" and len(element.bonds) == 2 and isinstance(value, Form):
                ports = {}
                for port, number in zip(("p1", "p2"), element.bonds):
                    ports[f"{port}.e"], ports[f"{port}.f"] = Form.var(c.effort[number]), Form.var(c.flow[number])
                for left, right in info.ratios:     # left = r * right
                    c.equal(ports[left], value.plus(ports[right]), span, "ratio",
                            f"{left} = r*{right} of {kind} '{element.name}'")
        for state in element.states:
            own = Form.var(c.state[state.qualified])
            if state.rate is not None:
                rate = c.dim(state.rate, local, element.name)
                c.equal(own.plus(Form(_SECOND), -1), rate, state.span, "rate", f"der({state.qualified})")
            if state.initial is not None:
                c.equal(own, c.dim(state.initial, local, element.name), state.span, "initial",
                        f"the initial value of '{state.qualified}'")
    c.tier = 3
    for state in graph.model_states:
        own = Form.var(c.state[state.qualified])
        if state.rate is not None:
            c.equal(own.plus(Form(_SECOND), -1), c.dim(state.rate, {}), state.span, "rate", f"der({state.name})")
        if state.initial is not None:
            c.equal(own, c.dim(state.initial, {}), state.span, "initial", f"the initial value of '{state.name}'")
    for name, output in ctx.outputs.items():
        declared = c.declared(output.unit)
        value = c.dim(output.value, {})
        if declared is not None and output.unit is not None:
            c.equal(declared, value, output.value.span, "output", f"output '{name}' [{output.unit.text}]")
    for name, signal in ctx.inputs.items():
        declared = c.declared(signal.unit)
        if declared is not None and signal.unit is not None and signal.value is not None:
            c.equal(declared, c.dim(signal.value, {}), signal.value.span, "input",
                    f"input '{name}' [{signal.unit.text}]")
    c.tier = 4          # the statements of when clauses check, last: they decide no dimension
    for when in getattr(graph, "whens", ()):
        c.dim(when.condition, {})
        for kind, target, value in when.actions:
            # a discrete variable set, a state reinitialised: the value measures what it replaces
            name = target.name if isinstance(target, ast.Name) else target.dotted
            what = f"{name} = ..." if kind == "assign" else f"reinit({name}, ...)"
            c.equal(c.dim(target, {}), c.dim(value, {}), value.span, "assign",
                    f"{what} in '{when.text}'")

    source: dict[int, _Equation] = {}
    known = _solve(c.equations, source)
    diagnostics = []
    for equation in c.equations:
        left_side = _substitute(equation.left, known)
        right_side = _substitute(equation.right, known)
        if left_side.terms or right_side.terms or left_side.const == right_side.const:
            continue
        related: list[Related] = []
        for index, _ in equation.left.terms + equation.right.terms:
            origin = source.get(index)
            if origin is not None and origin is not equation and origin.span != equation.span \
                    and all(r.span != origin.span for r in related):
                related.append(Related(origin.span, f"the {c.names[index]} is {text(known[index])} from "
                                                    f"{origin.what} here"))
        diagnostics.append(_diagnostic(equation, left_side.const, right_side.const, related[:2]))
    found: dict[str, str] = {}
    for qualified, index in c.state.items():
        if index in known:
            found[qualified] = text(known[index])
    for bond in graph.bonds:
        for variable, table in (("e", c.effort), ("f", c.flow)):
            unknown = table.get(bond.number)
            if unknown is not None and unknown in known:
                found[f"{bond.name}.{variable}"] = text(known[unknown])
    # a pseudo bond graph (temperature and heat flow: e*f in K*W) has its own "energy" unit
    joule = Form.of(SIUnit(1.0, tuple(map(Fraction, (2, 1, -2, 0, 0, 0, 0, 0))), "J").dims).const
    for element in graph.elements.values():
        first = element.bonds[0] if element.bonds else None
        e, f = (c.effort.get(first), c.flow.get(first)) if first is not None else (None, None)
        if e in known and f in known:
            energy = tuple(a + b + s for a, b, s in zip(known[e], known[f], _SECOND))
            if energy != joule:         # written relative to the joule: K*J, J/m
                rest = text(tuple(a - b for a, b in zip(energy, joule)))
                found[f"energy:{element.name}"] = f"J/{rest[2:]}" if rest.startswith("1/") else f"{rest}*J"
    return diagnostics, found


#: What E210 says for each kind of equation: (message, hint), the message formatted with the two
#: dimensions ``a`` and ``b`` and the equation's ``what``.
_DECLARED = ("{what} is {a}, but its expression is {b}",
             "declare the unit of what the expression computes, or fix the expression")
_MESSAGES: Mapping[str, tuple[str, str]] = {
    "sum": ("cannot add or subtract {a} and {b}",
            "both terms of a sum must measure the same quantity; check the units of the names involved"),
    "compare": ("cannot compare {a} with {b}", "both sides of a comparison must measure the same quantity"),
    "branch": ("the branches of 'if' differ: {a} and {b}", "both branches must give the same quantity"),
    "output": _DECLARED,
    "input": _DECLARED,
    "law": ("the two sides of the law differ: {what} is {a}, but the expression is {b}",
            "the bond's domain comes from the elements around it; check the units of the parameters in the law"),
    "assign": ("{what} sets {a} to {b}",
               "the new value must measure the same quantity as the variable or state it replaces"),
    "exponent": ("an exponent must be dimensionless, not {b}", "divide by a reference quantity of the same unit"),
}
_OTHER = ("dimensions differ in {what}: {a} and {b}", "check the units of the quantities involved")


def _diagnostic(equation: _Equation, left, right, related=()) -> Diagnostic:
    template, hint = _MESSAGES.get(equation.kind, _OTHER)
    message = template.format(a=text(left), b=text(right), what=equation.what)
    return Diagnostic("error", codes.E210, message, equation.span, hint, tuple(related))

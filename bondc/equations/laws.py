"""The equations' symbols and laws: every quantity of the graph a sympy symbol (:class:`Laws`),
a law translated from the AST (:class:`bondc.symbolic.Translator`), and inverted where causality
needs it in the other form (``E605``). The state every step of the derivation shares is set up
here; the other modules of :mod:`bondc.equations` add the steps.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Mapping

import sympy

from bondc import ast
from bondc.causality import ROLES, CausalGraph, describe_node, element_span
from bondc.errors import Diagnostic, EquationError
from bondc.evaluate import ExpansionBudget
from bondc.model import ElementNode, readable_names
from bondc.source import NO_SPAN
from bondc.statespace import AlgebraicBlock
from bondc.symbolic import TRANSLATION_IN_ALL, Csv, External, Step, Table, Translator, as_sympy
from bondc import codes

_OPAQUE = (sympy.Piecewise, sympy.Abs, sympy.sign, sympy.Min, sympy.Max, sympy.Heaviside, Table, Step, Csv, External)

def _real(name: str) -> sympy.Symbol:
    return sympy.Symbol(name, real=True)


class _Equation:
    __slots__ = ("target", "rhs", "node", "role", "index")

    def __init__(self, target, rhs, node: str, role: str, index: int):
        self.target, self.rhs, self.node, self.role, self.index = target, rhs, node, role, index


class _Dependent:
    """A storage element in derivative causality."""

    def __init__(self, element: ElementNode, state: sympy.Symbol, rate, unknown: sympy.Symbol):
        self.element, self.state, self.rate, self.unknown = element, state, rate, unknown


def _error(code: str, message: str, span=NO_SPAN, hint: str | None = None, related=()) -> EquationError:
    return EquationError(Diagnostic("error", code, message, span or NO_SPAN, hint=hint, related=tuple(related)))


class Laws:
    """The derivation's state: the symbols, the equations the nodes contribute (:mod:`.rules`),
    then the assignments in causal order (:mod:`.loops`, :mod:`.derivative`) that
    :mod:`.assemble` makes a StateSpace of; and the laws, translated and inverted."""

    # set in causal order by Ordering.order (loops.py); the elimination and the assembly read them
    by_target: dict[sympy.Symbol, _Equation]        # each equation by the variable it assigns
    deps: dict[sympy.Symbol, list[sympy.Symbol]]    # the variables each one's right-hand side uses
    assignments: list[tuple]                        # (symbol, expression) in the order they are computed
    blocks: list[AlgebraicBlock]                    # the loops solved numerically

    @functools.cached_property
    def element_names(self) -> dict:
        """{bond variable: the element variable it is} for the messages (b2.e -> r1.e)."""
        return readable_names(self.graph)

    def __init__(self, causal: CausalGraph):
        self.causal = causal
        graph = self.graph = causal.graph
        self.t = _real("t")
        self.symbols: dict[str, sympy.Symbol] = {"t": self.t}
        self.parameters = {name: self._new_symbol(name) for name in graph.parameters}
        self.param_values = {self.parameters[n]: p.value for n, p in graph.parameters.items()}
        self.values_consulted = False
        self.input_symbols = {name: self._new_symbol(name) for name in graph.inputs}
        self.output_symbols = {name: self._new_symbol(name) for name in graph.outputs}
        self.state_symbols = {s.qualified: self._new_symbol(s.qualified) for s in graph.states}
        self.bond_symbols = {}
        for bond in graph.bonds:
            self.bond_symbols[bond.number] = (self._new_symbol(f"{bond.name}.e"), self._new_symbol(f"{bond.name}.f"))
        self.equations: list[_Equation] = []
        self.rates: dict[str, sympy.Expr] = {}
        self.dependents: list[_Dependent] = []
        self.diagnostics: list[Diagnostic] = []
        self.law_memo: dict = {}
        self.base_dir = Path(graph.file).parent if graph.file else None
        # what translating the laws may spend on expanding fn calls, for the whole model (E319)
        self.budget = ExpansionBudget.for_sources(getattr(graph, "sources", None) or {}, TRANSLATION_IN_ALL)

    def _new_symbol(self, name: str) -> sympy.Symbol:
        if name in self.symbols:
            raise _error(codes.E701, f"the name '{name}' is used for two different quantities",
                         hint="rename the parameter, input, output or state")
        symbol = _real(name)
        self.symbols[name] = symbol
        return symbol

    # ------------------------------------------------------------ translation

    def e(self, bond: int) -> sympy.Symbol:
        return self.bond_symbols[bond][0]

    def f(self, bond: int) -> sympy.Symbol:
        return self.bond_symbols[bond][1]

    def translate(self, expr: ast.Expr, owner: ElementNode | None = None, local: Mapping | None = None):
        local = dict(local or {})
        graph = self.graph
        if owner is not None:
            if len(owner.bonds) == 1:
                local.setdefault("e", self.e(owner.bond))
                local.setdefault("f", self.f(owner.bond))
            for state in owner.states:
                local.setdefault(state.name, self.state_symbols[state.qualified])

        scope = getattr(graph, "scope", None)

        def resolve_name(name, node):
            if name in local:
                return local[name]
            if name == "t":
                return self.t
            category = scope.category(name) if scope is not None else None
            if category == "parameter":
                return self.parameters[name]
            if category == "input":
                return self.input_symbols[name]
            if category == "output":
                return self.output_symbols[name]
            if category in ("state", "discrete"):
                return self.state_symbols[name]
            if name in self.parameters:         # a graph built without a scope (by hand, in tests)
                return self.parameters[name]
            if name in self.input_symbols:
                return self.input_symbols[name]
            if name in self.output_symbols:
                return self.output_symbols[name]
            for state in graph.model_states:
                if state.name == name:
                    return self.state_symbols[state.qualified]
            if name == "pi":
                return sympy.pi
            raise _error(codes.E701, f"unknown name '{name}'", node.span)

        def resolve_ref(node):
            target = self.causal.reference(node.parts, owner.name if owner is not None else None)
            if target is None:
                raise _error(codes.E701, f"'{node.dotted}' names no variable of the graph", node.span)
            kind, what = target
            if kind == "state":
                return self.state_symbols[what]
            return self.e(what) if kind == "e" else self.f(what)

        translator = Translator(resolve_name, resolve_ref, graph.functions, self.base_dir, self.t, self.budget)
        return translator(expr)

    def law(self, element: ElementNode, target: str, local: Mapping | None = None):
        if local:
            return self.translate(element.laws[target], element, local)
        key = (element.name, target)      # a storage law is read again for its energy function
        if key not in self.law_memo:
            self.law_memo[key] = self.translate(element.laws[target], element)
        return self.law_memo[key]

    def add(self, target, rhs, node: str, role: str) -> None:
        self.equations.append(_Equation(target, as_sympy(rhs), node, role, len(self.equations)))

    # ------------------------------------------------------------- inversion

    def invert(self, expr, variable: sympy.Symbol, value, element: ElementNode, law: str, wanted: str):
        """The ``variable`` for which ``expr == value``, or E605."""
        derivative = sympy.diff(expr, variable)
        if variable not in derivative.free_symbols and derivative != 0 and not derivative.has(sympy.DiracDelta):
            base = expr.xreplace({variable: sympy.Integer(0)})
            return (value - base) / derivative
        solution = self._solve_nonlinear(expr, variable) if not expr.has(*_OPAQUE) else None
        if solution is None:
            span = element.law_spans.get(law) if element.law_spans else None
            other = {"e": "f", "f": "e"}.get(law, "q")
            if ROLES.get(element.kind) == "resistor":
                hint = (f"give the other form as well: `{other} = ...` next to `{law} = ...` "
                        f"(the law solved for {other})")
            else:
                hint = ("the causality needs the state as a function of the port variable; "
                        "give an invertible law, or add compliance/inertia to avoid derivative causality")
            raise _error(codes.E605,
                         f"the law `{law} = ...` of {describe_node(self.graph, element.name)} must be solved for "
                         f"{wanted} ({'conductance' if wanted == 'f' else 'the causality'} needs it) and "
                         "bondc cannot invert it",
                         span if span is not None and span.line > 0 else element_span(element), hint=hint)
        return solution.xreplace({self._value_dummy: value})

    _value_dummy = sympy.Dummy("y", real=True)

    def _solve_nonlinear(self, expr, variable):
        if sympy.count_ops(expr) > 60:
            return None
        try:
            candidates = sympy.solve(sympy.Eq(expr, self._value_dummy), variable)
        except (NotImplementedError, ValueError, TypeError):
            return None
        others = sorted(expr.free_symbols - {variable}, key=lambda s: s.name)
        values = {s: self.param_values.get(s, 0.7) for s in others}
        if any(s in self.param_values for s in others):
            self.values_consulted = True        # the parameters' values chose the inverse
        accepted = [c for c in candidates if self._reproduces(expr, variable, c, values)]
        return accepted[0] if len(accepted) == 1 else None

    def _reproduces(self, expr, variable, candidate, values) -> bool:
        checked = 0
        for sample in (-1.7, -0.35, 0.2, 1.3):
            try:
                y = complex(expr.xreplace({**values, variable: sympy.Float(sample)}).evalf())
            except (TypeError, ValueError, ZeroDivisionError):
                continue
            if abs(y.imag) > 1e-12 or not math.isfinite(y.real):
                continue
            try:
                back = complex(candidate.xreplace({**values, self._value_dummy: sympy.Float(y.real)}).evalf())
            except (TypeError, ValueError, ZeroDivisionError):
                return False
            if abs(back.imag) > 1e-9 * max(1.0, abs(sample)) or abs(back.real - sample) > 1e-7 * max(1.0, abs(sample)):
                return False
            checked += 1
        return checked >= 2

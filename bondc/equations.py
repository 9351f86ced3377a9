"""Equations stage: :class:`~bondc.causality.CausalGraph` -> :class:`~bondc.statespace.StateSpace`.

Every node of the causal graph contributes the equations for the variables its
causality makes it compute (a ``C`` in integral causality its bond's effort, a
0-junction the efforts of its other bonds and the flow of its strong bond, a
transformer one effort and one flow, ...). Laws are translated from the AST by
:class:`bondc.symbolic.Translator`. The equations are then put in causal order
(strongly connected components of their dependencies, topologically sorted):

- an acyclic equation becomes one assignment;
- an algebraic loop (a cyclic component) is torn: a few tearing variables
  (resistors' outputs first) are chosen so the rest of the loop is a chain,
  the chain is substituted into the tearing equations, and those are solved
  symbolically when they are linear in the tearing variables (a square linear
  system), else kept as an :class:`~bondc.statespace.AlgebraicBlock` solved
  numerically at run time (``W604``);
- storage elements in derivative causality are eliminated: their state is
  assigned from the law inverted (``q = C*e``), the time derivative of that
  expression in the independent states (chain rule with their state
  equations, plus the explicit time dependence through inputs) is equated to
  their rate law, and the resulting implicit equations are solved for their
  port variables (two inertias joined by a gear become one state with the
  combined inertia).

A law that causality needs in the other form (``f = ...`` when only
``e = ...`` is written) is inverted symbolically: directly when it is linear in
the variable, else with ``sympy.solve`` when exactly one solution reproduces
the law at sample points on both sides of zero; otherwise ``E605``.

Nothing is simplified: laws keep the form they were written in.

Diagnostics: ``E605`` law cannot be inverted, ``E701`` expression cannot be
translated, ``E702`` singular algebraic loop, ``E703`` derivative causality
that cannot be resolved, ``W604`` nonlinear algebraic loop solved numerically,
``W704`` initial value of an eliminated state ignored.
"""

from __future__ import annotations

import dataclasses
import functools
import heapq
import json
import math
import re
from pathlib import Path
from typing import Mapping

import sympy
from sympy.core.symbol import Str as _SymStr
from sympy.printing.str import StrPrinter

from bondc import ast
from bondc.causality import (CONDUCTANCE, DERIVATIVE, ROLES, CausalGraph, describe_node, element_span, join_words,
                             strongly_connected)
from bondc.errors import Diagnostic, EquationError, Related
from bondc.evaluate import ExpansionBudget
from bondc.model import ElementNode, JunctionNode, readable_names
from bondc.source import NO_SPAN
from bondc.statespace import AlgebraicBlock, StateInfo, StateSpace
from bondc.symbolic import (TRANSLATION_IN_ALL, Csv, External, Step, Table, Translator, discontinuities, strip_impulses,
                            as_sympy)
from bondc import codes

_OPAQUE = (sympy.Piecewise, sympy.Abs, sympy.sign, sympy.Min, sympy.Max, sympy.Heaviside, Table, Step, Csv, External)
_ENERGY_VARIABLE = sympy.Dummy("s", real=True)      # the integration variable of stored-energy functions


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


class _Deriver:
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

    # ------------------------------------------------------------ node rules

    def build(self) -> None:
        graph = self.graph
        for name, signal in graph.inputs.items():
            value = self.translate(signal.expr)
            if getattr(signal, "external", False):     # supplied by the host; its default otherwise
                value = External(self.t, _SymStr(name), value)
            self.add(self.input_symbols[name], value, name, "input")
        for element in graph.elements.values():
            getattr(self, "_" + ROLES[element.kind])(element)
        for junction in graph.junctions.values():
            self._junction(junction)
        for state in graph.model_states:
            rate = self.translate(state.rate) if state.rate is not None else sympy.Integer(0)
            self.rates[state.qualified] = rate
        for name, output in graph.outputs.items():
            self.add(self.output_symbols[name], self.translate(output.expr), name, "output")

    def _source(self, element: ElementNode) -> None:
        bond = element.bond
        if self.causal.sets_effort(bond, element.name):
            self.add(self.e(bond), self.law(element, "e"), element.name, "source")
        else:
            self.add(self.f(bond), self.law(element, "f"), element.name, "source")

    def _storage(self, element: ElementNode) -> None:
        bond = element.bond
        is_c = element.kind_info.storage == "C"
        port_out, port_in = (self.e(bond), self.f(bond)) if is_c else (self.f(bond), self.e(bond))
        law = "e" if is_c else "f"
        rates = {}
        for state in element.states:
            if state.rate is not None:
                rates[state.qualified] = self.translate(state.rate, element)
            else:
                rates[state.qualified] = port_in
        if self.causal.storage[element.name] != DERIVATIVE:
            self.add(port_out, self.law(element, law), element.name, "storage")
            self.rates.update(rates)
            return
        # Derivative causality: the port input (e for a C) is fixed by the rest of the
        # graph; the state follows from the law, its rate from the others' states.
        if len(element.states) != 1:
            raise _error(codes.E703, f"{describe_node(self.graph, element.name)} is in derivative causality and has "
                                 f"{len(element.states)} states; bondc can eliminate only a single-state element",
                         element_span(element),
                         hint="add compliance or inertia so that it gets integral causality")
        state = element.states[0]
        symbol = self.state_symbols[state.qualified]
        dummy = sympy.Dummy(state.name, real=True)
        expr = self.law(element, law, {state.name: dummy})
        # In derivative causality the element receives what it would deliver in integral
        # causality (the effort of a C) and must deliver the other (the flow of a C).
        value = self.invert(expr, dummy, port_out, element, law, wanted=state.name)
        self.add(symbol, value, element.name, "state")
        self.dependents.append(_Dependent(element, symbol, rates[state.qualified], port_in))
        if state.initial is not None and not self._zero_initial(state.initial):
            self.diagnostics.append(Diagnostic(
                "warning", codes.W704,
                f"the initial value of '{state.qualified}' is ignored: {describe_node(self.graph, element.name)} is "
                "in derivative causality, so its state follows from the other states",
                state.initial.span if getattr(state.initial, "span", NO_SPAN).line > 0 else element_span(element)))

    def _zero_initial(self, expr) -> bool:
        """Whether an initial value is 0 with the parameters' values (a component's ``p(0) =
        J*w0`` with its default ``w0 = 0``: nothing is ignored, W704 would only be noise)."""
        from bondc.evaluate import EvaluationError, evaluate

        if isinstance(expr, ast.Num):
            return expr.value == 0
        self.values_consulted = True        # the warning depends on the values: checked after each edit
        values = {name: p.value for name, p in self.graph.parameters.items() if p.value is not None}
        try:
            return evaluate(expr, values, self.graph.functions) == 0.0
        except EvaluationError:
            return False        # it uses more than parameters (an input at t = 0): say it is ignored

    def _resistor(self, element: ElementNode) -> None:
        bond = element.bond
        e, f = self.e(bond), self.f(bond)
        if self.causal.resistors[element.name] == CONDUCTANCE:
            if "f" in element.laws:
                rhs = self.law(element, "f")
            else:
                dummy = sympy.Dummy("f", real=True)
                rhs = self.invert(self.law(element, "e", {"f": dummy}), dummy, e, element, "e", "f")
            self.add(f, rhs, element.name, "resistor")
        else:
            if "e" in element.laws:
                rhs = self.law(element, "e")
            else:
                dummy = sympy.Dummy("e", real=True)
                rhs = self.invert(self.law(element, "f", {"e": dummy}), dummy, f, element, "f", "e")
            self.add(e, rhs, element.name, "resistor")

    def _ports(self, element: ElementNode):
        (b1, b2), (s1, s2) = element.bonds, element.port_signs
        return b1, b2, sympy.Integer(s1), sympy.Integer(s2), self.law(element, "r")

    def _divisor(self, element: ElementNode, r):
        """``r``, the ratio a two-port's equations divide by in its causality: E606 where it is 0
        whatever the values (``r = 0``, ``0/Ar``): the equations would divide by zero."""
        if r.is_zero:
            kind, law = (("transformer", "p2.e = p1.e/r") if element.kind in ("TF", "MTF")
                         else ("gyrator", "p2.f = p1.e/r"))
            raise _error(codes.E606, f"the ratio r of {kind} '{element.name}' is 0, and its causality (it is given "
                                 f"port 1's effort) makes its equations divide by r: {law}",
                         element.law_spans.get("r") if element.law_spans else element.span,
                         hint="a ratio of 0 connects nothing: give the ratio it has (r = 1/Ar for a piston of "
                              "area Ar), or draw the model without the two-port")
        return r

    def _transformer(self, element: ElementNode) -> None:
        # p1.e = r*p2.e, p2.f = r*p1.f with port flows = sign * bond flows.
        b1, b2, s1, s2, r = self._ports(element)
        name = element.name
        if self.causal.sets_effort(b1, name):
            self.add(self.e(b1), r * self.e(b2), name, "transformer")
            self.add(self.f(b2), s2 * r * s1 * self.f(b1), name, "transformer")
        else:
            r = self._divisor(element, r)
            self.add(self.e(b2), self.e(b1) / r, name, "transformer")
            self.add(self.f(b1), s1 * (s2 * self.f(b2)) / r, name, "transformer")

    def _gyrator(self, element: ElementNode) -> None:
        # p1.e = r*p2.f, p2.e = r*p1.f.
        b1, b2, s1, s2, r = self._ports(element)
        name = element.name
        if self.causal.sets_effort(b1, name):
            self.add(self.e(b1), r * s2 * self.f(b2), name, "gyrator")
            self.add(self.e(b2), r * s1 * self.f(b1), name, "gyrator")
        else:
            r = self._divisor(element, r)
            self.add(self.f(b2), s2 * self.e(b1) / r, name, "gyrator")
            self.add(self.f(b1), s1 * self.e(b2) / r, name, "gyrator")

    def _junction(self, junction: JunctionNode) -> None:
        if not junction.bonds:
            return
        strong = self.causal.strong_bond(junction.name)
        common, summed = (self.e, self.f) if junction.kind == "0" else (self.f, self.e)
        sign = {}
        for bond in junction.bonds:
            sign[bond] = 1 if self.graph.bond(bond).head == junction.name else -1
        # the strong bond's variable is minus its sign times the signed sum of the others: each
        # term +-x built as sympy's -1*x would be, the sum built once (adding term by term and
        # negating the sum rebuilt it at every step)
        terms = []
        for bond in junction.bonds:
            if bond == strong:
                continue
            self.add(common(bond), common(strong), junction.name, "junction")
            variable = summed(bond)
            terms.append(variable if sign[bond] != sign[strong] else sympy.Mul._from_args((sympy.S.NegativeOne,
                                                                                          variable)))
        self.add(summed(strong), sympy.Add(*terms), junction.name, "junction")


    # ------------------------------------------------------------- ordering

    def order(self) -> None:
        """Assignments in causal order; loops torn and solved (see module docstring)."""
        equations = self.equations
        self.by_target = by_target = {eq.target: eq for eq in equations}
        self.deps: dict[sympy.Symbol, list[sympy.Symbol]] = {}
        deps = self.deps
        for eq in equations:
            deps[eq.target] = sorted((s for s in eq.rhs.free_symbols if s in by_target),
                                     key=lambda s: by_target[s].index)
        used = set()
        for eq in equations:
            used |= eq.rhs.free_symbols
        for rate in self.rates.values():
            used |= rate.free_symbols
        for dependent in self.dependents:
            used |= dependent.rate.free_symbols
        self.assignments: list[tuple] = []
        self.blocks: list[AlgebraicBlock] = []
        for component in self._components([eq.target for eq in equations], deps):
            first = component[0]
            if len(component) == 1 and first not in deps[first]:
                eq = by_target[first]
                if eq.role == "output" and first not in used:
                    continue
                self.assignments.append((first, eq.rhs))
            else:
                self._solve_loop(component)

    @staticmethod
    def _components(nodes: list, deps: Mapping) -> list[list]:
        """Strongly connected components, dependencies first, otherwise in creation order."""
        position = {n: i for i, n in enumerate(nodes)}
        components = strongly_connected(nodes, deps)
        owner = {}
        for index, component in enumerate(components):
            for node in component:
                owner[node] = index
        needs: dict[int, set[int]] = {i: set() for i in range(len(components))}
        users: dict[int, set[int]] = {i: set() for i in range(len(components))}
        for index, component in enumerate(components):
            for node in component:
                for dep in deps.get(node, ()):
                    if owner[dep] != index:
                        needs[index].add(owner[dep])
                        users[owner[dep]].add(index)
        key = {i: min(position[n] for n in c) for i, c in enumerate(components)}
        ready = [(key[i], i) for i in needs if not needs[i]]
        heapq.heapify(ready)
        ordered = []
        while ready:
            _, index = heapq.heappop(ready)
            ordered.append(components[index])
            for user in sorted(users[index]):
                needs[user].discard(index)
                if not needs[user]:
                    heapq.heappush(ready, (key[user], user))
        return ordered

    def _loop_nodes(self, targets) -> tuple[str, ...]:
        names = {self.by_target[t].node for t in targets if t in self.by_target}
        graph = self.graph
        return tuple(n for n in list(graph.elements) + list(graph.junctions) + list(graph.outputs) if n in names)

    def _solve_loop(self, component: list) -> None:
        by_target = self.by_target
        members = set(component)
        local = {t: [d for d in self.deps[t] if d in members] for t in component}
        tears: list = []
        while True:
            rest = [t for t in component if t not in tears]
            edges = {t: [d for d in local[t] if d not in tears] for t in rest}
            cyclic = [c for c in strongly_connected(rest, edges) if len(c) > 1 or c[0] in edges[c[0]]]
            if not cyclic:
                break
            candidates = cyclic[0]
            inside = set(candidates)
            tears.append(min(candidates, key=lambda t: (by_target[t].role != "resistor",
                                                        -sum(d in inside for d in edges[t]), by_target[t].index)))
        chain = [c[0] for c in strongly_connected(rest, edges)]
        substitution: dict = {}
        for target in chain:
            substitution[target] = by_target[target].rhs.xreplace(substitution)
        residuals = [tear - by_target[tear].rhs.xreplace(substitution) for tear in tears]
        nodes = self._loop_nodes(component)
        solution = self._solve_linear(residuals, tears, nodes)
        if solution is not None:
            self.assignments += list(zip(tears, solution))
        else:
            self._add_block(tears, residuals, nodes)
        self.assignments += [(target, by_target[target].rhs) for target in chain]

    def _add_block(self, unknowns, residuals, nodes) -> None:
        self.blocks.append(AlgebraicBlock(tuple(unknowns), tuple(residuals),
                                          tuple(sympy.Integer(0) for _ in unknowns), len(self.assignments), nodes))
        graph = self.graph
        spans = [element_span(graph.elements[n]) if n in graph.elements else graph.junctions[n].span
                 for n in nodes if n in graph.elements or n in graph.junctions]
        self.diagnostics.append(Diagnostic(
            "warning", codes.W604,
            f"nonlinear algebraic loop through {join_words([repr(n) for n in nodes])}: "
            f"{', '.join(self.element_names.get(u.name, u.name) for u in unknowns)} solved numerically at "
            "every evaluation",
            spans[0] if spans else NO_SPAN,
            related=tuple(Related(span, "on the loop") for span in spans[1:]),
            hint="slower and may fail to converge; a small storage element would break the loop"))

    def _solve_linear(self, residuals, unknowns, nodes):
        """Solve residuals == 0 for unknowns if they are linear in them, else None."""
        zero = {u: sympy.Integer(0) for u in unknowns}
        unknown_set = set(unknowns)
        matrix = []
        for residual in residuals:
            row = []
            for unknown in unknowns:
                coefficient = sympy.diff(residual, unknown)
                if coefficient.free_symbols & unknown_set or coefficient.has(sympy.DiracDelta, sympy.Derivative):
                    return None
                row.append(coefficient)
            matrix.append(row)
        A = sympy.Matrix(matrix)
        b = sympy.Matrix([-residual.xreplace(zero) for residual in residuals])
        if len(unknowns) == 1:
            singular = A[0, 0].is_zero is True
        else:
            singular = sympy.expand(A.det(method="berkowitz")) == 0
        if singular:
            graph = self.graph
            spans = [element_span(graph.elements[n]) if n in graph.elements else graph.junctions[n].span
                     for n in nodes if n in graph.elements or n in graph.junctions]
            names = ", ".join(self.element_names.get(u.name, u.name) for u in unknowns)
            raise _error(codes.E702, f"the algebraic loop through {join_words([repr(n) for n in nodes])} is singular: "
                                 f"its equations do not determine {names}",
                         spans[0] if spans else NO_SPAN,
                         related=[Related(span, "on the loop") for span in spans[1:]],
                         hint="the loop's laws cancel each other (for example two ideal paths in parallel with "
                              "nothing on them); check signs and bond directions")
        if len(unknowns) == 1:
            return [b[0] / A[0, 0]]
        return list(A.LUsolve(b))

    # ------------------------------------------------- derivative causality

    def eliminate(self) -> None:
        """Solve for the port variables of storage elements in derivative causality."""
        if not self.dependents:
            return
        unknowns = [d.unknown for d in self.dependents]
        tainted = set(unknowns)
        for symbol, rhs in self.assignments:
            if rhs.free_symbols & tainted:
                tainted.add(symbol)
        for block in self.blocks:
            if any(r.free_symbols & tainted for r in block.residuals):
                raise _error(codes.E703, "a storage element in derivative causality feeds a nonlinear algebraic "
                                     f"loop ({join_words([repr(n) for n in block.nodes])}); bondc cannot eliminate it",
                             element_span(self.dependents[0].element),
                             hint="add compliance or inertia so that it gets integral causality")
        partial: dict = {}
        for symbol, rhs in self.assignments:
            if symbol in tainted and symbol not in unknowns:
                partial[symbol] = rhs.xreplace(partial)
        expanded = self._expander()
        states = [self.state_symbols[s.qualified] for s in self.graph.states
                  if s.qualified in self.rates]
        residuals = []
        for dependent in self.dependents:
            value = expanded(dependent.state)
            bad = value.free_symbols & (tainted | {u for b in self.blocks for u in b.unknowns})
            if bad:
                raise _error(codes.E703, f"the state of {describe_node(self.graph, dependent.element.name)} depends on "
                                     "another eliminated state's rate; bondc cannot eliminate it",
                             element_span(dependent.element),
                             hint="add compliance or inertia so that it gets integral causality")
            try:
                rate = sympy.diff(value, self.t)
                for state in states:
                    if state in value.free_symbols:
                        qualified = state.name
                        rate += sympy.diff(value, state) * self.rates[qualified].xreplace(partial)
            except EquationError as error:      # a measured signal cannot be differentiated: say where
                first = error.diagnostics[0]
                if first.span.line > 0:
                    raise
                raise EquationError(dataclasses.replace(
                    first, span=element_span(dependent.element),
                    message=f"{describe_node(self.graph, dependent.element.name)}: {first.message}")) from None
            rate = strip_impulses(rate)
            if rate.has(sympy.Derivative):
                raise _error(codes.E703, f"the rate of {describe_node(self.graph, dependent.element.name)} needs the "
                                     "time derivative of a signal bondc cannot differentiate",
                             element_span(dependent.element))
            residuals.append(dependent.rate.xreplace(partial) - rate)
        nodes = tuple(d.element.name for d in self.dependents)
        solution = self._solve_linear(residuals, unknowns, nodes)
        before = [(s, r) for s, r in self.assignments if s not in tainted]
        after = [(s, r) for s, r in self.assignments if s in tainted]
        index_map = []
        count = 0
        for symbol, _ in self.assignments:
            index_map.append(count)
            if symbol not in tainted:
                count += 1
        index_map.append(count)
        self.blocks = [AlgebraicBlock(b.unknowns, b.residuals, b.guesses, index_map[b.index], b.nodes)
                       for b in self.blocks]
        self.assignments = before
        if solution is None:
            self._add_block(unknowns, residuals, nodes)
        else:
            self.assignments += list(zip(unknowns, solution))
        self.assignments += after

    def _expander(self):
        """Expand an expression fully in states, parameters and t (inputs expanded too)."""
        rhs_of = dict(self.assignments)
        memo: dict = {}

        def expand(expr):
            replacements = {}
            for symbol in expr.free_symbols:
                if symbol in rhs_of:
                    if symbol not in memo:
                        memo[symbol] = expand(rhs_of[symbol])
                    replacements[symbol] = memo[symbol]
            return expr.xreplace(replacements) if replacements else expr

        return expand

    # --------------------------------------------------------------- result

    def result(self) -> StateSpace:
        graph = self.graph
        eliminated = {d.element.name: d.state for d in self.dependents}
        states = []
        for state in graph.states:
            if state.owner in eliminated:
                continue
            owner = graph.elements.get(state.owner) if state.owner else None
            initial = (self.translate(state.initial, owner) if state.initial is not None else sympy.Integer(0))
            states.append(StateInfo(state.qualified, self.state_symbols[state.qualified], state.unit_text,
                                    initial, state.description, state.owner))
        inputs = {}
        input_values: dict = {}
        for name, symbol in self.input_symbols.items():
            value = self.by_target[symbol].rhs.xreplace(input_values)
            input_values[symbol] = value
            inputs[name] = (symbol, value)
        states = self._initials_at_start(states, input_values)
        derivatives = {s.name: self.rates[s.name] for s in states}
        outputs = {name: self.by_target[symbol].rhs for name, symbol in self.output_symbols.items()}
        found: list = []
        exprs = [rhs for _, rhs in self.assignments] + list(derivatives.values()) + list(outputs.values())
        exprs += [r for block in self.blocks for r in block.residuals]
        for expr in exprs:
            for candidate in discontinuities(expr):
                if candidate not in found and -candidate not in found:
                    found.append(candidate)
        return StateSpace(
            graph=graph, causal=self.causal, states=tuple(states),
            parameters={name: (symbol, graph.parameters[name].value) for name, symbol in self.parameters.items()},
            inputs=inputs, time=self.t, assignments=tuple(self.assignments), derivatives=derivatives,
            outputs=outputs, algebraic_blocks=tuple(self.blocks), discontinuities=tuple(found),
            energy=self._energy(), eliminated=eliminated, symbols=dict(self.symbols),
            bond_symbols=dict(self.bond_symbols), diagnostics=tuple(self.diagnostics), events=self._events(),
            values_consulted=self.values_consulted)

    def _initials_at_start(self, states: list, input_values: Mapping) -> list:
        """Initial values in parameters only: a discrete variable's may use inputs and other states'
        initial values at t = 0 (the language reference, section 12), substituted here."""
        start = {self.t: sympy.Integer(0)}
        inputs = {symbol: as_sympy(value).xreplace(start) for symbol, value in input_values.items()}
        initial = {s.symbol: as_sympy(s.initial) for s in states}
        keys = set(initial) | set(inputs) | {self.t}
        # only the values that use time, an input or another state are substituted (a 20000-state
        # chain has none: a map of the others per state made this quadratic)
        pending = [symbol for symbol, expr in initial.items() if expr.free_symbols & keys]
        for _ in range(len(pending) + 1):      # initial values that use other initial values, in order
            changed = False
            for symbol in pending:
                expr = initial.pop(symbol)     # a value never replaces its own symbol
                new = expr.xreplace(start).xreplace(inputs).xreplace(initial)
                initial[symbol] = new
                if new != expr:
                    changed = True
            if not changed:
                break
        for s in states:
            left = initial[s.symbol].free_symbols & keys
            if left:
                declared = next((v.span for v in self.graph.states if v.qualified == s.name), NO_SPAN)
                raise _error(codes.E701, f"the initial value of '{s.name}' depends on itself through "
                                     f"{', '.join(sorted(str(x) for x in left))}", declared,
                             hint="give one of the initial values in this cycle a value that uses "
                                  "parameters and inputs only")
        return [dataclasses.replace(s, initial=initial[s.symbol]) if initial[s.symbol] is not s.initial else s
                for s in states]

    def _events(self) -> tuple:
        """The when clauses: condition and (state, value) pairs, in sympy (an output they use is
        replaced by its expression: the event functions compute the graph's variables, not outputs)."""
        outputs = {symbol: self.by_target[symbol].rhs for symbol in self.output_symbols.values()}

        def expand(expr):
            for _ in range(len(outputs) + 1):
                new = as_sympy(expr).xreplace(outputs)
                if new == expr:
                    break
                expr = new
            return expr

        events = []
        for when in getattr(self.graph, "whens", ()):
            actions = []
            for kind, target, value in when.actions:
                if isinstance(target, ast.Name):
                    name = target.name
                else:
                    found = self.causal.reference(target.parts, None)
                    if found is None or found[0] != "state":
                        raise _error(codes.E701, f"'{target.dotted}' is not a state", target.span)
                    name = found[1]
                actions.append((name, expand(self.translate(value))))
            events.append((when.text, expand(self.translate(when.condition)), tuple(actions)))
        return tuple(events)

    def _energy(self) -> dict:
        energy: dict[str, sympy.Expr | None] = {}
        integrals: dict = {}
        parameters = set(self.parameters.values())
        for element in self.graph.storage_elements:
            energy[element.name] = None
            kind = element.kind_info
            if len(element.states) != 1 or element.states[0].name != kind.state or element.states[0].rate is not None:
                continue
            law = "e" if kind.storage == "C" else "f"
            if law not in element.laws:
                continue
            state = self.state_symbols[element.states[0].qualified]
            try:
                expr = self.law(element, law)
            except EquationError:
                continue
            if not expr.free_symbols <= parameters | {state} or not expr.is_polynomial(state):
                continue
            # the integral of a polynomial term by term, once per distinct law (a chain of N equal
            # springs integrates once): sympy.integrate per element is most of a large model's time
            key = expr.xreplace({state: _ENERGY_VARIABLE})
            if key not in integrals:
                integrals[key] = sympy.Poly(key, _ENERGY_VARIABLE).integrate().as_expr()
            energy[element.name] = integrals[key].xreplace({_ENERGY_VARIABLE: state})
        return energy


# ------------------------------------------------------------------- stage

def derive(causal: CausalGraph) -> StateSpace:
    """State equations of a causal graph, as a sorted sequence of sympy assignments.

    >>> from bondc.causality import assign_causality
    >>> from bondc.parse import parse_text
    >>> from bondc.semantic import build
    >>> text = "model M\\n Se force : e = 10\\n I mass : f = p/m\\n R damper : e = b*f\\n" \\
    ...        " param m = 2\\n param b = 3\\n 1 j\\n force -> j\\n j -> mass\\n j -> damper\\nend\\n"
    >>> ss = derive(assign_causality(build(parse_text(text, "m.bg"))[0]))
    >>> ss.derivatives["mass.p"], ss.substituted(ss.derivatives["mass.p"])
    (b2.e, -b*mass.p/m + 10)
    """
    deriver = _Deriver(causal)
    deriver.build()
    deriver.order()
    deriver.eliminate()
    return deriver.result()


# ------------------------------------------------------------------ display

FORMATS = ("text", "latex", "json")


def _display(ss: StateSpace):
    """Expansions shown by ``bondc equations``: in states, inputs, parameters and t."""
    keep = ss.input_symbols
    mapping = ss.substitution(keep)
    return lambda expr: as_sympy(expr).xreplace(mapping)


def _latex_symbol(name: str) -> str:
    r"""A name as LaTeX: Greek letters as symbols, a multi-letter name upright as one word
    (``Iz`` -> ``\mathit{Iz}``, not I times z), the part after ``_`` a subscript."""
    base, _, sub = name.partition("_")
    shown = sympy.latex(sympy.Symbol(base)) if base else ""
    leading = re.match(r"[A-Za-z]*", base)
    letters = leading.group(0) if leading else ""
    if len(letters) > 1 and not shown.startswith("\\"):       # (t1 stays t_1, as sympy writes it)
        shown = r"\mathit{%s}" % base
    return shown + (r"_{\mathrm{%s}}" % sub.replace("_", r"\_") if sub else "")


def _latex_name(name: str) -> str:
    def mathrm(text):
        return r"\mathrm{%s}" % text.replace("_", r"\_")

    if name.startswith("der(") and name.endswith(")"):
        inner = name[4:-1]
        if "." in inner:
            owner, variable = inner.rsplit(".", 1)
            return r"\dot{%s}_{%s}" % (_latex_symbol(variable), mathrm(owner))
        return r"\dot{%s}" % _latex_name(inner)
    if "." in name:
        owner, variable = name.rsplit(".", 1)
        return "%s_{%s}" % (_latex_symbol(variable), mathrm(owner))
    return _latex_symbol(name)


def format_equations(ss: StateSpace, fmt: str = "text") -> str:
    """The state and output equations for ``bondc equations`` (text, latex or json).

    Deterministic: the same model prints byte-identical text in every run.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    show = _display(ss)
    return {"text": _format_text, "latex": _format_latex, "json": _format_json}[fmt](ss, show)


def _format_json(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    graph = ss.graph
    data = {
        "model": graph.name,
        "states": [{"name": s.name, "unit": s.unit_text, "initial": values[s.name]} for s in ss.states],
        "inputs": [{"name": name, "unit": graph.inputs[name].unit_text, "expr": sympy.sstr(expr)}
                   for name, (_, expr) in ss.inputs.items()],
        "parameters": {name: value for name, (_, value) in ss.parameters.items()},
        "derivatives": {name: sympy.sstr(show(expr)) for name, expr in ss.derivatives.items()},
        "outputs": {name: sympy.sstr(show(expr)) for name, expr in ss.outputs.items()},
        "eliminated": {name: sympy.sstr(show(symbol)) for name, symbol in ss.eliminated.items()},
        "algebraic_blocks": [{"unknowns": [u.name for u in block.unknowns],
                              "residuals": [sympy.sstr(show(r)) for r in block.residuals]}
                             for block in ss.algebraic_blocks],
    }
    if ss.events:
        data["when"] = [{"condition": label, "condition_sympy": sympy.sstr(condition),
                         "set": {name: sympy.sstr(value) for name, value in actions}}
                        for label, condition, actions in ss.events]
    return json.dumps(data, indent=2) + "\n"


class BgPrinter(StrPrinter):
    """Expressions in ``.bg`` syntax for ``bondc equations --format text``: ``abs``, ``^``,
    ``if ... then ... else``, ``min``/``max``, ``and``/``or``/``not``, ``==``/``!=``.

    >>> x, y = sympy.symbols("x y", real=True)
    >>> bg_text(sympy.Piecewise((sympy.Abs(x - y)**sympy.Rational(3, 2), x < y), (sympy.Max(x, 1), True)))
    '(if x < y then abs(x - y)^(3/2) else max(1, x))'
    >>> bg_text(sympy.Float("0.1") * x + sympy.Float("2.5e-7"))
    '0.1*x + 2.5e-7'
    """

    def _print_Pow(self, expr, rational=False):
        return super()._print_Pow(expr, rational).replace("**", "^")

    def _call(self, name, expr):
        """``name(arguments)`` in the language's own names for sympy's functions."""
        return f"{name}({', '.join(self._print(a) for a in expr.args)})"

    def _print_Exp1(self, expr):
        return "exp(1)"

    def _print_Float(self, expr):
        # the shortest text that reads back as the same double (0.1, not sympy's 0.100000000000000)
        value = float(expr)
        if not math.isfinite(value):
            return super()._print_Float(expr)
        mantissa, _, exponent = repr(value).partition("e")
        return f"{mantissa}e{int(exponent)}" if exponent else mantissa

    def _print_Table(self, expr):
        x, breakpoints, values = expr.args
        return (f"table({self._print(x)}, [{', '.join(self._print(v) for v in breakpoints)}], "
                f"[{', '.join(self._print(v) for v in values)}])")

    def _print_Piecewise(self, expr):
        parts = []
        for value, condition in expr.args[:-1]:
            parts.append(f"if {self._print(condition)} then {self._print(value)}")
        last_value, last_condition = expr.args[-1]
        tail = self._print(last_value) if last_condition == sympy.true else \
            f"if {self._print(last_condition)} then {self._print(last_value)} else nan"
        return "(" + " else ".join(parts + [tail]) + ")" if parts else tail

    def _print_Equality(self, expr):
        return f"{self._print(expr.lhs)} == {self._print(expr.rhs)}"

    def _print_Unequality(self, expr):
        return f"{self._print(expr.lhs)} != {self._print(expr.rhs)}"

    def _print_And(self, expr):
        return " and ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Or(self, expr):
        return " or ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Not(self, expr):
        return f"not ({self._print(expr.args[0])})"

    def _print_BooleanTrue(self, expr):
        return "1"

    def _print_BooleanFalse(self, expr):
        return "0"


#: sympy's function -> the language's name for it, printed as ``name(arguments)``
_BG_CALLS = {"Abs": "abs", "Min": "min", "Max": "max", "ceiling": "ceil", "floor": "floor", "Mod": "mod",
             "Coulomb": "coulomb", "Step": "step", "Pwm": "pwm"}
for _function, _name in _BG_CALLS.items():
    setattr(BgPrinter, f"_print_{_function}", lambda self, expr, name=_name: self._call(name, expr))


def bg_text(expr) -> str:
    """An expression in ``.bg`` syntax (see :class:`BgPrinter`)."""
    return BgPrinter().doprint(as_sympy(expr))


def _format_text(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    graph = ss.graph
    head = f"model {graph.name}" + (f' "{graph.description}"' if graph.description else "")
    lines = [head]

    def section(title, rows):
        lines.append("")
        lines.append(title)
        lines.extend(f"  {row}" for row in rows or ["(none)"])

    width = max([len(s.name) for s in ss.states] + [1])
    units = [f"[{s.unit_text}]" if s.unit_text else "" for s in ss.states]
    unit_width = max([len(u) for u in units] + [0])
    rows = []
    for s, unit in zip(ss.states, units):
        initial = as_sympy(s.initial)
        value = repr(values[s.name])
        shown = value if initial.is_number else f"{bg_text(initial)} = {value}"
        cells = [s.name.ljust(width)] + ([unit.ljust(unit_width)] if unit_width else []) + [f"initial {shown}"]
        rows.append("  ".join(cells))
    section("states", rows)
    section("inputs", [f"{name} = external (default {bg_text(expr.default)})" if isinstance(expr, External)
                       else f"{name} = {bg_text(expr)}" for name, (_, expr) in ss.inputs.items()])
    section("parameters (SI)", [f"{name} = {value!r}" for name, (_, value) in ss.parameters.items()])
    section("state equations", [f"der({name}) = {bg_text(show(expr))}" for name, expr in ss.derivatives.items()])
    section("outputs", [f"{name} = {bg_text(show(expr))}" for name, expr in ss.outputs.items()])
    if ss.eliminated:
        section("eliminated states (derivative causality)",
                [f"{symbol.name} = {bg_text(show(symbol))}" for symbol in ss.eliminated.values()])
    if ss.algebraic_blocks:
        rows = []
        for block in ss.algebraic_blocks:
            rows.append(f"solve for {', '.join(u.name for u in block.unknowns)}:")
            rows += [f"  0 = {bg_text(show(r))}" for r in block.residuals]
        section("algebraic loops (solved numerically)", rows)
    if ss.events:
        section("when clauses (at the instant the condition becomes true)",
                [f"{label} then " + ", ".join(f"{name} = {bg_text(value)}" for name, value in actions)
                 for label, _, actions in ss.events])
    return "\n".join(lines) + "\n"


def _format_latex(ss: StateSpace, show) -> str:
    values = ss.initial_values()       # once: it evaluates every state's initial value
    names = {symbol: _latex_name(name) for name, symbol in ss.symbols.items()}

    def tex(expr):
        return sympy.latex(show(expr), symbol_names=names)

    lines = [f"% bondc equations of model {ss.graph.name}", "% states (initial values, SI):"]
    lines += [f"%   {s.name} = {values[s.name]!r}" for s in ss.states]
    lines += ["% parameters (SI):"] + [f"%   {name} = {value!r}" for name, (_, value) in ss.parameters.items()]
    rows = []
    for name, (symbol, expr) in ss.inputs.items():
        rows.append(f"{names[symbol]} &= {sympy.latex(expr, symbol_names=names)}")
    rows += [f"{_latex_name(f'der({name})')} &= {tex(expr)}" for name, expr in ss.derivatives.items()]
    rows += [f"{_latex_name(name)} &= {tex(expr)}" for name, expr in ss.outputs.items()]
    lines.append(r"\begin{align*}")
    lines.append(" \\\\\n".join(f"  {row}" for row in rows))
    lines.append(r"\end{align*}")
    return "\n".join(lines) + "\n"

"""The :class:`~bondc.statespace.StateSpace` assembled from the ordered assignments: the
independent states with their initial values at the start, the inputs, outputs and rates, the
discontinuities, the ``when`` clauses and each storage element's stored-energy function.
"""

from __future__ import annotations

import dataclasses
from typing import Mapping

import sympy

from bondc import ast
from bondc.equations.laws import Laws, _error
from bondc.errors import EquationError
from bondc.source import NO_SPAN
from bondc.statespace import StateInfo, StateSpace
from bondc.symbolic import as_sympy, discontinuities
from bondc import codes

_ENERGY_VARIABLE = sympy.Dummy("s", real=True)      # the integration variable of stored-energy functions


class Assembly(Laws):
    """:meth:`result`: the StateSpace of the derivation."""

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
                    name = str(found[1])        # (a state's qualified name)
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

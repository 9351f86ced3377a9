"""Storage elements in derivative causality eliminated: the state is assigned from the law
inverted (``q = C*e``), the time derivative of that expression in the independent states (the
chain rule with their state equations, plus the explicit time dependence through inputs) is
equated to the element's rate law, and the resulting implicit equations are solved for its port
variables (two inertias joined by a gear become one state with the combined inertia); ``E703``
where that cannot be done.
"""

from __future__ import annotations

import dataclasses

import sympy

from bondc.causality import describe_node, element_span, join_words
from bondc.equations.laws import _error
from bondc.equations.loops import Ordering
from bondc.errors import EquationError
from bondc.statespace import AlgebraicBlock
from bondc.symbolic import strip_impulses
from bondc import codes


class Elimination(Ordering):
    """:meth:`eliminate`: the port variables of the storage elements in derivative causality
    solved for, in the ordered assignments (it solves with the loops' :meth:`_solve_linear`)."""

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

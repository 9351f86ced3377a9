"""The equations in causal order: strongly connected components of their dependencies,
topologically sorted. An acyclic equation becomes one assignment; an algebraic loop is torn and
solved symbolically when it is linear in its tearing variables, else kept as an
:class:`~bondc.statespace.AlgebraicBlock` solved numerically at run time (``W604``); a singular
one is ``E702``.
"""

from __future__ import annotations

import heapq
from typing import Mapping

import sympy

from bondc.causality import element_span, join_words, strongly_connected
from bondc.equations.laws import Laws, _error
from bondc.errors import Diagnostic, Related
from bondc.source import NO_SPAN
from bondc.statespace import AlgebraicBlock
from bondc import codes


class Ordering(Laws):
    """:meth:`order`: the equations as assignments in causal order, the loops torn and solved."""

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

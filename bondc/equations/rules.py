"""The equations each node of the causal graph contributes, for the variables its causality makes
it compute: a source its law, a storage element in integral causality its port output from its
state (in derivative causality its state from the law inverted, eliminated later by
:mod:`.derivative`), a resistor its law in the form its causality needs, a two-port its two
relations, a junction the common variable of its bonds and the sum on its strong bond.
"""

from __future__ import annotations

import sympy
from sympy.core.symbol import Str as _SymStr

from bondc import ast
from bondc.causality import CONDUCTANCE, DERIVATIVE, ROLES, describe_node, element_span
from bondc.errors import Diagnostic
from bondc.equations.laws import Laws, _Dependent, _error
from bondc.model import ElementNode, JunctionNode
from bondc.source import NO_SPAN
from bondc.symbolic import External
from bondc import codes


class NodeRules(Laws):
    """:meth:`build`: every node's equations, the inputs', the outputs' and the states' rates."""

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
        port = {"e": self.e(bond), "f": self.f(bond)}
        # conductance causality: the resistor computes its flow from its effort; resistance: the reverse
        wanted, given = ("f", "e") if self.causal.resistors[element.name] == CONDUCTANCE else ("e", "f")
        if wanted in element.laws:
            rhs = self.law(element, wanted)
        else:       # only the other form is written: inverted
            dummy = sympy.Dummy(wanted, real=True)
            rhs = self.invert(self.law(element, given, {wanted: dummy}), dummy, port[given], element, given, wanted)
        self.add(port[wanted], rhs, element.name, "resistor")

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

"""The report's state equations: a :class:`~bondc.statespace.StateSpace` -> MathML rows
(:func:`state_equations`), each element's law kept by name when its expanded form is long, the
parameters and states shown by their model names."""

from __future__ import annotations

import sympy
from pathlib import Path
from typing import Any

from bondc.model import BondGraph, KINDS
from bondc.report.render import Equation, equation_markup, Table
from bondc.symbolic import as_sympy, Translator


#: Element laws whose expanded form has more operations than this are kept as named
#: quantities in the state equations and written out once under "where".
LAW_OPERATIONS = 8


def _display_names(ss) -> dict[sympy.Symbol, sympy.Symbol]:
    """Symbols renamed for reading: ``mass.p`` -> p_mass, a bond's effort -> e_<element that sets it>."""
    graph = ss.graph
    taken = set(ss.symbols)
    renamed: dict[sympy.Symbol, sympy.Symbol] = {}

    def rename(symbol, name):
        if name not in taken:
            taken.add(name)
            renamed[symbol] = sympy.Symbol(name, real=True)

    owned = {s.qualified: s for s in graph.states if s.owner is not None}     # the graph says whose
    for state in ss.states:
        own = owned.get(state.name)
        if own is not None:                               # valve.chamber.p: p of valve.chamber
            rename(state.symbol, f"{own.name}_{own.owner}")
    for name, symbol in ss.eliminated.items():
        own = owned.get(name)
        if own is not None:
            rename(symbol, f"{own.name}_{own.owner}")
    for number, (effort, flow) in ss.bond_symbols.items():
        bond = graph.bond(number)
        for which, symbol in (("e", effort), ("f", flow)):
            ends = [(end, port) for end, port in ((bond.head, bond.head_port), (bond.tail, bond.tail_port))
                    if end in graph.elements]
            setting = [(end, port) for end, port in ends if which in graph.elements[end].laws]
            chosen = (setting or ends or [(None, None)])[0]
            if bond.label:
                rename(symbol, f"{which}_{bond.label}")
            elif chosen[0] is not None:
                end, port = chosen
                rename(symbol, f"{which}_{end}" + (f".{port}" if port else ""))
    return renamed


def _law_owner(ss, symbol) -> str | None:
    """The element whose own law computes the bond variable ``symbol`` (a store, resistor or source)."""
    graph = ss.graph
    for number, (effort, flow) in ss.bond_symbols.items():
        if symbol in (effort, flow):
            which = "e" if symbol == effort else "f"
            bond = graph.bond(number)
            for end in (bond.head, bond.tail):
                element = graph.elements.get(end)
                if element is not None and KINDS[element.kind].ports == 1 and which in element.laws:
                    return end
    return None


class _CallsKept(Translator):
    """Translates a law as the model writes it: calls of its ``fn`` functions stay calls, recorded in ``called``.

    The equations stage inlines every function; for reading, ``f_valve =
    valve_mdot(P1, P_chamber, ...)`` and the function once are clearer than
    the function's body pasted into every law that calls it.
    """

    def __init__(self, ss, owner=None):
        self.ss = ss
        self.called: list[str] = []
        local: dict = {}
        if owner is not None:
            if len(owner.bonds) == 1:
                local["e"], local["f"] = ss.bond_symbols[owner.bond]
            for state in owner.states:
                if state.qualified in ss.symbols:
                    local[state.name] = ss.symbols[state.qualified]

        def resolve_name(name, node):
            if name in local:
                return local[name]
            if name == "t":
                return ss.time
            if name in ss.parameters:
                return ss.parameters[name][0]
            if name in ss.inputs:
                return ss.inputs[name][0]
            if name in ss.symbols:
                return ss.symbols[name]
            if name == "pi":
                return sympy.pi
            raise KeyError(f"'{name}' is not a name of the model (the equations stage accepted it)")

        def resolve_ref(node):
            kind, what = ss.causal.reference(node.parts, owner.name if owner is not None else None)
            if kind == "state":
                return ss.symbols[what]
            return ss.bond_symbols[what][0 if kind == "e" else 1]

        graph = ss.graph
        super().__init__(resolve_name, resolve_ref, graph.functions,
                         Path(graph.file).parent if graph.file else None, ss.time)

    def _inline(self, node, function):
        if function.name not in self.called:
            self.called.append(function.name)
        return sympy.Function(function.name, real=True)(*[self(arg) for arg in node.args])

    def law(self, element, which: str):
        """The law of ``element`` for its ``which`` ("e" or "f") variable."""
        return self(element.laws[which])

    def function(self, function) -> tuple[Any, Any]:
        """``name(params)`` and its body, calls kept."""
        parameters = [sympy.Symbol(name, real=True) for name in function.params]
        self._bound.append(dict(zip(function.params, parameters)))
        try:
            body = self(function.body)
        finally:
            self._bound.pop()
        return sympy.Function(function.name, real=True)(*parameters), body


def state_equations(ss) -> tuple[list[Equation], list[Equation], Table | None]:
    """The state equations for reading: (d(state)/dt = ..., the laws they name, a table of the states).

    Every assignment is expanded into the derivatives except the inputs (kept
    by name) and the element laws that are long or piecewise (friction,
    orifice flow, backlash): those stay named (e_friction) and are written out
    once under "where", as the model writes them (its ``fn`` functions called,
    not inlined; the functions follow), in causal order.
    """
    names = _display_names(ss)
    keep = set(ss.input_symbols)
    mapping: dict = {}
    laws: list[tuple[sympy.Symbol, str]] = []
    for symbol, rhs in ss.assignments:
        if symbol in keep:
            continue
        value = rhs.xreplace(mapping)
        owner = _law_owner(ss, symbol)
        if owner is not None and (value.has(sympy.Piecewise) or sympy.count_ops(value) > LAW_OPERATIONS):
            laws.append((symbol, owner))
            continue
        mapping[symbol] = value

    def show(expr):
        return as_sympy(expr).xreplace(mapping).xreplace(names)

    time = ss.time
    equations = []
    for state in ss.states:
        lhs = sympy.Derivative(names.get(state.symbol, state.symbol), time)
        equations.append(Equation(equation_markup(lhs, show(ss.derivatives[state.name])), state.name))
    where = []
    functions: list[str] = []
    for symbol, owner in laws:
        element = ss.graph.elements[owner]
        which = "e" if symbol == ss.bond_symbols[element.bond][0] else "f"
        written = _CallsKept(ss, element)
        law = written.law(element, which)
        functions += [name for name in written.called if name not in functions]
        where.append(Equation(equation_markup(names.get(symbol, symbol), show(law)), f"{element.kind} {owner}"))
    for name, symbol in ss.eliminated.items():
        where.append(Equation(equation_markup(names.get(symbol, symbol), show(symbol)),
                              f"{name} (derivative causality)"))
    for number, block in enumerate(ss.algebraic_blocks, start=1):
        for residual in block.residuals:
            where.append(Equation(equation_markup(sympy.Integer(0), show(residual)), f"algebraic loop {number}"))
    index = 0
    while index < len(functions):      # functions called by functions follow the ones that call them
        written = _CallsKept(ss)
        head, body = written.function(ss.graph.functions[functions[index]])
        functions += [name for name in written.called if name not in functions]
        where.append(Equation(equation_markup(head, body.xreplace(names)), f"fn {functions[index]}"))
        index += 1

    table = None
    if ss.states:
        initial = ss.initial_values()
        with_units = any(s.unit_text for s in ss.states)
        rows = []
        for s in ss.states:
            row = {"state": s.name}
            if with_units:
                row["unit"] = s.unit_text or ""
            row["initial value (SI)"] = initial[s.name]
            row["description"] = s.description or _state_description(ss.graph, s)
            rows.append(row)
        table = Table.from_dicts("States and their initial values", rows)
    return equations, where, table


def _state_description(graph: BondGraph, state) -> str:
    if state.element is None or state.element not in graph.elements:
        return ""
    element = graph.elements[state.element]
    own = next((s for s in element.states if s.qualified == state.name), None)
    default = own is not None and own.rate is None          # q of a C, p of an I (not a custom state)
    what = {"q": "generalised displacement", "p": "generalised momentum"}.get(own.name, "state") if default else "state"
    return f"{what} of {element.kind} {element.name}"

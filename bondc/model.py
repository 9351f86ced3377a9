"""The checked bond graph: what ``semantic.build`` returns and later stages read.

A :class:`BondGraph` is one model of a file with every name resolved, every
bond numbered and oriented, every two-port's ports assigned, parameters in SI,
and element kinds described by data (:data:`bondc.kinds.KINDS`). Laws, inputs and outputs
stay AST expressions (``bondc.ast``); the equations stage turns them into sympy
by walking the AST, never by evaluating text.

Variable naming used throughout bondc (reports, CSV columns, JSON):

- bond variables: ``b3.e``/``b3.f`` or, for a labelled bond, ``label.e``;
- states: ``element.state`` (``mass.p``, ``spring.q``, ``chamber.P``) and
  model-level states by their own name (``x``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Collection, Mapping

from bondc import ast
from bondc.kinds import JUNCTION_KINDS, JUNCTIONS, KINDS, RESISTOR, STORAGE, JunctionKind, Kind
from bondc.scope import Scope
from bondc.source import NO_SPAN, Source, Span
from bondc import codes

if TYPE_CHECKING:       # (flatten builds the instances; the graph only carries them)
    from bondc.errors import Diagnostic
    from bondc.flatten import Instance


PORT_NAMES = ("p1", "p2")


@dataclass(frozen=True)
class Parameter:
    name: str
    value: float                    # SI
    expr: ast.Expr
    unit_text: str | None           # as written, for display
    description: str | None
    span: Span = NO_SPAN
    display_factor: float = 1.0     # SI value / display_factor = value in unit_text


@dataclass(frozen=True)
class Function:
    name: str
    params: tuple[str, ...]
    body: ast.Expr
    description: str | None
    span: Span = NO_SPAN


@dataclass(frozen=True)
class Signal:
    """An ``input``: a named signal of ``t`` and parameters, in SI.

    ``external``: the host supplies it (a table, a function of ``t``, a CSV file); ``expr`` is then
    its default, a constant, used when nothing supplies it."""

    name: str
    expr: ast.Expr
    unit_text: str | None
    description: str | None
    span: Span = NO_SPAN
    external: bool = False
    default: float | None = None    # an external input's default, SI (None: not known)
    name_span: Span = NO_SPAN


@dataclass(frozen=True)
class OutputDef:
    name: str
    expr: ast.Expr
    unit_text: str | None
    description: str | None
    span: Span = NO_SPAN
    display_factor: float = 1.0     # value in unit_text = SI value / display_factor


@dataclass(frozen=True)
class StateVar:
    """An integrated quantity: a storage element's state or a model-level state.

    ``rate`` is None for a storage element's default state (``der(q) = f``,
    ``der(p) = e``); a custom or model-level state gives its own rate law.
    """

    name: str                       # local name: "q", "p", "P", "x"
    qualified: str                  # "spring.q", "chamber.P", "x"
    owner: str | None               # element name, or None for a model-level state
    unit_text: str | None
    initial: ast.Expr | None        # None means 0
    rate: ast.Expr | None
    description: str | None
    span: Span = NO_SPAN


@dataclass(frozen=True)
class Bond:
    number: int                     # 1, 2, 3, ... in order of appearance
    tail: str                       # element or junction name power leaves
    head: str                       # element or junction name power enters
    tail_port: str | None = None    # "p1"/"p2" where the tail is a two-port
    head_port: str | None = None
    label: str | None = None
    span: Span = NO_SPAN
    default_name: str | None = None  # set when another bond's label is "b<number>" (then "bond<number>")

    @property
    def name(self) -> str:
        """``label`` if the bond has one, else ``b<number>`` (``bond<number>`` if a label took that)."""
        return self.label or self.default_name or f"b{self.number}"


@dataclass(frozen=True)
class ElementNode:
    kind: str
    name: str
    description: str | None
    laws: Mapping[str, ast.Expr]    # "e", "f", "r" -> expression
    law_spans: Mapping[str, Span]
    states: tuple[StateVar, ...]    # storage elements: their states (default q/p or custom)
    bonds: tuple[int, ...]          # one-port: (bond,); two-port: (p1 bond, p2 bond)
    port_signs: tuple[int, ...]     # +1 where the bond is drawn "through" (into p1, out of p2), else -1
    span: Span = NO_SPAN
    name_span: Span = NO_SPAN

    @property
    def kind_info(self) -> Kind:
        return KINDS[self.kind]

    @property
    def bond(self) -> int:
        """The bond of a one-port element."""
        return self.bonds[0]


@dataclass(frozen=True)
class JunctionNode:
    kind: str                       # "0" (common effort) or "1" (common flow)
    name: str
    bonds: tuple[int, ...]
    span: Span = NO_SPAN

    @property
    def kind_info(self) -> JunctionKind:
        return JUNCTIONS[self.kind]


@dataclass(frozen=True)
class ExperimentDef:
    name: str
    description: str | None
    t_end: float | None = None
    solver: str | None = None
    rtol: float | None = None
    atol: float | None = None
    max_step: float | None = None
    cycle: float | None = None
    outputs: tuple[str, ...] = ()
    parameters: Mapping[str, float] = field(default_factory=dict)   # overrides, SI
    inputs: Mapping[str, Signal] = field(default_factory=dict)      # replaced inputs
    settings: Mapping[str, object] = field(default_factory=dict)    # any further setting, SI
    span: Span = NO_SPAN


@dataclass(frozen=True)
class WhenDef:
    """A ``when`` clause: its condition and its statements as (kind, target, value), kind
    ``"assign"`` (a discrete variable, by name) or ``"reinit"`` (a state: a Name or a Ref)."""

    condition: ast.Expr
    actions: tuple[tuple[str, ast.Expr, ast.Expr], ...]
    text: str
    span: Span = NO_SPAN


@dataclass(frozen=True)
class BondGraph:
    name: str
    description: str | None
    file: str
    parameters: Mapping[str, Parameter]
    functions: Mapping[str, Function]
    inputs: Mapping[str, Signal]
    outputs: Mapping[str, OutputDef]
    elements: Mapping[str, ElementNode]
    junctions: Mapping[str, JunctionNode]
    bonds: tuple[Bond, ...]
    model_states: tuple[StateVar, ...]
    experiments: Mapping[str, ExperimentDef]
    sources: Mapping[str, Source] = field(default_factory=dict, compare=False)
    span: Span = NO_SPAN
    # discrete variables are model states whose rate is 0 (they change only in when clauses)
    discrete: tuple[str, ...] = ()
    whens: tuple[WhenDef, ...] = ()
    # the SI unit (as dimensions: "kg*m/s") of each state and bond variable whose dimension is known
    si_units: Mapping[str, str] = field(default_factory=dict, compare=False)
    # submodel instances (path, model, description, ports), outermost first
    instances: tuple[Instance, ...] = field(default=(), compare=False)
    # every declaration and use of a name, with its span
    scope: Scope | None = field(default=None, compare=False)
    # every division by parameters alone, as (divisor expression, parameter names): E311 for bound values
    divisors: tuple[tuple[ast.Expr, tuple[str, ...]], ...] = field(default=(), compare=False)

    def bond(self, number: int) -> Bond:
        return self.bonds[number - 1]

    @property
    def states(self) -> tuple[StateVar, ...]:
        """Every state in declaration order: storage elements' first, then model-level."""
        out = [s for element in self.elements.values() for s in element.states]
        return tuple(out) + self.model_states

    @property
    def storage_elements(self) -> tuple[ElementNode, ...]:
        return tuple(e for e in self.elements.values() if KINDS[e.kind].stores)

    def summary(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "elements": len(self.elements),
            "junctions": len(self.junctions),
            "bonds": len(self.bonds),
            "storage_elements": len(self.storage_elements),
            "states": len(self.states),
            "parameters": len(self.parameters),
            "inputs": len(self.inputs),
            "outputs": len(self.outputs),
            "experiments": len(self.experiments),
        }


def bond_alias(graph: BondGraph | None, variable: str | None) -> str | None:
    """``b3.e`` -> ``damper.e`` (or ``screw.p1.e``): the element variable a bond variable is (the
    element that computes it, else every element at the bond's ends, joined by ", "); None for a
    bond between two junctions or a name that is no bond variable."""
    if graph is None or not variable:
        return None
    head, _, which = variable.rpartition(".")
    if which not in ("e", "f"):
        return None
    for bond in getattr(graph, "bonds", ()):
        if bond.name == head:
            return _bond_alias(graph, bond, which)
    return None


def _bond_alias(graph: BondGraph, bond: Bond, which: str) -> str | None:
    names, computing = [], []
    for end, port in ((bond.head, bond.head_port), (bond.tail, bond.tail_port)):
        if end in graph.elements:
            names.append(f"{end}.{port}.{which}" if port else f"{end}.{which}")
            if which in graph.elements[end].laws:
                computing.append(names[-1])
    return ", ".join(computing or names) or None


_BOND_VARIABLE = re.compile(r"(?<![\w.'])(?:[A-Za-z_]\w*\.)*[A-Za-z_]\w*\.[ef]\b")


def readable_names(graph: BondGraph | None) -> dict[str, str]:
    """{bond variable: the element variable it is} (``b14.e`` -> ``nut.e``, the element that computes
    it), for :func:`readable`; bonds between two junctions have none."""
    names: dict[str, str] = {}
    if graph is None:
        return names
    for bond in getattr(graph, "bonds", ()):
        for which in ("e", "f"):
            alias = _bond_alias(graph, bond, which)
            if alias:
                names[f"{bond.name}.{which}"] = alias.split(", ")[0]
    return names


def readable(names: Mapping[str, str], text: str) -> str:
    """``text`` (a switch's label, a message) with every bond variable not in quotes named by the
    element variable it is (``names``, from :func:`readable_names`): ``coulomb(b5.f) in b5.e`` ->
    ``coulomb(fr1.f) in fr1.e``. A bond between two junctions keeps its name; quoted names
    (``'b3.e' (damper.e)``) stay as they are."""
    if not names or not text:
        return text
    return _BOND_VARIABLE.sub(lambda match: names.get(match.group(0), match.group(0)), text)


def external_input_notes(graph: BondGraph | None, supplied: Collection[str] = ()) -> list[Diagnostic]:
    """I346 for each external input of ``graph`` that nothing supplies (not in ``supplied``): its
    default is used. ``bondc check`` and ``bondc simulate`` print it once."""
    from bondc.errors import Diagnostic

    notes = []
    for name, signal in getattr(graph, "inputs", {}).items():
        if not getattr(signal, "external", False) or name in supplied:
            continue
        value = getattr(signal, "default", None)
        shown = "" if value is None else f" {value:g}" + (f" {signal.unit_text}" if signal.unit_text else "")
        notes.append(Diagnostic("info", codes.I346, f"input {name} is external: nothing supplies it, so its default"
                                                f"{shown} is used",
                                signal.name_span if signal.name_span != NO_SPAN else signal.span,
                                hint=f"supply it: bondc simulate --input {name}=FILE.csv[:COLUMN], or "
                                     f"simulate(..., inputs={{{name!r}: (times, values)}}) in Python"))
    return notes


def result_units(graph: BondGraph | None) -> dict[str, tuple[str, float]]:
    """Each result column's unit and its factor (SI value / factor = value in that unit):
    ``{"t": ("s", 1.0), "P_kPa": ("kPa", 1000.0), "mass.p": ("kg*m/s", 1.0)}``.

    An output is shown in its declared unit; a state or bond variable in SI when its dimension is
    known (the dimension check infers it); a column whose unit is unknown has none. Every result
    file records these (:func:`bondc.runtime.write_result`), the generated module carries them
    (``RESULT_UNITS``)."""
    units = {"t": ("s", 1.0)}
    if graph is None:
        return units
    for name, unit in getattr(graph, "si_units", {}).items():
        units[name] = (unit, 1.0)
    from bondc.units import lookup

    for state in graph.states:
        written = state.unit_text
        declared = lookup(written) if written else None
        if written and declared is not None and declared.is_coherent:   # "chamber.P [Pa]" rather than kg/(m*s^2)
            units[state.qualified] = (written, 1.0)
    for name, output in graph.outputs.items():
        if output.unit_text:
            units[name] = (output.unit_text, output.display_factor or 1.0)
    return units


def law_span(graph: BondGraph | None, variable: str | None) -> Span | None:
    """The source span of the law that computes ``variable`` (a bond variable, input, output or state,
    ``der(x)`` for its rate), or None: where a diagnostic about that variable points."""
    if graph is None or not variable:
        return None
    name = variable[4:-1] if variable.startswith("der(") else variable
    if name in getattr(graph, "inputs", {}):
        return graph.inputs[name].span
    if name in getattr(graph, "outputs", {}):
        return graph.outputs[name].span
    for state in getattr(graph, "states", ()):
        if state.qualified == name:
            span: Span = state.span
            return span
    head, _, which = name.rpartition(".")
    for bond in getattr(graph, "bonds", ()):
        if bond.name == head:
            ends = [graph.elements[end] for end in (bond.head, bond.tail) if end in graph.elements]
            for element in ends:        # the law that computes this variable, at either end
                if which in element.law_spans:
                    return element.law_spans[which]
            for element in ends:        # else a storage or resistor law written the other way round
                if element.kind_info.role in (STORAGE, RESISTOR) and element.law_spans:
                    return next(iter(element.law_spans.values()))
            for end in (bond.head, bond.tail):
                if end in graph.elements:
                    return graph.elements[end].span
    return None

"""Semantic stage: ``ast.File`` (and its imports) -> checked :class:`bondc.model.BondGraph`.

:func:`load` reads a ``.bg`` file and the files it imports, picks a model,
applies an experiment's and the command line's overrides and builds the graph;
:func:`build` does the same for a file already parsed. Building runs every
``check_<what>`` function below on the chosen model; each collects diagnostics instead of stopping, so one run
reports every problem. If any is an error, :class:`bondc.errors.ModelError`
is raised carrying all of them, sorted by position; otherwise the graph is
returned with the warnings. Errors in laws, parameters or experiments leave the
graph's structure known: unless the structural checks (names, kinds, bonds,
ports) found an error too, the causal conflicts (E601) of that structure are
among them (:func:`_structural_conflicts`), so one run reports both.

What the checks enforce is the language reference (``docs/language.md``); the
codes are listed in ``docs/diagnostics.md``.

>>> from bondc.parse import parse_text
>>> text = '''model M
...   param m = 2 [kg]
...   param lead = 5.0 [mm]
...   MSe force : e = 10
...   I mass : f = p/m
...   TF screw : r = lead/(2*pi)
...   force -> screw -> mass
... end
... '''
>>> graph, warnings = build(parse_text(text, "m.bg"), {})
>>> graph.parameters["lead"].value, [(b.number, b.tail, b.head) for b in graph.bonds]
(0.005, [(1, 'force', 'screw'), (2, 'screw', 'mass')])
>>> graph.elements["screw"].bonds, graph.elements["screw"].port_signs
((1, 2), (1, 1))
"""

from __future__ import annotations

import bisect
import csv
import dataclasses
import difflib
import math
import os
import re
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from bondc import ast, builtins, units
from bondc.io import read_source
from bondc.errors import Diagnostic, Hint, ModelError, Related, sort_key
from bondc.evaluate import EvaluationError, ExpansionBudget, evaluate
from bondc.kinds import JUNCTION_KINDS, JUNCTIONS, KINDS, RESISTOR, STORAGE
from bondc.model import (
    PORT_NAMES, BondGraph, Bond, ElementNode, ExperimentDef, Function, JunctionNode,
    OutputDef, Parameter, Signal, StateVar, WhenDef,
)
from bondc.parse import parse_source
from bondc.flatten import KIND_CODES, flatten, ports_of
from bondc.std import LIBRARIES as STD_LIBRARIES, path_of as std_path_of
from bondc.source import Source, Span

#: The hint of every problem with a ``--set`` value: what one looks like (here and in
#: :func:`bondc.pipeline.parse_sets`).
SET_HINT = 'a --set value is NAME=VALUE: a number, with a unit in [ ] or in the parameter\'s declared unit ' \
           '(--set k=800, --set "k=0.8 [kN/m]"), or an expression of the model\'s parameters (--set "k=2*k0")'

# Built-in functions and how many arguments each takes: (at least, at most); None is "no limit".
BUILTINS: Mapping[str, tuple[int, int | None]] = {name: b.arity for name, b in builtins.BUILTINS.items()}

RESERVED = {"t": "time", "pi": "the constant pi"}

SOLVERS = ("auto", "CVODE", "CVODE-BDF", "CVODE-Adams", "IDA", "DOPRI5", "RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")

# Experiment settings: name -> what its value is.
SETTINGS: Mapping[str, str] = {
    "t_end": "time",
    "solver": "solver",
    "rtol": "tolerance",
    "atol": "tolerance",
    "max_step": "time",
    "cycle": "time",
    "outputs": "outputs",
    "first_step": "time",
    "dt": "time",
    "bode": "transfers",
    "bode_at": "operating point",
}

#: ``bode_at``: where the report's frequency responses are linearised (as ``bondc bode --at``).
OPERATING_POINTS = ("initial", "equilibrium")

# Pass as ``experiment=`` to use the model's first experiment (what a command does without --experiment).
FIRST = "<first experiment>"

_BOND_NUMBER = re.compile(r"b([0-9]+)")


def _a(noun: str) -> str:
    """The noun with its article: "an input", "a C", "an R", "an MSe" (letters as spoken)."""
    first = noun[:1]
    vowel = first in "aeiou" if first.islower() else first in "AEFHILMNORSX"
    return f"{'an' if vowel else 'a'} {noun}"


def _quoted(names: Iterable[str]) -> str:
    return ", ".join(f"'{n}'" for n in names)


def _did_you_mean(name: str, candidates: Iterable[str]) -> str | None:
    """``"did you mean 'x'?"`` for the closest candidate, or None."""
    candidates = sorted(set(candidates))
    same_case = [c for c in candidates if c.lower() == name.lower() and c != name]
    found = same_case or difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return Hint(f"did you mean '{found[0]}'?", (found[0],)) if found else None


def _join_hints(*hints: str | None) -> str | None:
    parts = [h for h in hints if h]
    return Hint.join(parts) if parts else None


def _error(code: str, message: str, span: Span, hint: str | None = None,
           related: Sequence[Related] = ()) -> Diagnostic:
    return Diagnostic("error", code, message, span, hint=hint, related=tuple(related),
                      suggestions=getattr(hint, "suggestions", ()))


def _warning(code: str, message: str, span: Span, hint: str | None = None,
             related: Sequence[Related] = ()) -> Diagnostic:
    return Diagnostic("warning", code, message, span, hint=hint, related=tuple(related),
                      suggestions=getattr(hint, "suggestions", ()))


def _file_span(name: str) -> Span:
    """A span naming only a file (rendered ``file: error...`` without source lines)."""
    return Span(name, 0, 0, 0, 0)


# ============================================================== declarations

@dataclass(frozen=True)
class _Decl:
    """One name the model defines, in its single namespace."""

    category: str       # parameter input output state element junction function "bond label"
    name: str
    span: Span          # the name as written
    node: object


@dataclass
class _Definition:
    """How a parameter gets its value: its declaration, or an override of it."""

    name: str
    expr: ast.Expr
    unit: ast.Unit | None
    span: Span                      # the statement that gives this value
    declared_unit: ast.Unit | None  # the declaration's unit (a bare-number override is read in it)
    origin: str                     # "declaration", "experiment 'x'", "--set"


@dataclass
class _Model:
    """Everything the checks share about the model being built."""

    file: ast.File
    sources: Mapping[str, Source]
    model: ast.Model
    files: tuple[ast.File, ...]
    diagnostics: list[Diagnostic] = field(default_factory=list)
    decls: dict[str, _Decl] = field(default_factory=dict)
    all_decls: list[_Decl] = field(default_factory=list)
    file_functions: dict[str, ast.FnDef] = field(default_factory=dict)
    functions: dict[str, ast.FnDef] = field(default_factory=dict)
    bad_functions: set[str] = field(default_factory=set)
    bonds: list[Bond] = field(default_factory=list)
    ends: dict[str, list["_End"]] = field(default_factory=dict)
    ports: dict[str, tuple[tuple[int, int], tuple[int, int]]] = field(default_factory=dict)
    element_laws: dict[str, "_ElementLaws"] = field(default_factory=dict)
    model_states: dict[str, "_StateLaws"] = field(default_factory=dict)
    units: dict[int, units.SIUnit | None] = field(default_factory=dict)
    expr_ok: dict[int, bool] = field(default_factory=dict)
    used: set[str] = field(default_factory=set)
    csv_headers: dict[str, list[str] | str | None] = field(default_factory=dict)   # str: why unreadable
    misspelt: set[str] = field(default_factory=set)   # nodes a misspelt bond endpoint probably meant
    bindings: list = field(default_factory=list)       # flatten.Binding: instances' parameter values
    good_bindings: list = field(default_factory=list)  # those that fit their parameter
    instances: list = field(default_factory=list)      # flatten.Instance: the instance tree
    by_kind: dict = field(default_factory=dict, repr=False)     # statements(): kind -> statements
    # what evaluating the constants may spend on expanding fn calls (E319)
    budget: ExpansionBudget = field(default_factory=ExpansionBudget, repr=False)

    def report(self, diagnostic: Diagnostic) -> None:
        self.diagnostics.append(diagnostic)

    # The model's statements by type, in order (each kind sorted out once: the checks ask ~60
    # times, and a 10000-section chain has 120000 statements).
    def statements(self, kind) -> list:
        body = self.model.body
        if self.by_kind.get(None) is not body:      # (the body is a tuple: replaced, never changed)
            self.by_kind.clear()
            self.by_kind[None] = body
        if kind not in self.by_kind:
            self.by_kind[kind] = [s for s in body if isinstance(s, kind)]
        return list(self.by_kind[kind])

    @property
    def params(self) -> list[ast.Param]:
        return self.statements(ast.Param)

    @property
    def elements(self) -> list[ast.Element]:
        """The elements, each name once (a second definition is only reported, E302)."""
        return [e for e in self.statements(ast.Element) if self.decls[e.name].node is e]

    @property
    def inputs(self) -> list[ast.Input]:
        return self.statements(ast.Input)

    @property
    def outputs(self) -> list[ast.Output]:
        return self.statements(ast.Output)

    @property
    def experiments(self) -> list[ast.Experiment]:
        return self.statements(ast.Experiment)

    def names(self, *categories: str) -> list[str]:
        return [d.name for d in self.decls.values() if d.category in categories]

    def element(self, name: str) -> ast.Element | None:
        decl = self.decls.get(name)
        return decl.node if decl is not None and decl.category == "element" else None

    def known_kind(self, name: str) -> str | None:
        """The kind of element ``name`` if it is an element of a known kind."""
        element = self.element(name)
        return element.kind if element is not None and element.kind in KINDS else None

    def junction_kind(self, name: str) -> str | None:
        decl = self.decls.get(name)
        if decl is None or decl.category != "junction":
            return None
        return decl.node.kind if decl.node.kind in JUNCTION_KINDS else None


def _declare(m: _Model) -> None:
    """Fill the model's one namespace: file-level functions, then the model's own names."""
    for file in m.files:
        for function in file.functions:
            _add_decl(m, _Decl("function", function.name, function.name_span, function))
            m.file_functions.setdefault(function.name, function)
    for statement in m.model.body:
        if isinstance(statement, ast.Param):
            _add_decl(m, _Decl("parameter", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Input):
            _add_decl(m, _Decl("input", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Output):
            _add_decl(m, _Decl("output", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.StateDecl):
            _add_decl(m, _Decl("state", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Discrete):
            _add_decl(m, _Decl("discrete", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.FnDef):
            _add_decl(m, _Decl("function", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Element):
            _add_decl(m, _Decl("element", statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Junction):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for name, span in zip(statement.names, spans):
                _add_decl(m, _Decl("junction", name, span, statement))
        elif isinstance(statement, ast.BondChain) and statement.label is not None:
            _add_decl(m, _Decl("bond label", statement.label, statement.label_span, statement))
    m.functions = {d.name: d.node for d in m.decls.values() if d.category == "function"}


def _add_decl(m: _Model, decl: _Decl) -> None:
    m.all_decls.append(decl)
    m.decls.setdefault(decl.name, decl)


# ============================================================ names and kinds

def check_reserved_names(m: _Model) -> None:
    """E315: ``t`` and ``pi`` cannot be defined; a function cannot take a built-in's name."""
    for decl in m.all_decls:
        if decl.name in RESERVED:
            m.report(_error("E315", f"'{decl.name}' is reserved for {RESERVED[decl.name]} and cannot name "
                                    f"{_a(decl.category)}", decl.span,
                            hint=f"choose another name, e.g. '{decl.name}_'"))
        elif decl.category == "function" and decl.name in BUILTINS:
            m.report(_error("E315", f"'{decl.name}' is a built-in function and cannot be redefined", decl.span,
                            hint=f"choose another name, e.g. 'my_{decl.name}'"))


def check_duplicate_names(m: _Model) -> None:
    """E302: one namespace per model; experiments, function arguments, settings each their own."""
    first: dict[str, _Decl] = {}
    for decl in m.all_decls:
        earlier = first.setdefault(decl.name, decl)
        if earlier is not decl:
            m.report(_error(
                "E302", f"'{decl.name}' is defined twice", decl.span,
                hint="elements, junctions, parameters, inputs, outputs, states, functions and bond labels "
                     "share one namespace; rename one of them",
                related=[Related(earlier.span, f"first defined here, as {_a(earlier.category)}")]))
    seen_experiments: dict[str, ast.Experiment] = {}
    for experiment in m.experiments:
        earlier = seen_experiments.setdefault(experiment.name, experiment)
        if earlier is not experiment:
            m.report(_error("E302", f"experiment '{experiment.name}' is defined twice", experiment.name_span,
                            related=[Related(earlier.name_span, "first defined here")]))
    for function in m.functions.values():
        seen: set[str] = set()
        for name in function.params:
            if name in seen:
                m.report(_error("E302", f"function '{function.name}' has two arguments named '{name}'",
                                function.name_span))
            seen.add(name)


def check_kinds(m: _Model) -> None:
    """E303 unknown element kind, E407 junction kind other than 0 or 1."""
    nodes = {d.name for d in m.all_decls if d.category in ("element", "junction")}
    # a kind the flattener already reported (E330 no such model in a library, E331 defined twice)
    reported = {(d.span.file, d.span.start) for d in m.diagnostics if d.code in KIND_CODES and d.span}
    models = {model.name for file in m.files for model in file.models} - {m.model.name}
    for element in m.statements(ast.Element):
        if element.kind in KINDS or (element.kind_span.file, element.kind_span.start) in reported:
            continue
        hint = _join_hints(_did_you_mean(element.kind, set(KINDS) | models),
                           f"element kinds are: {' '.join(KINDS)}"
                           + (", or a model defined or imported here" if models else ""))
        if element.kind in nodes:
            hint = f"to connect '{element.kind}' and '{element.name}' with a bond, write " \
                   f"'{element.kind} -> {element.name}'"
        m.report(_error("E303", f"unknown element kind '{element.kind}'", element.kind_span, hint=hint))
    for junction in m.statements(ast.Junction):
        if junction.kind not in JUNCTION_KINDS:
            m.report(_error("E407", f"unknown junction kind '{junction.kind}'", junction.kind_span,
                            hint="a junction is 0 (common effort, flows sum to zero) or "
                                 "1 (common flow, efforts sum to zero)"))


def check_shadowing(m: _Model) -> None:
    """W303: a model name hidden inside element laws by an element's own e, f or state."""
    one_ports = [e for e in m.elements if m.known_kind(e.name) and KINDS[e.kind].ports == 1]
    for decl in m.decls.values():
        if decl.category in ("element", "junction", "bond label", "function"):
            continue
        if decl.name in ("e", "f") and one_ports:
            meaning = "effort" if decl.name == "e" else "flow"
            m.report(_warning("W303", f"{decl.category} '{decl.name}' is hidden inside element laws", decl.span,
                              hint=f"in an element's laws '{decl.name}' is the element's own {meaning}; "
                                   f"rename the {decl.category} to use it there"))
            continue
        if decl.category not in ("parameter", "input"):
            continue  # an output or state of the same name as an element's state is usually that state
        owners = [name for name, laws in m.element_laws.items() if decl.name in laws.state_names]
        if owners:
            m.report(_warning("W303", f"{decl.category} '{decl.name}' is hidden inside the laws of "
                                      f"{_quoted(owners)}", decl.span,
                              hint=f"there '{decl.name}' is the element's own state; rename one of them"))


# ====================================================================== bonds

@dataclass(frozen=True)
class _End:
    """One end of a bond at a node."""

    bond: int
    side: str           # "tail" (power leaves the node) or "head" (power enters it)
    port: str | None    # the port as written, if any
    span: Span          # the endpoint as written


def _number_bonds(m: _Model) -> None:
    """Bonds 1, 2, 3, ... in order of appearance, chains left to right."""
    for chain in m.statements(ast.BondChain):
        single = len(chain.endpoints) == 2
        for tail, head in zip(chain.endpoints, chain.endpoints[1:]):
            number = len(m.bonds) + 1
            label = chain.label if single else None
            start = chain.label_span if label is not None else tail.span
            m.bonds.append(Bond(number, tail.name, head.name, label=label, span=start.to(head.span)))
            m.ends.setdefault(tail.name, []).append(_End(number, "tail", tail.port, tail.span))
            m.ends.setdefault(head.name, []).append(_End(number, "head", head.port, head.span))


def check_bonds(m: _Model) -> None:
    """E404 endpoint not an element or junction, E405 bond to itself, E406 label on a chain."""
    nodes = {d.name for d in m.all_decls if d.category in ("element", "junction")}
    for chain in m.statements(ast.BondChain):
        for endpoint in chain.endpoints:
            decl = m.decls.get(endpoint.name)
            if endpoint.name in nodes:
                continue
            if decl is None:
                hint = _did_you_mean(endpoint.name, nodes)
                if hint is not None:
                    m.misspelt.add(hint.split("'")[1])
                m.report(_error("E404", f"unknown element or junction '{endpoint.name}'", _name_part(endpoint),
                                hint=hint))
            elif decl.category not in ("element", "junction"):
                m.report(_error("E404", f"'{endpoint.name}' is {_a(decl.category)}, not an element or junction",
                                _name_part(endpoint), hint="bonds connect elements and junctions",
                                related=[Related(decl.span, f"'{endpoint.name}' is defined here")]))
        if chain.label is not None and len(chain.endpoints) > 2:
            m.report(_error("E406", f"the label '{chain.label}' is on a chain of {len(chain.endpoints) - 1} bonds",
                            chain.label_span,
                            hint=f"a label names one bond: write '{chain.label}: {chain.endpoints[0].name} -> "
                                 f"{chain.endpoints[1].name}' on its own line"))
    for bond in m.bonds:
        if bond.tail == bond.head:
            m.report(_error("E405", f"bond {bond.number} connects '{bond.tail}' to itself", bond.span,
                            hint="a bond joins two different elements or junctions"))


def _name_part(endpoint: ast.Endpoint) -> Span:
    """The span of an endpoint's node name, without ``.port``."""
    span = endpoint.span
    if endpoint.port is None:
        return span
    width = span.end - span.start - len(endpoint.port) - 1   # the name as written (a component's is not dotted)
    if width <= 0 or span.end_line != span.line:
        return span
    return Span(span.file, span.line, span.column, span.line, span.column + width,
                span.start, span.start + width, span.instance)


def _bond_notes(m: _Model, ends: Sequence[_End]) -> list[Related]:
    return [Related(m.bonds[end.bond - 1].span, f"bond {end.bond}") for end in ends]


def check_ports(m: _Model) -> None:
    """E401 one-port bonds, E402 two-port ports, E403 junction with fewer than two bonds."""
    for element in m.elements:
        kind = m.known_kind(element.name)
        if kind is None:
            continue
        ends = m.ends.get(element.name, [])
        if KINDS[kind].ports == 1:
            _check_one_port(m, element, ends)
        else:
            _check_two_port(m, element, ends)
    for junction in m.statements(ast.Junction):
        for name, span in zip(junction.names, junction.name_spans or (junction.span,) * len(junction.names)):
            ends = m.ends.get(name, [])
            for end in ends:
                if end.port is not None:
                    m.report(_error("E402", f"junction '{name}' has no port '{end.port}'", end.span,
                                    hint=f"ports belong to two-ports (TF, GY); write just '{name}'"))
            if len(ends) < 2 and not (not ends and name in m.misspelt):
                count = "no bond" if not ends else "only one bond"
                m.report(_error("E403", f"junction '{name}' has {count}", span,
                                hint="a junction joins two or more bonds; connect it or remove it",
                                related=_bond_notes(m, ends)))


def _check_one_port(m: _Model, element: ast.Element, ends: list[_End]) -> None:
    for end in ends:
        if end.port is not None:
            m.report(_error("E402", f"'{element.name}' is a one-port {element.kind} and has no port '{end.port}'",
                            end.span, hint=f"write just '{element.name}'"))
    if len(ends) == 1:
        return
    if not ends:
        if element.name in m.misspelt:
            return  # its bond names it misspelt (E404)
        m.report(_error("E401", f"{element.kind} '{element.name}' has no bond", element.name_span,
                        hint=f"connect it to a junction, e.g. 'j -> {element.name}'"))
        return
    m.report(_error("E401", f"{element.kind} '{element.name}' has {len(ends)} bonds; a one-port element has "
                            f"exactly one", element.name_span,
                    hint="join the bonds at a 0- or 1-junction and connect the element to it",
                    related=_bond_notes(m, ends)))


def _check_two_port(m: _Model, element: ast.Element, ends: list[_End]) -> None:
    name = element.name
    if len(ends) != 2:
        count = "no bond" if not ends else f"{len(ends)} bond" + ("s" if len(ends) > 1 else "")
        m.report(_error("E402", f"{element.kind} '{name}' has {count}; a two-port has exactly two", element.name_span,
                        hint=f"connect one bond to each port: 'a -> {name}.p1' and '{name}.p2 -> b'",
                        related=_bond_notes(m, ends)))
        return
    problems = False
    for end in ends:
        if end.port is not None and end.port not in PORT_NAMES:
            m.report(_error("E402", f"{element.kind} '{name}' has no port '{end.port}'", end.span,
                            hint=f"the ports of a two-port are p1 and p2{_port_suggestion(end.port)}"))
            problems = True
    if problems:
        return
    first, second = ends
    if first.port is not None and first.port == second.port:
        m.report(_error("E402", f"port {first.port} of '{name}' is used by two bonds ({first.bond} and {second.bond})",
                        second.span, hint="each port of a two-port takes one bond: use p1 and p2",
                        related=[Related(first.span, f"bond {first.bond} uses {first.port} here")]))
        return
    if first.port is None and second.port is None:
        if first.side == second.side:
            direction = "into" if first.side == "head" else "out of"
            m.report(_error("E402", f"both bonds of {element.kind} '{name}' point {direction} it, so its ports "
                                    f"must be named", element.name_span,
                            hint=f"write {name}.p1 at one bond and {name}.p2 at the other",
                            related=_bond_notes(m, ends)))
            return
        p1, p2 = (first, second) if first.side == "head" else (second, first)
    elif first.port is not None:
        p1, p2 = (first, second) if first.port == "p1" else (second, first)
    else:
        p1, p2 = (second, first) if second.port == "p1" else (first, second)
    signs = (1 if p1.side == "head" else -1, 1 if p2.side == "tail" else -1)
    m.ports[name] = ((p1.bond, p2.bond), signs)


def _port_suggestion(port: str) -> str:
    hint = _did_you_mean(port, PORT_NAMES)
    return f" ({hint})" if hint else ""


# ======================================================================= laws

@dataclass
class _ElementLaws:
    """An element's laws sorted out: what the expression checks and the graph need."""

    assigns: dict[str, ast.LawAssign] = field(default_factory=dict)
    custom: dict[str, ast.LawState] = field(default_factory=dict)
    initials: dict[str, ast.LawCall] = field(default_factory=dict)
    rates: dict[str, ast.LawCall] = field(default_factory=dict)
    state_names: tuple[str, ...] = ()


@dataclass
class _StateLaws:
    initial: ast.LawCall | None = None
    rate: ast.LawCall | None = None


def _kind_takes(kind_name: str) -> str:
    """The laws a kind takes, for hints: "e = ... and q(0) = ... (or its own states: ...)"."""
    kind = KINDS[kind_name]
    if kind.ports == 2:
        return "r = ..."
    laws = " and/or ".join(f"{law} = ..." for law in sorted(kind.laws))
    if kind.storage:
        return f"{laws} and {kind.state}(0) = ..., or its own states: state X, der(X) = ..., X(0) = ..."
    return laws


def check_laws(m: _Model) -> None:
    """E501-E505: the laws each element kind takes, needs and may not repeat; states and rates."""
    for element in m.elements:
        if element.kind in KINDS:
            m.element_laws[element.name] = _check_element_laws(m, element)


def _check_element_laws(m: _Model, element: ast.Element) -> _ElementLaws:
    kind = KINDS[element.kind]
    laws = _ElementLaws()
    calls: list[ast.LawCall] = []
    for law in element.laws:
        if isinstance(law, ast.LawState):
            if not kind.storage:
                m.report(_error("E505", f"{element.kind} '{element.name}' cannot declare states", law.span,
                                hint=f"only storage elements (C, I) have states; "
                                     f"{_a(element.kind)} takes {_kind_takes(element.kind)}"))
            elif law.name in ("e", "f"):
                m.report(_error("E505", f"a state cannot be called '{law.name}'", law.name_span,
                                hint="e and f are the element's effort and flow; choose another name"))
            elif law.name in laws.custom:
                m.report(_error("E503", f"state '{law.name}' of '{element.name}' is declared twice", law.name_span,
                                related=[Related(laws.custom[law.name].name_span, "first declared here")]))
            else:
                laws.custom[law.name] = law
        elif isinstance(law, ast.LawAssign):
            if law.target not in kind.laws:
                m.report(_error("E501", f"{element.kind} '{element.name}' cannot have a law '{law.target} = ...'",
                                law.target_span, hint=f"{_a(element.kind)} takes {_kind_takes(element.kind)}"))
            elif law.target in laws.assigns:
                m.report(_error("E503", f"'{element.name}' has two laws for {law.target}", law.target_span,
                                related=[Related(laws.assigns[law.target].target_span, "first given here")]))
            else:
                laws.assigns[law.target] = law
        else:
            calls.append(law)
    if kind.storage:
        laws.state_names = tuple(laws.custom) or (kind.state,)
    for call in calls:
        _check_state_law(m, element, laws, call)
    for required in kind.required:
        if not required & set(laws.assigns):
            needed = " or ".join(f"'{law} = ...'" for law in sorted(required))
            m.report(_error("E502", f"{element.kind} '{element.name}' has no law {needed}", element.name_span,
                            hint=f"{_a(element.kind)} takes {_kind_takes(element.kind)}"))
    for name, state in laws.custom.items():
        if name not in laws.rates:
            m.report(_error("E504", f"state '{name}' of '{element.name}' has no rate law", state.name_span,
                            hint=f"add 'der({name}) = ...', driven by the element's "
                                 f"{kind.stored_variable}"))
    return laws


def _check_state_law(m: _Model, element: ast.Element, laws: _ElementLaws, call: ast.LawCall) -> None:
    kind = KINDS[element.kind]
    states = laws.state_names
    if not kind.storage:
        target = call.arg.name if call.func == "der" and isinstance(call.arg, ast.Name) else call.func
        if any(isinstance(law, ast.LawState) and law.name == target for law in element.laws):
            return  # the state itself is reported (E505)
        m.report(_error("E504", f"{element.kind} '{element.name}' has no states, so '{call.func}(...)' means nothing "
                                f"here", call.func_span, hint=f"{_a(element.kind)} takes {_kind_takes(element.kind)}"))
        return
    listing = f"its states: {', '.join(states)}"
    if call.func == "der":
        target = call.arg.name if isinstance(call.arg, ast.Name) else None
        if target in laws.custom:
            _store_once(m, laws.rates, target, call, f"'{element.name}' has two rate laws for {target}")
        elif target is not None and target == kind.state and not laws.custom:
            port = kind.stored_variable or ""
            m.report(_error("E504", f"the rate of {target} is the {port} of '{element.name}' and cannot be given",
                            call.span, hint=f"der({target}) = {port[-1]} always; to integrate something else, declare "
                                            f"a state: 'state X [unit], der(X) = ..., X(0) = ...'"))
        elif target is None:
            m.report(_error("E504", "der(...) takes the name of a state", call.arg.span,
                            hint=f"write der(X) = ... for a state X; {listing}"))
        else:
            m.report(_error("E504", f"der({target}): '{element.name}' has no state '{target}'", call.arg.span,
                            hint=_join_hints(_did_you_mean(target, states), listing)))
        return
    if call.func in states:
        if not (isinstance(call.arg, ast.Num) and call.arg.value == 0):
            m.report(_error("E504", f"an initial value is written {call.func}(0) = ...", call.arg.span))
        else:
            _store_once(m, laws.initials, call.func, call, f"'{element.name}' has two initial values for {call.func}")
        return
    m.report(_error("E504", f"'{call.func}(...)' on '{element.name}' is neither an initial value nor a rate law",
                    call.func_span,
                    hint=_join_hints(_did_you_mean(call.func, states + ("der",)),
                                     f"write STATE(0) = ... or der(STATE) = ...; {listing}")))


def _store_once(m: _Model, store: dict, key: str, law: ast.LawCall, message: str) -> None:
    if key in store:
        m.report(_error("E503", message, law.span, related=[Related(store[key].span, "first given here")]))
    else:
        store[key] = law


def check_model_states(m: _Model) -> None:
    """E501/E503/E504/E505 for model-level ``state x : der(x) = ..., x(0) = ...``."""
    for state in m.statements(ast.StateDecl):
        laws = _StateLaws()
        m.model_states[state.name] = laws
        for law in state.laws:
            if isinstance(law, ast.LawAssign):
                m.report(_error("E501", f"state '{state.name}' has no law '{law.target} = ...'", law.target_span,
                                hint=f"a model state takes der({state.name}) = ... and {state.name}(0) = ..."))
            elif isinstance(law, ast.LawState):
                m.report(_error("E505", f"state '{state.name}' cannot declare further states", law.span,
                                hint="declare each model state with its own 'state' statement"))
            elif law.func == "der":
                if isinstance(law.arg, ast.Name) and law.arg.name == state.name:
                    if laws.rate is not None:
                        m.report(_error("E503", f"state '{state.name}' has two rate laws", law.span,
                                        related=[Related(laws.rate.span, "first given here")]))
                    laws.rate = laws.rate or law
                else:
                    m.report(_error("E504", f"the rate law of state '{state.name}' is written der({state.name}) = ...",
                                    law.arg.span))
            elif law.func == state.name:
                if not (isinstance(law.arg, ast.Num) and law.arg.value == 0):
                    m.report(_error("E504", f"an initial value is written {state.name}(0) = ...", law.arg.span))
                elif laws.initial is not None:
                    m.report(_error("E503", f"state '{state.name}' has two initial values", law.span,
                                    related=[Related(laws.initial.span, "first given here")]))
                else:
                    laws.initial = law
            else:
                m.report(_error("E504", f"'{law.func}(...)' is neither an initial value nor a rate law of state "
                                        f"'{state.name}'", law.func_span,
                                hint=f"write der({state.name}) = ... and {state.name}(0) = ..."))
        if laws.rate is None:
            m.report(_error("E504", f"state '{state.name}' has no rate law", state.name_span,
                            hint=f"add ': der({state.name}) = ...' (and '{state.name}(0) = ...' if not 0)"))


# ================================================================ expressions

GENERAL = frozenset({"parameter", "input", "output", "state", "discrete", "graph", "time", "csv"})
DISCRETE_START = frozenset({"parameter", "input", "state", "discrete", "graph"})
_DISCRETE_RULE = ("a discrete variable's initial value is an expression of parameters, and of inputs and initial "
                  "states at t = 0")
SIGNAL = frozenset({"parameter", "input", "time", "csv"})
CONSTANT = frozenset({"parameter"})

_CATEGORY_PHRASE = {"state": "model state", "time": "time", "discrete": "discrete variable"}


@dataclass(frozen=True)
class _Scope:
    """Where an expression is written: which names it may use, and how to explain it."""

    what: str                               # "a parameter", "an input", "the law e = ... of C 'spring'", ...
    allowed: frozenset[str]                 # categories of model names, and "graph", "time", "csv"
    rule: str                               # the hint that says what this place may use
    functions: Mapping[str, ast.FnDef]
    local: Mapping[str, str] = field(default_factory=dict)       # name -> what it is here
    forbidden: Mapping[str, str] = field(default_factory=dict)   # own names this law may not use -> why
    owner: str | None = None                # the element whose law this is
    params_before: "_Above | frozenset[str] | None" = None   # in a parameter declaration: those above it
    current: str | None = None              # the name being defined (a parameter's self-reference)
    constant_locals: bool = False           # locals are constants (function arguments)
    code: str = "E316"                      # the code of a name this place may not use

    def constant(self, what: str) -> "_Scope":
        """The scope of a table's breakpoints inside this one: constants only."""
        return dataclasses.replace(
            self, what=what, allowed=self.allowed & CONSTANT,
            rule="table breakpoints are constants: numbers, parameters and pi",
            local=self.local if self.constant_locals else {}, forbidden={})


class _ExpressionChecker:
    """Checks one expression's names, references and calls; one ``_check_<Class>`` per node class."""

    def __init__(self, m: _Model, scope: _Scope):
        self.m = m
        self.scope = scope
        self.errors = 0

    def report(self, diagnostic: Diagnostic) -> None:
        self.errors += diagnostic.is_error
        self.m.report(diagnostic)

    def check(self, node, scope: _Scope | None = None) -> None:
        saved = self.scope
        self.scope = scope or self.scope
        try:
            method = getattr(self, f"_check_{type(node).__name__}", None)
            if method is None:
                raise TypeError(f"unsupported expression node {type(node).__name__}")
            method(node)
        finally:
            self.scope = saved

    # leaves ------------------------------------------------------------------
    def _check_Num(self, node: ast.Num) -> None:
        pass

    def _check_Str(self, node: ast.Str) -> None:
        self.report(_error("E313", "a string where a number is expected", node.span,
                           hint="strings are descriptions, or the file and column of csv(...)"))

    def _check_ListExpr(self, node: ast.ListExpr) -> None:
        self.report(_error("E313", "a list where a number is expected", node.span,
                           hint="lists are the breakpoints of table(t, [t0, t1, ...], [v0, v1, ...])"))

    def _check_Unary(self, node: ast.Unary) -> None:
        self.check(node.operand)

    def _check_Binary(self, node: ast.Binary) -> None:
        self.check(node.left)
        self.check(node.right)

    def _check_If(self, node: ast.If) -> None:
        self.check(node.cond)
        self.check(node.then)
        self.check(node.orelse)

    # names -------------------------------------------------------------------
    def _not_allowed(self, node, phrase: str) -> None:
        self.report(_error(self.scope.code, f"{self.scope.what} cannot use {phrase}", node.span,
                           hint=self.scope.rule))

    def _check_Name(self, node: ast.Name) -> None:
        scope, name = self.scope, node.name
        if name in scope.forbidden:
            self.report(_error("E506", scope.forbidden[name], node.span, hint=scope.rule))
            return
        if name in scope.local or name == "pi":
            return
        if name == "t":
            if "time" not in scope.allowed:
                self._not_allowed(node, "time 't'")
            return
        decl = self.m.decls.get(name)
        if decl is None:
            self._undefined(node)
            return
        self.m.used.add(name)
        if decl.category in ("element", "junction", "bond label"):
            variables = self._variables_of(name)
            self.report(_error("E316", f"'{name}' is {_a(decl.category)}, not a value", node.span,
                               hint=f"use one of its variables: {', '.join(variables)}" if variables else None))
        elif decl.category == "function":
            params = ", ".join(decl.node.params)
            self.report(_error("E316", f"'{name}' is a function, not a value", node.span,
                               hint=f"call it: {name}({params})"))
        elif decl.category not in scope.allowed:
            self._not_allowed(node, f"{_CATEGORY_PHRASE.get(decl.category, decl.category)} '{name}'")
        elif decl.category == "parameter" and scope.params_before is not None:
            if name == scope.current:
                self.report(_error("E305", f"parameter '{name}' is defined in terms of itself", node.span))
            elif name not in scope.params_before:
                self.report(_error("E305", f"parameter '{name}' is used before it is defined", node.span,
                                   hint=f"a parameter may use only parameters defined above it: move "
                                        f"'param {name}' above this line",
                                   related=[Related(decl.span, f"'{name}' is defined here")]))

    def _undefined(self, node: ast.Name) -> None:
        name, scope = node.name, self.scope
        visible = [n for n, d in self.m.decls.items()
                   if d.category in scope.allowed or d.category == "function"] + list(scope.local) + ["pi"]
        if "time" in scope.allowed:
            visible.append("t")
        hint = _did_you_mean(name, visible)
        if hint is None and name in ("e", "f"):
            hint = (f"'{name}' alone is an element's own {'effort' if name == 'e' else 'flow'}, usable in its laws; "
                    f"elsewhere write X.{name} for element X")
        if hint is None:
            owners = [o for o, laws in self.m.element_laws.items() if name in laws.state_names]
            if owners:
                hint = f"'{name}' is a state of '{owners[0]}': write {owners[0]}.{name}"
        if node.span.file.startswith("--set #"):     # --set k=abc

            hint = f"{hint}; {SET_HINT}" if hint else SET_HINT
        self.report(_error("E301", f"undefined name '{name}'", node.span, hint=hint))

    def _variables_of(self, name: str) -> list[str]:
        """The variables an element, junction or bond exposes, as written in expressions."""
        decl = self.m.decls.get(name)
        if decl is None or decl.category == "bond label":
            return [f"{name}.e", f"{name}.f"]
        if decl.category == "junction":
            kind = self.m.junction_kind(name)
            return [f"{name}.{JUNCTIONS[kind].common}"] if kind is not None else []
        kind = self.m.known_kind(name)
        if kind is None:
            return []
        if KINDS[kind].ports == 2:
            return [f"{name}.{port}.{var}" for port in PORT_NAMES for var in "ef"]
        laws = self.m.element_laws.get(name)
        states = laws.state_names if laws else ()
        return [f"{name}.e", f"{name}.f"] + [f"{name}.{s}" for s in states]

    # graph references ------------------------------------------------------
    def _check_Ref(self, node: ast.Ref) -> None:
        if not self._valid_ref(node):
            return
        head = node.parts[0]
        if head == self.scope.owner and len(node.parts) == 2 and node.parts[1] in self.scope.forbidden:
            self.report(_error("E506", self.scope.forbidden[node.parts[1]], node.span, hint=self.scope.rule))
        elif "graph" not in self.scope.allowed:
            self._not_allowed(node, f"the graph variable '{node.dotted}'")

    def _valid_ref(self, node: ast.Ref) -> bool:
        head, rest = node.parts[0], node.parts[1:]
        decl = self.m.decls.get(head)
        if decl is not None and decl.category not in ("element", "junction", "bond label") \
                and _BOND_NUMBER.fullmatch(head):
            decl = None  # bN names bond N unless an element, junction or label is called bN
        if decl is None:
            match = _BOND_NUMBER.fullmatch(head)
            if match is None:
                self.report(_error("E301", f"undefined name '{head}' in '{node.dotted}'", node.span,
                                   hint=_did_you_mean(head, self.m.names("element", "junction", "bond label"))))
                return False
            number = int(match.group(1))
            if not 1 <= number <= len(self.m.bonds):
                self.report(_error("E312", f"there is no bond {number}", node.span,
                                   hint=f"bonds are numbered 1 to {len(self.m.bonds)} in order of appearance"))
                return False
            return self._bond_variable(node, rest, f"bond {number}")
        self.m.used.add(head)
        if decl.category == "bond label":
            return self._bond_variable(node, rest, f"bond '{head}'")
        if decl.category == "junction":
            return self._junction_variable(node, head, rest)
        if decl.category == "element":
            return self._element_variable(node, head, rest)
        self.report(_error("E312", f"'{head}' is {_a(decl.category)}; only elements, junctions and bonds have "
                                   f"variables", node.span, hint=f"write just '{head}'"))
        return False

    def _unknown_variable(self, node: ast.Ref, owner: str, variables: list[str], extra: str | None = None) -> bool:
        hint = None if extra else _did_you_mean(node.dotted, variables)
        listing = f"its variables: {', '.join(variables)}" if variables else None
        self.report(_error("E312", f"{owner} has no variable '{'.'.join(node.parts[1:])}'", node.span,
                           hint=_join_hints(extra, hint, listing)))
        return False

    def _bond_variable(self, node: ast.Ref, rest: tuple[str, ...], owner: str) -> bool:
        if rest in (("e",), ("f",)):
            return True
        return self._unknown_variable(node, owner, [f"{node.parts[0]}.e", f"{node.parts[0]}.f"])

    def _junction_variable(self, node: ast.Ref, name: str, rest: tuple[str, ...]) -> bool:
        kind = self.m.junction_kind(name)
        if kind is None:
            return True  # unknown junction kind, reported by check_kinds
        common = JUNCTIONS[kind].common
        if rest == (common,):
            return True
        if rest in (("e",), ("f",)):
            has, lacks = JUNCTIONS[kind].common_word, JUNCTIONS[kind].summed_word
            bonds = [f"b{end.bond}" if self.m.bonds[end.bond - 1].label is None else self.m.bonds[end.bond - 1].label
                     for end in self.m.ends.get(name, [])]
            example = f", e.g. {bonds[0]}.{rest[0]}" if bonds else ""
            self.report(_error("E312", f"'{name}' is a {kind}-junction: it has a common {has} ({name}.{common}) but "
                                       f"no common {lacks}", node.span,
                               hint=f"each bond at a {kind}-junction has its own {lacks}: use a bond's variable"
                                    f"{example}"))
            return False
        return self._unknown_variable(node, f"junction '{name}'", [f"{name}.{common}"])

    def _element_variable(self, node: ast.Ref, name: str, rest: tuple[str, ...]) -> bool:
        kind = self.m.known_kind(name)
        if kind is None:
            return True  # unknown kind, reported by check_kinds
        variables = self._variables_of(name)
        owner = f"{kind} '{name}'"
        if ".".join((name,) + rest) in variables:
            return True
        if KINDS[kind].ports == 1 and rest and rest[0] in PORT_NAMES:
            variable = rest[-1] if rest[-1] in ("e", "f") else "e"
            return self._unknown_variable(node, owner, variables, f"'{name}' is a one-port: write {name}.{variable}")
        if KINDS[kind].ports == 2 and rest in (("e",), ("f",)):
            return self._unknown_variable(node, owner, variables,
                                          f"'{name}' is a two-port: name the port, e.g. {name}.p1.{rest[0]}")
        return self._unknown_variable(node, owner, variables)

    # calls -------------------------------------------------------------------
    def _check_Call(self, node: ast.Call) -> None:
        scope, func = self.scope, node.func
        if func in scope.functions:
            self.m.used.add(func)
            function = scope.functions[func]
            if len(node.args) != len(function.params):
                self.report(_error("E306", f"'{func}' takes {len(function.params)} argument"
                                           f"{'' if len(function.params) == 1 else 's'} "
                                           f"({', '.join(function.params)}), {len(node.args)} given", node.span,
                                   related=[Related(function.name_span, f"'{func}' is defined here")]))
            for arg in node.args:
                self.check(arg)
            return
        if func in BUILTINS:
            getattr(self, f"_call_{func}", self._call_builtin)(node)
            return
        decl = self.m.decls.get(func)
        if decl is not None and decl.category != "function":
            self.report(_error("E316", f"'{func}' is {_a(decl.category)}, not a function", node.func_span))
        else:
            hint = _did_you_mean(func, list(BUILTINS) + list(scope.functions))
            if decl is not None:
                hint = f"'{func}' is defined inside the model; a function outside it cannot call it"
            self.report(_error("E301", f"unknown function '{func}'", node.func_span,
                               hint=hint or "built-in functions: " + " ".join(BUILTINS)))
        for arg in node.args:
            self.check(arg)

    def _arity(self, node: ast.Call) -> bool:
        least, most = BUILTINS[node.func]
        given = len(node.args)
        if least <= given and (most is None or given <= most):
            return True
        if most is None:
            wanted = f"at least {least} arguments"
        else:
            wanted = f"{least} argument{'' if least == 1 else 's'}"
        usage = {"table": "table(t, [t0, t1, ...], [v0, v1, ...])", "step": "step(t, t0)",
                 "csv": 'csv("file.csv", "column")', "atan2": "atan2(y, x)"}.get(node.func)
        self.report(_error("E306", f"{node.func}() takes {wanted}, {given} given", node.span,
                           hint=f"write {usage}" if usage else None))
        return False

    def _call_builtin(self, node: ast.Call) -> None:
        self._arity(node)
        for arg in node.args:
            self.check(arg)

    def _call_table(self, node: ast.Call) -> None:
        if not self._arity(node):
            for arg in node.args:
                if not isinstance(arg, ast.ListExpr):
                    self.check(arg)
            return
        x, xs, ys = node.args
        self.check(x)
        lists = []
        for position, arg in (("second", xs), ("third", ys)):
            if isinstance(arg, ast.ListExpr):
                lists.append(arg)
            else:
                self.report(_error("E306", f"the {position} argument of table() must be a list [...]", arg.span,
                                   hint="write table(t, [t0, t1, ...], [v0, v1, ...])"))
        entries = self.scope.constant("a table breakpoint")
        for lst in lists:
            for item in lst.items:
                self.check(item, entries)
        if len(lists) == 2:
            if len(xs.items) != len(ys.items):
                self.report(_error("E306", f"table() has {len(xs.items)} breakpoints but {len(ys.items)} values",
                                   node.span, hint="give one value per breakpoint"))
            elif len(xs.items) < 2:
                self.report(_error("E306", "table() needs at least two points", node.span,
                                   hint="for a constant, write the value itself"))

    def _call_mod(self, node: ast.Call) -> None:
        self._call_builtin(node)
        if len(node.args) == 2:
            divisor = node.args[1]
            while isinstance(divisor, ast.Unary) and divisor.op in "+-":
                divisor = divisor.operand
            if isinstance(divisor, ast.Num) and divisor.value == 0:
                self.report(_error("E306", "mod(x, 0): the divisor is zero", node.args[1].span,
                                   hint="the remainder of a division by zero is undefined; give a non-zero divisor"))

    def _call_csv(self, node: ast.Call) -> None:
        if "csv" not in self.scope.allowed:
            self._not_allowed(node, "csv(...)")
            return
        if not self._arity(node):
            return
        strings = []
        for position, arg in zip(("file name", "column name"), node.args):
            if isinstance(arg, ast.Str):
                strings.append(arg)
            else:
                self.report(_error("E313", f"the {position} of csv() must be a string", arg.span,
                                   hint='write csv("data/file.csv", "column")'))
        if len(strings) == 2:
            _check_csv(self.m, node, *strings, report=self.report)


def _is_table(path: Path, header: list[str]) -> bool:
    """Whether a file whose first line is ``header`` is a CSV table, whose column names may be
    shown: two columns or more, named in printable text, and a first data row (if any) of as many
    numbers."""
    if len(header) < 2 or any(_CONTROL.search(cell) for cell in header):
        return False
    from bondc.runtime import csv_rows, open_data

    try:
        with open_data(path) as handle:
            rows = csv_rows(handle)
    except (OSError, UnicodeDecodeError, ValueError, csv.Error):
        return False
    if len(rows) < 2:
        return True
    try:
        numbers = [float(cell) for cell in rows[1]]
    except ValueError:
        return False
    return len(numbers) == len(header)


#: Characters no column name (or line of a model) holds: the C0 controls but tab, and DEL.
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")


def _check_csv(m: _Model, node: ast.Call, path_arg: ast.Str, column_arg: ast.Str, report) -> None:
    """E310: the CSV file exists (relative to the model file) and has the column."""
    source = m.sources.get(node.span.file)
    base = source.path.parent if source is not None and source.path is not None else Path(node.span.file).parent
    path = base / path_arg.value
    shown = os.path.normpath(os.path.join(os.path.dirname(node.span.file), path_arg.value))
    key = str(path)
    if key not in m.csv_headers:
        from bondc.runtime import CsvError, csv_header      # (numpy: only for a model that reads a csv file)

        try:
            m.csv_headers[key] = csv_header(path)      # the simulator's own reader
        except CsvError as problem:
            m.csv_headers[key] = str(problem).rpartition(": ")[2]
        except (OSError, UnicodeDecodeError, csv.Error):
            m.csv_headers[key] = None
    header = m.csv_headers[key]
    if isinstance(header, str):
        report(_error("E310", f"cannot read CSV file '{path_arg.value}': {header}", path_arg.span,
                      hint="a data file is a regular text file with a header line"))
    elif header is None:
        report(_error("E310", f"cannot read CSV file '{path_arg.value}'", path_arg.span,
                      hint=f"the path is relative to the model file: looked for '{shown}'"))
    elif not header or not any(header):
        report(_error("E310", f"CSV file '{path_arg.value}' has no header line", path_arg.span,
                      hint="the first line names the columns, e.g. t,omega"))
    elif column_arg.value not in header and not _is_table(path, header):
        # a model may name any file (/etc/passwd, /proc/self/environ): what is not a table is not quoted
        report(_error("E310", f"'{path_arg.value}' is not a CSV table", path_arg.span,
                      hint="a data file is a header line of column names separated by commas (time first), "
                           "then rows of numbers"))
    elif column_arg.value not in header:
        columns = [c for c in header if c]
        report(_error("E310", f"CSV file '{path_arg.value}' has no column '{column_arg.value}'", column_arg.span,
                      hint=_join_hints(_did_you_mean(column_arg.value, columns), f"its columns: {', '.join(columns)}")))
    elif len(header) < 2:
        report(_error("E310", f"CSV file '{path_arg.value}' needs a time column and a value column",
                      path_arg.span, hint="the first column (or the column t or time) is time"))
    else:
        from bondc.numeric import csv_scales

        try:
            csv_scales(str(path), column_arg.value)
        except ValueError as problem:
            report(_error("E310", f"CSV file '{path_arg.value}': {problem} in its header", column_arg.span,
                          hint="a header names a column's unit in brackets, e.g. 'omega [rpm]', 't [ms]'; "
                               "a column without one is SI"))
            return
        from bondc.runtime import CsvError, load_csv

        try:
            load_csv(path, column_arg.value)        # the data rows, as the simulation reads them
        except CsvError as problem:
            report(_error("E310", f"CSV file '{path_arg.value}': {str(problem).partition(': ')[2]}",
                          path_arg.span, hint="rows (after the header, not counting blank lines and # comments) "
                                              "are numbers, times in increasing order"))
        except (OSError, UnicodeDecodeError, csv.Error):
            report(_error("E310", f"cannot read CSV file '{path_arg.value}'", path_arg.span))


def _check_expr(m: _Model, expr: ast.Expr, scope: _Scope) -> bool:
    """Check one expression in its scope; remember and return whether it had no errors."""
    checker = _ExpressionChecker(m, scope)
    checker.check(expr)
    m.expr_ok[id(expr)] = checker.errors == 0
    return checker.errors == 0


_PARAMETER_RULE = "a parameter is a constant: numbers, parameters defined above it, pi and functions"
_OVERRIDE_RULE = "an override is a constant: numbers, parameters, pi and functions"
_BINDING_RULE = ("a parameter is a constant: numbers, parameters, pi and functions; a value that varies "
                 "needs an input of the component (bind it to any signal) or an element of your own")
_CONSTANT_RULE = "{} is a constant: numbers, parameters, pi and functions"
_INPUT_RULE = ("an input is a signal of t, parameters and other inputs (table, step, csv, functions); "
               "feedback from the states goes into an element's law, a modulated source's for a controller "
               "(MSe drive : e = Kp*(x_ref - mass.q))")
_EXTERNAL_RULE = ("an external input's default is a constant: numbers, parameters, pi and functions; the host "
                  "supplies the signal itself (a table of times and values, a function of t or a CSV file)")
_GENERAL_RULE = ("an expression may use parameters, inputs, outputs, model states, t, functions and graph "
                 "variables (X.e, X.f, X.q, J.e, b3.f)")


def _scope(m: _Model, what: str, allowed: frozenset[str], rule: str, **extra) -> _Scope:
    return _Scope(what=what, allowed=allowed, rule=rule, functions=m.functions, **extra)


def check_functions(m: _Model) -> None:
    """Names in function bodies (their arguments only) and E304 recursion."""
    for decl in m.all_decls:
        if decl.category != "function" or m.decls[decl.name] is not decl:
            continue
        function = decl.node
        file_level = function.name in m.file_functions and m.file_functions[function.name] is function
        callable_ = m.file_functions if file_level else m.functions
        arguments = ", ".join(function.params) or "none"
        if file_level:
            allowed, rule = frozenset(), (f"a file-level function uses only its arguments ({arguments}), pi, "
                                          f"numbers and functions; pass other values as arguments")
        else:       # a function inside a model may also use the model's parameters (constants)
            allowed, rule = frozenset({"parameter"}), (f"a function uses its arguments ({arguments}), the "
                                                       f"model's parameters, pi, numbers and functions; pass "
                                                       f"signals and graph variables as arguments")
        scope = _Scope(what=f"function '{function.name}'", allowed=allowed, functions=callable_, rule=rule,
                       local={p: "argument" for p in function.params}, constant_locals=True)
        _check_expr(m, function.body, scope)
    calls = {name: [c for c in _calls(f.body) if c in m.functions] for name, f in m.functions.items()}
    for cycle in _cycles(list(m.functions), calls):
        m.bad_functions.update(cycle)
        first = m.functions[cycle[0]]
        path = " -> ".join(cycle + [cycle[0]])
        message = (f"function '{cycle[0]}' calls itself" if len(cycle) == 1
                   else f"functions {_quoted(cycle)} call each other")
        m.report(_error("E304", f"{message}: {path}", first.name_span,
                        hint="functions cannot be recursive; write the repetition out",
                        related=[Related(m.functions[name].name_span, f"'{name}' is defined here")
                                 for name in cycle[1:]]))


def _calls(expr: ast.Expr) -> list[str]:
    return [node.func for node in ast.walk(expr) if isinstance(node, ast.Call)]


def _names(expr: ast.Expr) -> list[str]:
    return [node.name for node in ast.walk(expr) if isinstance(node, ast.Name)]


def _cycles(order: Sequence[str], edges: Mapping[str, Sequence[str]]) -> list[list[str]]:
    """Each dependency cycle once, as the list of its members starting at the earliest in ``order``."""
    rank = {name: index for index, name in enumerate(order)}
    state: dict[str, str] = {}
    found: list[list[str]] = []
    seen: set[frozenset[str]] = set()

    def visit(name: str, stack: list[str]) -> None:
        state[name] = "visiting"
        stack.append(name)
        for target in edges.get(name, ()):
            if target not in rank:
                continue
            if state.get(target) == "visiting":
                cycle = stack[stack.index(target):]
                start = min(range(len(cycle)), key=lambda i: rank[cycle[i]])
                cycle = cycle[start:] + cycle[:start]
                if frozenset(cycle) not in seen:
                    seen.add(frozenset(cycle))
                    found.append(cycle)
            elif target not in state:
                visit(target, stack)
        stack.pop()
        state[name] = "done"

    for name in order:
        if name not in state:
            visit(name, [])
    return found


class _Above:
    """The parameters declared above the one at ``index`` (``name in above``), without a copy."""

    __slots__ = ("order", "index")

    def __init__(self, order: Mapping[str, int], index: int):
        self.order, self.index = order, index

    def __contains__(self, name) -> bool:
        return self.order.get(name, self.index) < self.index


def check_expressions(m: _Model) -> None:
    """Every expression of the model: E301, E305, E306, E310, E312, E313, E316, E506."""
    order: dict[str, int] = {}
    for index, param in enumerate(m.params):
        order.setdefault(param.name, index)         # (a name defined twice: from its first line on)
    for index, param in enumerate(m.params):
        # (the parameters above it as a view, not a copy: a copy per parameter was quadratic, 39 s
        # for 60 000 parameters)
        scope = _scope(m, "a parameter", CONSTANT, _PARAMETER_RULE,
                       params_before=_Above(order, index), current=param.name)
        _check_expr(m, param.value, scope)
    for signal in m.inputs:
        if signal.external:
            _check_expr(m, signal.value, _scope(m, f"the default of external input '{signal.name}'", CONSTANT,
                                                _EXTERNAL_RULE, code="E344"))
        else:
            _check_expr(m, signal.value, _scope(m, "an input", SIGNAL, _INPUT_RULE))
    for output in m.outputs:
        _check_expr(m, output.value, _scope(m, "an output", GENERAL, _GENERAL_RULE))
    for element in m.elements:
        if element.name in m.element_laws:
            _check_element_expressions(m, element, m.element_laws[element.name])
    for state in m.statements(ast.StateDecl):
        laws = m.model_states[state.name]
        if laws.rate is not None:
            _check_expr(m, laws.rate.value, _scope(m, f"the rate of state '{state.name}'", GENERAL, _GENERAL_RULE))
        if laws.initial is not None:
            _check_expr(m, laws.initial.value, _scope(m, "an initial value", CONSTANT,
                                                      _CONSTANT_RULE.format("an initial value")))
    for discrete in m.statements(ast.Discrete):     # parameters, and inputs and initial states at t = 0
        _check_expr(m, discrete.value, _scope(m, f"the initial value of discrete variable '{discrete.name}'",
                                              DISCRETE_START, _DISCRETE_RULE))
    for when in m.statements(ast.When):
        _check_when(m, when)


_WHEN_RULE = ("a when clause's statements are NAME = EXPR, for a discrete variable, and reinit(STATE, EXPR), "
              "for a state (X.q, X.p, a custom or a model state)")


def _check_when(m: _Model, when: ast.When) -> None:
    """The condition and the statements of a ``when`` clause: targets are discrete variables
    (``NAME = ...``) or states (``reinit(STATE, ...)``), E301/E306/E316 otherwise."""
    scope = _scope(m, "a when clause", GENERAL, _GENERAL_RULE)
    _check_expr(m, when.condition, scope)
    for action in when.actions:
        if isinstance(action, ast.WhenAssign):
            decl = m.decls.get(action.name)
            if decl is None:
                m.report(_error("E301", f"undefined name '{action.name}'", action.name_span,
                                hint=_did_you_mean(action.name, m.names("discrete")) or _WHEN_RULE))
            elif decl.category != "discrete":
                m.report(_error("E316", f"a when clause cannot assign {_a(decl.category)} ('{action.name}')",
                                action.name_span, hint=_WHEN_RULE))
            else:
                m.used.add(action.name)
            _check_expr(m, action.value, scope)
            continue
        if action.func != "reinit":
            m.report(_error("E301", f"unknown statement '{action.func}(...)' in a when clause", action.func_span,
                            hint=_WHEN_RULE))
            continue
        if len(action.args) != 2:
            m.report(_error("E306", f"reinit() takes 2 arguments, {len(action.args)} given", action.span,
                            hint="write reinit(STATE, new value)"))
            continue
        target, value = action.args
        if _check_expr(m, target, scope) and _reinit_target(m, target) is None:
            m.report(_error("E316", "reinit() sets a state: X.q, X.p, a custom state X.NAME or a model state",
                            target.span, hint=_WHEN_RULE))
        _check_expr(m, value, scope)


def _reinit_target(m: _Model, target) -> str | None:
    """The qualified state ``target`` names (``ball.p``, ``x``), or None."""
    if isinstance(target, ast.Name):
        decl = m.decls.get(target.name)
        return target.name if decl is not None and decl.category == "state" else None
    if isinstance(target, ast.Ref) and len(target.parts) == 2:
        head, name = target.parts
        kind = m.known_kind(head)
        laws = m.element_laws.get(head)
        if kind is None or laws is None or not KINDS[kind].storage:
            return None
        states = set(laws.state_names) | {KINDS[kind].state}
        return f"{head}.{name}" if name in states else None
    return None


def _own_variable_rules(kind_name: str, target: str, name: str,
                        states: Sequence[str]) -> tuple[dict[str, str], str]:
    """Which of its own variables an element's ``target = ...`` law may not use and why (E506), and its rule."""
    kind = KINDS[kind_name]
    own = f"{kind_name} '{name}'"
    itself = f"the law {target} = ... of {own} cannot use {target} itself"
    other = "f" if target == "e" else "e"
    other_word = "flow" if other == "f" else "effort"
    if kind.source:
        return ({target: itself,
                 other: f"the law {target} = ... of source {own} cannot use its own {other_word} {other}: a "
                        f"source is independent of its load"},
                "a source's law may use parameters, inputs, t and other elements' variables, not its own e or f "
                "(for a load-dependent source use an R)")
    if kind.storage:
        listing = ", ".join(states)
        return ({target: itself,
                 other: f"the law {target} = ... of {own} is a function of its state, not of its {other_word} "
                        f"{other}"},
                f"the law {target} = ... of {_a(kind_name)} may use its states ({listing}), parameters, inputs, t "
                f"and other elements' variables, not its own e or f")
    if kind.ports == 1:
        return ({target: itself},
                f"the law {target} = ... of {_a(kind_name)} may use its {other_word} {other}, not {target} itself")
    return {}, "a two-port's law may use parameters, inputs, t and other elements' variables"


def _check_element_expressions(m: _Model, element: ast.Element, laws: _ElementLaws) -> None:
    kind = KINDS[element.kind]
    local: dict[str, str] = {}
    if kind.ports == 1:
        local = {"e": "effort", "f": "flow", **{s: "state" for s in laws.state_names}}
    for target, law in laws.assigns.items():
        forbidden, rule = _own_variable_rules(element.kind, target, element.name, laws.state_names)
        scope = _scope(m, f"the law {target} = ... of {element.kind} '{element.name}'", GENERAL, rule,
                       local=local, forbidden=forbidden, owner=element.name)
        _check_expr(m, law.value, scope)
    for name, rate in laws.rates.items():
        scope = _scope(m, f"the rate of state '{name}' of '{element.name}'", GENERAL,
                       "a rate law may use the element's e, f and states, parameters, inputs, t and other "
                       "elements' variables", local=local, owner=element.name)
        _check_expr(m, rate.value, scope)
    not_constant = {n: f"an initial value is a constant and cannot use the {what} '{n}' of '{element.name}'"
                    for n, what in local.items() if n not in m.decls}
    for name, initial in laws.initials.items():
        scope = _scope(m, "an initial value", CONSTANT, _CONSTANT_RULE.format("an initial value"),
                       forbidden=not_constant)
        _check_expr(m, initial.value, scope)


def check_signal_cycles(m: _Model, inputs: Mapping[str, ast.Input] | None = None) -> None:
    """E305: inputs defined in terms of each other, outputs defined in terms of each other."""
    groups = (("input", inputs if inputs is not None else {i.name: i for i in m.inputs}),
              ("output", {o.name: o for o in m.outputs}))
    for category, defs in groups:
        edges = {name: _names(d.value) for name, d in defs.items()}
        for cycle in _cycles(list(defs), edges):
            path = " -> ".join(cycle + [cycle[0]])
            m.report(_error("E305", f"{category}s defined in terms of each other: {path}",
                            defs[cycle[0]].name_span,
                            related=[Related(defs[n].name_span, f"'{n}' is defined here") for n in cycle[1:]],
                            hint=f"an {category} cannot depend on itself, directly or through other {category}s"))


# ====================================================================== units

def _resolve_unit(m: _Model, unit: ast.Unit | None) -> units.SIUnit | None:
    """The SI meaning of a written unit; E201/E203 reported once per unit."""
    if unit is None:
        return None
    if id(unit) in m.units:
        return m.units[id(unit)]
    numbers = [f for f in unit.factors if f.name != "1" and not f.name[:1].isalpha() and f.name[:1] != "_"]
    if numbers:
        bad = numbers[0]
        m.report(_error("E203", f"[{unit.text}] is not a unit: '{bad.name}' is a number", bad.span,
                        hint="a unit is a product of unit names (and 1); put a scale factor in the value, "
                             f"e.g. {bad.name}*x [{_without(unit, bad)}]"))
        resolved = None
    else:
        resolved, diagnostics = units.resolve(unit)
        for diagnostic in diagnostics:
            m.report(diagnostic)
    m.units[id(unit)] = resolved
    return resolved


def _without(unit: ast.Unit, factor: ast.UnitFactor) -> str:
    rest = [f for f in unit.factors if f is not factor]
    return units._factors_text(tuple(rest)) if rest else "1"


# Coherent replacements for units that take no prefix.
_COHERENT: Mapping[str, tuple[tuple[str, int], ...]] = {
    "deg": (("rad", 1),), "rev": (("rad", 1),), "rpm": (("rad", 1), ("s", -1)), "min": (("s", 1),),
    "h": (("s", 1),), "bar": (("Pa", 1),), "mbar": (("Pa", 1),), "L": (("m", 3),), "l": (("m", 3),),
}


def _coherent_factors(name: str) -> tuple[tuple[str, int], ...] | None:
    """The coherent SI unit names (with powers) for one unit name: ``kN`` -> N, ``mg`` -> kg."""
    if name in _COHERENT:
        return _COHERENT[name]
    si = units.lookup(name)
    if si is None or si.is_coherent:
        return ((name, 1),)
    if si.dims == units.lookup("kg").dims:
        return (("kg", 1),)
    for prefix in units.PREFIXES:
        base = units.lookup(name[len(prefix):]) if name.startswith(prefix) else None
        if base is not None and base.is_coherent and base.dims == si.dims:
            return ((name[len(prefix):], 1),)
    return None


def coherent_suggestion(unit: ast.Unit) -> str:
    """The coherent SI unit measuring the same as ``unit``: ``ms`` -> ``s``, ``kN*m`` -> ``N*m``, ``rpm`` -> ``rad/s``.

    >>> from bondc.parse import parse_set_value
    >>> [coherent_suggestion(parse_set_value(f"x = 1 [{u}]").unit) for u in ("ms", "kN*m", "rpm", "L/min", "mm^2")]
    ['s', 'N*m', 'rad/s', 'm^3/s', 'm^2']
    """
    powers: dict[str, Fraction] = {}
    for factor in unit.factors:
        replacement = _coherent_factors(factor.name)
        if replacement is None:
            powers = {}
            break
        for name, power in replacement:
            if name != "1":
                powers[name] = powers.get(name, Fraction(0)) + power * Fraction(factor.exponent)
    factors = tuple(ast.UnitFactor(name, power) for name, power in powers.items() if power != 0)
    text = units._factors_text(factors) if factors else "1"
    candidate, problems = units.resolve(ast.Unit(factors, text))
    original, _ = units.resolve(unit)
    if original is None:
        return text
    if problems or candidate is None or not candidate.is_coherent or candidate.dims != original.dims:
        return original.dimension_text()
    return text


def _require_coherent(m: _Model, unit: ast.Unit | None, who: str, why: str) -> units.SIUnit | None:
    """E202 unless ``unit`` (if any) is coherent SI; returns the resolved unit."""
    resolved = _resolve_unit(m, unit)
    if resolved is not None and not resolved.is_coherent:
        m.report(_error("E202", f"the unit of {who} must be a coherent SI unit, not [{unit.text}]", unit.span,
                        hint=f"{why}: write [{coherent_suggestion(unit)}]"))
    return resolved


def _is_constant(expr: ast.Expr) -> bool:
    """No parameter names: a number written with a unit, converted to SI by it."""
    return all(name == "pi" for name in _names(expr))


_COMPUTED_WHY = ("{} uses other parameters, which are in SI, so it is computed in SI and its unit only declares "
                 "the result")


def check_units(m: _Model) -> None:
    """E201 unknown unit, E202 non-coherent unit on a computed value, E203 not a plain unit."""
    for param in m.params:
        if _is_constant(param.value):
            _resolve_unit(m, param.unit)
        else:
            _require_coherent(m, param.unit, f"parameter '{param.name}'",
                              _COMPUTED_WHY.format(f"'{param.name}'"))
    for signal in m.inputs:
        _require_coherent(m, signal.unit, f"input '{signal.name}'", "an input is computed in SI")
    for output in m.outputs:
        _resolve_unit(m, output.unit)
    for state in m.statements(ast.StateDecl):
        _require_coherent(m, state.unit, f"state '{state.name}'", "states are integrated in SI")
    for discrete in m.statements(ast.Discrete):
        _require_coherent(m, discrete.unit, f"discrete variable '{discrete.name}'", "it is computed in SI")
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, ast.LawState):
                _require_coherent(m, law.unit, f"state '{law.name}'", "states are integrated in SI")


# ================================================================= parameters

def _parameter_definitions(m: _Model) -> dict[str, _Definition]:
    """Every parameter's declaration, with the values its instance binds (section 11)."""
    definitions = {p.name: _Definition(p.name, p.value, p.unit, p.span, p.unit, "declaration") for p in m.params
                   if m.decls.get(p.name) is not None and m.decls[p.name].node is p}
    for binding in m.good_bindings:
        _override(binding.name, binding.value, binding.unit, binding.span, binding.origin, definitions)
    return definitions


def check_bindings(m: _Model) -> None:
    """An instance's parameter bindings: the value fits the parameter as an override would."""
    m.good_bindings = [b for b in m.bindings
                       if _check_override(m, b.name, b.name_span, b.value, b.unit, b.origin)]


def _override(name: str, expr: ast.Expr, unit: ast.Unit | None, span: Span, origin: str,
              definitions: dict[str, _Definition]) -> None:
    """Replace the definition of parameter ``name`` (if it is one) by an override."""
    base = definitions.get(name)
    if base is not None:
        definitions[name] = _Definition(name, expr, unit, span, base.declared_unit, origin)


def _check_override(m: _Model, name: str, name_span: Span, expr: ast.Expr, unit: ast.Unit | None,
                    where: str) -> bool:
    """An experiment's ``param`` or a ``--set``: the name is a parameter, the value and unit fit it."""
    decl = m.decls.get(name)
    if decl is None or decl.category != "parameter":
        what = f"; '{name}' is {_a(decl.category)}" if decl is not None else ""
        m.report(_error("E301", f"{where} sets '{name}', which is not a parameter{what}", name_span,
                        hint=_did_you_mean(name, m.names("parameter"))))
        return False
    m.used.add(name)
    if where.startswith("instance "):       # a component's parameter bound in an instance
        scope = _scope(m, f"the value of parameter '{name.rsplit('.', 1)[-1]}' in {where}", CONSTANT,
                       _BINDING_RULE)
    else:
        scope = _scope(m, "an override", CONSTANT, _OVERRIDE_RULE)
    ok = _check_expr(m, expr, scope)
    if _is_constant(expr):
        resolved = _resolve_unit(m, unit)
    else:
        resolved = _require_coherent(m, unit, f"the value of '{name}'", _COMPUTED_WHY.format("the value"))
    declared = _resolve_unit(m, decl.node.unit)
    if resolved is not None and declared is not None and resolved.dims != declared.dims:
        m.report(_error("E204", f"[{unit.text}] does not measure the same quantity as [{declared.text}], the unit "
                                f"of '{name}'", unit.span,
                        hint=f"give the value in [{declared.text}] or a unit of the same kind "
                             f"({declared.dimension_text()})",
                        related=[Related(decl.node.unit.span, f"'{name}' is declared in [{declared.text}] here")]))
        ok = False
    return ok


def _evaluate_parameters(m: _Model, definitions: Mapping[str, _Definition]) -> dict[str, float]:
    """Every parameter's SI value, in dependency order; problems reported, failed ones left out."""
    order = list(definitions)
    edges = {name: [n for n in _names(d.expr) + _names_in_functions(m, d.expr) if n in definitions]
             for name, d in definitions.items()}
    in_cycle: set[str] = set()
    for cycle in _cycles(order, edges):
        in_cycle.update(cycle)
        overridden = [n for n in cycle if definitions[n].origin != "declaration"]
        if not overridden:
            continue  # a cycle of declarations always has a forward reference, reported as such
        culprit = definitions[overridden[0]]
        path = " -> ".join(cycle + [cycle[0]])
        m.report(_error("E305", f"parameter dependency cycle: {path}", culprit.span,
                        hint=f"the value from {culprit.origin} makes '{culprit.name}' depend on itself",
                        related=[Related(definitions[n].span, f"'{n}' is defined here") for n in cycle
                                 if n != culprit.name]))
    values: dict[str, float] = {}
    failed: set[str] = set(in_cycle)
    done: set[str] = set()

    def visit(name: str) -> None:
        if name in done:
            return
        done.add(name)
        for dependency in edges[name]:
            if dependency not in in_cycle:
                visit(dependency)
        definition = definitions[name]
        if name in failed or any(d in failed for d in edges[name]) or not m.expr_ok.get(id(definition.expr), True) \
                or _function_closure(m, _calls(definition.expr)) & m.bad_functions:
            failed.add(name)
            return
        value = _definition_value(m, definition, values)
        if value is None:
            failed.add(name)
        else:
            values[name] = value

    for name in order:
        visit(name)
    return values


def _names_in_functions(m: _Model, expr: ast.Expr) -> list[str]:
    """The names the bodies of the functions ``expr`` calls use (a model's function may use its
    parameters), arguments left out."""
    found: list[str] = []
    for name in sorted(_function_closure(m, _calls(expr))):
        function = m.functions.get(name)
        if function is not None:
            found += [n for n in _names(function.body) if n not in function.params]
    return found


def _function_closure(m: _Model, names: Iterable[str]) -> set[str]:
    found: set[str] = set()
    todo = [n for n in names if n in m.functions]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found.add(name)
        todo += [c for c in _calls(m.functions[name].body) if c in m.functions]
    return found


def _definition_value(m: _Model, definition: _Definition, values: Mapping[str, float]) -> float | None:
    """A parameter's SI value: a constant is converted by its unit (or the declared one), an expression is SI."""
    try:
        value = evaluate(definition.expr, values, m.functions, m.budget)
    except EvaluationError as error:
        if not error.repeated:
            m.report(error.diagnostic)
        return None
    if not _is_constant(definition.expr):
        return value
    unit = definition.unit if definition.unit is not None else definition.declared_unit
    resolved = m.units.get(id(unit)) if unit is not None else None
    if unit is not None and resolved is None:
        return None
    if resolved is None:
        return value
    return _finite_si(m, resolved.to_si(value), value, unit, definition.expr.span)


def _finite_si(m: _Model, si: float, value: float, unit: ast.Unit, span: Span) -> float | None:
    """A number converted to SI, or None with E311 where the conversion leaves a double's range
    (``1e308 [kN/m]`` is 1e311 N/m: inf, which no law and no generated module can use)."""
    if math.isfinite(si):
        return si
    m.report(_error("E311", f"cannot evaluate: {value:g} [{unit.text}] is {'an infinite' if si == si else 'no'} "
                            f"number in SI units (beyond a double's range, about 1.8e308)", span,
                    hint="write the value in a unit closer to SI, or a smaller value"))
    return None


def _parameters(m: _Model, definitions: Mapping[str, _Definition],
                values: Mapping[str, float]) -> dict[str, Parameter]:
    out = {}
    for name, definition in definitions.items():
        declared = m.decls[name].node
        unit = definition.unit if definition.unit is not None else definition.declared_unit
        resolved = m.units.get(id(unit)) if unit is not None else None
        out[name] = Parameter(name, values[name], definition.expr, unit.text if unit is not None else None,
                              declared.description, declared.span,
                              resolved.factor if resolved is not None else 1.0)
    return out


def check_constants(m: _Model, values: Mapping[str, float]) -> None:
    """E311/E306 for constants outside parameters: initial values and table breakpoints."""
    constants: list[ast.Expr] = []
    for laws in m.element_laws.values():
        constants += [law.value for law in laws.initials.values()]
    constants += [laws.initial.value for laws in m.model_states.values() if laws.initial is not None]
    constants += [signal.value for signal in m.inputs if signal.external]      # external inputs' defaults
    for expr in constants:
        _try_evaluate(m, expr, values)
    for expr in _all_expressions(m):
        if not m.expr_ok.get(id(expr), False):
            continue
        for node in ast.walk(expr):
            if isinstance(node, ast.Call) and node.func == "table" and len(node.args) == 3 \
                    and isinstance(node.args[1], ast.ListExpr):
                _check_breakpoints(m, node.args[1], values)


def check_divisors(m: _Model, values: Mapping[str, float]) -> None:
    """E311: a law, output, input or rate that divides by parameters whose value is 0 (``p/m`` with
    ``m = 0``): every evaluation of it would be inf or nan. The divisions are kept on the graph
    (``BondGraph.divisors``) so that values bound later (a sweep's points) are checked the same way
    (:func:`zero_divisors`)."""
    exprs = [i.value for i in m.inputs] + [o.value for o in m.outputs]
    for element in m.elements:
        exprs += [law.value for law in element.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    for state in m.statements(ast.StateDecl):
        exprs += [law.value for law in state.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    def unguarded(node):
        """The sub-expressions outside every if-branch (a guarded division may well be by 0)."""
        yield node
        if isinstance(node, ast.If):
            return
        for child in (getattr(node, "args", None) or getattr(node, "items", None) or
                      [getattr(node, k) for k in ("operand", "left", "right") if hasattr(node, k)]):
            yield from unguarded(child)

    divisors = []
    for expr in exprs:
        if not m.expr_ok.get(id(expr), False):
            continue
        for node in unguarded(expr):
            if not (isinstance(node, ast.Binary) and node.op == "/"):
                continue
            names = [n for n in ast.walk(node.right) if isinstance(n, (ast.Name, ast.Ref, ast.Call))]
            if names and all(isinstance(n, ast.Name) and n.name in values for n in names):
                divisors.append((node.right, tuple(dict.fromkeys(n.name for n in names))))
    m.divisors = tuple(divisors)
    for diagnostic in zero_divisors(m.divisors, values):
        m.report(diagnostic)


def zero_divisors(divisors, values: Mapping[str, float]) -> list[Diagnostic]:
    """E311 for each division of ``divisors`` (``BondGraph.divisors``: divisor and the parameters it
    uses) whose divisor is 0 with the parameter values ``values`` (name -> SI value)."""
    found = []
    for divisor, names in divisors:
        if not all(name in values for name in names):
            continue
        try:
            value = evaluate(divisor, values, {})
        except EvaluationError:
            continue
        if value == 0:
            used = ", ".join(f"{name} = {values[name]:g}" for name in names)
            found.append(_error("E311", f"a division by zero: the divisor is 0 with {used}", divisor.span,
                                hint="a parameter that divides must not be 0; check its value and the "
                                     "experiment's and --set overrides"))
    return found


def _try_evaluate(m: _Model, expr: ast.Expr, values: Mapping[str, float], checked: bool = False) -> float | None:
    """The value of a checked constant expression, or None (with E311 reported if it has none)."""
    if not (checked or m.expr_ok.get(id(expr), False)) or _function_closure(m, _calls(expr)) & m.bad_functions:
        return None
    if any(name not in values and name != "pi" for name in _names(expr)):
        return None  # uses a parameter that failed (already reported), or a function argument
    try:
        return evaluate(expr, values, m.functions, m.budget)
    except EvaluationError as error:
        if not error.repeated:
            m.report(error.diagnostic)
        return None


def _check_breakpoints(m: _Model, breakpoints: ast.ListExpr, values: Mapping[str, float]) -> None:
    points = []
    for item in breakpoints.items:
        value = _try_evaluate(m, item, values, checked=True)
        if value is None:
            return
        points.append((value, item))
    for (previous, _), (value, item) in zip(points, points[1:]):
        if value < previous:
            m.report(_error("E306", f"table breakpoints must not decrease: {value:g} comes after {previous:g}",
                            item.span, hint="list the breakpoints in increasing order"))
            return


def _all_expressions(m: _Model) -> list[ast.Expr]:
    exprs = [p.value for p in m.params] + [i.value for i in m.inputs] + [o.value for o in m.outputs]
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, (ast.LawAssign, ast.LawCall)):
                exprs.append(law.value)
    for state in m.statements(ast.StateDecl):
        exprs += [law.value for law in state.laws if isinstance(law, (ast.LawAssign, ast.LawCall))]
    exprs += [discrete.value for discrete in m.statements(ast.Discrete)]
    for when in m.statements(ast.When):
        exprs.append(when.condition)
        for action in when.actions:
            exprs += [action.value] if isinstance(action, ast.WhenAssign) else list(action.args)
    for experiment in m.experiments:
        exprs += [item.value for item in experiment.body]
    exprs += [f.body for f in m.functions.values()]
    return exprs


# ================================================================ experiments

@dataclass
class _ExperimentPlan:
    """An experiment's overrides, checked: what :func:`_experiment_def` needs."""

    experiment: ast.Experiment
    params: list[ast.Param] = field(default_factory=list)
    inputs: dict[str, ast.Input] = field(default_factory=dict)
    settings: dict[str, ast.Setting] = field(default_factory=dict)


def _with_defaults(model: ast.Model) -> ast.Model:
    """Each experiment with the settings of the model's ``defaults`` that it does not set itself."""
    defaults = [item for s in model.body if isinstance(s, ast.Defaults) for item in s.body]
    if not defaults:
        return model
    if not any(isinstance(s, ast.Experiment) for s in model.body):
        # a model without experiments runs with its defaults, as an experiment called "defaults"
        block = next(s for s in model.body if isinstance(s, ast.Defaults))
        experiment = ast.Experiment("defaults", "the model's defaults", tuple(defaults), block.span, block.span)
        return dataclasses.replace(model, body=model.body + (experiment,))
    body = []
    for statement in model.body:
        if isinstance(statement, ast.Experiment):
            own = {item.name for item in statement.body if isinstance(item, ast.Setting)}
            inherited = tuple(item for item in defaults if item.name not in own)
            statement = dataclasses.replace(statement, body=inherited + statement.body)
        body.append(statement)
    return dataclasses.replace(model, body=tuple(body))


def check_defaults(m: _Model) -> None:
    """``defaults`` blocks: settings only, each once (checked even where no experiment uses them)."""
    plan = _ExperimentPlan(ast.Experiment("defaults", None, ()))
    for block in m.statements(ast.Defaults):
        for item in block.body:
            _check_setting(m, plan, item)


def check_experiments(m: _Model) -> list[_ExperimentPlan]:
    """E314 unknown setting, E313/E317 bad setting values, overrides of unknown names (E301)."""
    plans = []
    for experiment in m.experiments:
        plan = _ExperimentPlan(experiment)
        plans.append(plan)
        where = f"experiment '{experiment.name}'"
        seen_params: dict[str, ast.Param] = {}
        for item in experiment.body:
            if isinstance(item, ast.Param):
                if item.name in seen_params:
                    m.report(_error("E302", f"{where} sets '{item.name}' twice", item.name_span,
                                    related=[Related(seen_params[item.name].name_span, "first set here")]))
                    continue
                seen_params[item.name] = item
                if _check_override(m, item.name, item.name_span, item.value, item.unit, where):
                    plan.params.append(item)
            elif isinstance(item, ast.Input):
                _check_input_replacement(m, plan, item, where)
            else:
                _check_setting(m, plan, item)
        if plan.inputs:
            check_signal_cycles(m, {**{i.name: i for i in m.inputs}, **plan.inputs})
    return plans


def _check_input_replacement(m: _Model, plan: _ExperimentPlan, item: ast.Input, where: str) -> None:
    decl = m.decls.get(item.name)
    if decl is None or decl.category != "input":
        what = f"; '{item.name}' is {_a(decl.category)}" if decl is not None else ""
        m.report(_error("E301", f"{where} replaces '{item.name}', which is not an input{what}", item.name_span,
                        hint=_did_you_mean(item.name, m.names("input"))))
        return
    if item.name in plan.inputs:
        m.report(_error("E302", f"{where} replaces input '{item.name}' twice", item.name_span,
                        related=[Related(plan.inputs[item.name].name_span, "first replaced here")]))
        return
    m.used.add(item.name)
    if item.external:
        m.report(_error("E345", f"{where} declares input '{item.name}' external", item.name_span,
                        hint=f"'external' belongs on the model's input ('input {item.name} [UNIT] external = ...'); "
                             f"an experiment replaces an input with a signal ('input {item.name} = ...')"))
        return
    _require_coherent(m, item.unit, f"input '{item.name}'", "an input is computed in SI")
    _check_expr(m, item.value, _scope(m, "an input", SIGNAL, _INPUT_RULE))
    plan.inputs[item.name] = item


def _check_setting(m: _Model, plan: _ExperimentPlan, item: ast.Setting) -> None:
    kind = SETTINGS.get(item.name)
    if kind is None:
        m.report(_error("E314", f"unknown experiment setting '{item.name}'", item.name_span,
                        hint=_join_hints(_did_you_mean(item.name, SETTINGS), "settings: " + " ".join(SETTINGS))))
        return
    if item.name in plan.settings:
        m.report(_error("E302", f"setting '{item.name}' is given twice", item.name_span,
                        related=[Related(plan.settings[item.name].name_span, "first given here")]))
        return
    if kind == "solver":
        if not isinstance(item.value, ast.Str):
            written = item.value.name if isinstance(item.value, ast.Name) else "Radau"
            m.report(_error("E313", "solver must be a string", item.value.span,
                            hint=f'write solver = "{written}"; solvers: {", ".join(SOLVERS)}'))
            return
        if item.unit is not None:
            m.report(_error("E313", "solver takes no unit", item.unit.span))
            return
        if item.value.value not in SOLVERS:
            m.report(_error("E317", f"unknown solver '{item.value.value}'", item.value.span,
                            hint=_join_hints(_did_you_mean(item.value.value, SOLVERS),
                                             "solvers (auto: chosen for stiffness; SUNDIALS CVODE and IDA; bondc's DOPRI5; scipy.integrate.solve_ivp methods): " + ", ".join(SOLVERS))))
            return
    elif kind in _LISTS:
        if not _list_setting_ok(m, item, kind):
            return
    elif kind == "operating point":
        if not isinstance(item.value, ast.Str) or item.value.value not in OPERATING_POINTS or item.unit is not None:
            m.report(_error("E313", f"{item.name} is \"initial\" or \"equilibrium\"", item.value.span,
                            hint=f'write {item.name} = "equilibrium" to linearise at the equilibrium found from the '
                                 "initial state"))
            return
    else:
        if isinstance(item.value, (ast.Str, ast.ListExpr)):
            m.report(_error("E313", f"{item.name} must be a number", item.value.span))
            return
        if not _check_expr(m, item.value, _scope(m, "a setting", CONSTANT, _CONSTANT_RULE.format("a setting"))):
            return
        if _is_constant(item.value):
            resolved = _resolve_unit(m, item.unit)
        else:
            resolved = _require_coherent(m, item.unit, f"setting '{item.name}'", _COMPUTED_WHY.format("it"))
        if resolved is not None and kind == "time" and resolved.dims != units.lookup("s").dims:
            m.report(_error("E204", f"{item.name} is a time, but [{item.unit.text}] is not a unit of time",
                            item.unit.span, hint="write it in s, ms, min or h"))
            return
        if item.unit is not None and resolved is None:
            return
    plan.settings[item.name] = item


#: Settings that list names: the node each entry must be, and the E313 message and hint for another.
_LISTS = {"outputs": (ast.Name, "outputs lists output names", "write outputs = [name1, name2]"),
          "transfers": (ast.Transfer, "bode lists pairs INPUT -> OUTPUT",
                        "write bode = [F -> x, F -> v]: the input excited and the output measured")}


def _list_setting_ok(m: _Model, item: ast.Setting, kind: str) -> bool:
    """Check a setting that lists outputs (``outputs = [a, b]``) or input-output pairs (``bode =
    [F -> x]``): E313 for an entry of another form, E301 for a name that is not an output (input)."""
    node, message, hint = _LISTS[kind]
    items = item.value.items if isinstance(item.value, ast.ListExpr) else (item.value,)
    ok = True
    for entry in items:
        if not isinstance(entry, node):
            m.report(_error("E313", message, entry.span, hint=hint))
            ok = False
        elif isinstance(entry, ast.Name):
            ok = _declared_as(m, entry, "output", f"declare it with 'output {entry.name} = ...'") and ok
        else:
            for name, category in ((entry.source, "input"), (entry.target, "output")):
                if _declared_as(m, name, category, f"bode = [INPUT -> OUTPUT]: declare it with "
                                                   f"'{category} {name.name} [UNIT] = ...'"):
                    m.used.add(name.name)
                else:
                    ok = False
    return ok


def _declared_as(m: _Model, entry: ast.Name, category: str, how: str) -> bool:
    """Whether a setting's name ``entry`` is a declared ``category`` ("output", "input"); else E301
    with the closest such name, what the name is instead, and ``how`` to declare it."""
    if entry.name in m.names(category):
        return True
    decl = m.decls.get(entry.name)
    what = f"'{entry.name}' is {_a(decl.category)}; " if decl is not None else ""
    m.report(_error("E301", f"no {category} named '{entry.name}'", entry.span,
                    hint=_join_hints(_did_you_mean(entry.name, m.names(category)), what + how)))
    return False


def _setting_value(m: _Model, item: ast.Setting, values: Mapping[str, float]):
    """A checked setting's value: SI float, solver string or output names."""
    kind = SETTINGS[item.name]
    if kind == "solver":
        return item.value.value
    if kind == "outputs":
        items = item.value.items if isinstance(item.value, ast.ListExpr) else (item.value,)
        return tuple(entry.name for entry in items)
    if kind == "transfers":
        return tuple((entry.source.name, entry.target.name) for entry in item.value.items)
    if kind == "operating point":
        return item.value.value
    value = _try_evaluate(m, item.value, values)
    if value is None:
        return None
    if _is_constant(item.value) and item.unit is not None:
        value = _finite_si(m, m.units[id(item.unit)].to_si(value), value, item.unit, item.value.span)
        if value is None:
            return None
    if value <= 0:
        m.report(_error("E317", f"{item.name} must be positive, not {value:g}", item.value.span))
        return None
    return value


def _signal(item: ast.Input, description: str | None = None) -> Signal:
    return Signal(item.name, item.value, item.unit.text if item.unit else None,
                  item.description or description, item.span, external=item.external, name_span=item.name_span)


def _experiment_def(m: _Model, plan: _ExperimentPlan, base_values: Mapping[str, float],
                    values: Mapping[str, float]) -> ExperimentDef:
    settings = {}
    for name, item in plan.settings.items():
        value = _setting_value(m, item, values)
        if value is not None:
            settings[name] = value
    known = {k: settings.pop(k) for k in ("t_end", "solver", "rtol", "atol", "max_step", "cycle", "outputs")
             if k in settings}
    descriptions = {i.name: i.description for i in m.inputs}
    changed = {name: value for name, value in values.items() if base_values.get(name) != value}
    experiment = plan.experiment
    return ExperimentDef(experiment.name, experiment.description, **known,
                         parameters=changed,
                         inputs={name: _signal(item, descriptions.get(name)) for name, item in plan.inputs.items()},
                         settings=settings, span=experiment.span)


# ==================================================================== unused

def check_passive_orientation(m: _Model) -> None:
    """W304: a resistor or storage element whose bond is drawn leaving it.

    Its ``e`` and ``f`` follow the half-arrow (LANGUAGE.md section 4), so with the
    bond drawn away from it ``e*f`` is the power it *delivers*: ``e = b*f`` makes a
    resistor a source, and ``der(q) = f`` fills a capacitor as it discharges. That
    is legal but almost never meant.
    """
    for element in m.elements:
        if element.kind not in KINDS or KINDS[element.kind].role not in (RESISTOR, STORAGE):
            continue
        ends = m.ends.get(element.name, ())
        if len(ends) != 1 or ends[0].side != "tail":
            continue
        bond = m.bonds[ends[0].bond - 1]
        role = "it stores" if KINDS[element.kind].stores else "it dissipates"
        m.report(_warning(
            "W304", f"the bond of {element.kind} '{element.name}' is drawn leaving it, so its e*f is the power "
                    f"it delivers, not the power {role}", element.name_span,
            related=(Related(bond.span, f"bond {bond.number} points away from '{element.name}'"),),
            hint=f"draw the bond towards it: '{bond.head} -> {element.name}'"))


def check_label_names(m: _Model) -> None:
    """W305: a bond label of the form ``b<N>`` that is also the default name of bond N."""
    for bond in m.bonds:
        if not bond.label or not bond.label[1:].isdigit() or bond.label[0] != "b":
            continue
        number = int(bond.label[1:])
        if number == bond.number or not 1 <= number <= len(m.bonds) or m.bonds[number - 1].label:
            continue
        other = m.bonds[number - 1]
        m.report(_warning(
            "W305", f"label '{bond.label}' names bond {bond.number}, but '{bond.label}' is also bond {number}'s "
                    f"default name; bond {number} is called 'bond{number}' in equations and results",
            bond.label_span if hasattr(bond, "label_span") else bond.span,
            related=(Related(other.span, f"bond {number}"),),
            hint=f"choose a label that is not b<number>, e.g. '{bond.label}_'"))


def check_unused(m: _Model) -> None:
    """W301 unused parameter, W302 unused input."""
    for decl in m.decls.values():
        if decl.name in m.used:
            continue
        if decl.category == "parameter":
            m.report(_warning("W301", f"parameter '{decl.name}' is never used", decl.span,
                              hint="remove it, or use it in a law, input or output"))
        elif decl.category == "input":
            m.report(_warning("W302", f"input '{decl.name}' is never used", decl.span,
                              hint="remove it, or use it in a law or output (e.g. MSe src : e = "
                                   f"{decl.name})"))


# ===================================================================== build

def _select_model(files: Sequence[ast.File], name: str | None) -> tuple[ast.Model | None, list[Diagnostic]]:
    """The model to build: the only one in the main file, or the one named (also from imports)."""
    main = files[0]
    where = _file_span(main.path)
    own = list(main.models)
    every = own + [model for file in files[1:] for model in file.models]
    listing = ", ".join(model.name for model in every) or "none"
    if name is not None:
        for model in own + every:
            if model.name == name:
                return model, []
        return None, [_error("E309", f"no model '{name}' in '{main.path}'", where,
                             hint=_join_hints(_did_you_mean(name, [m.name for m in every]),
                                              f"available models: {listing}"))]
    candidates = own or every
    runnable = [model for model in candidates if not ports_of(model)]   # a model with ports is a component
    if len(candidates) > 1 and len(runnable) == 1:
        return runnable[0], []
    if len(candidates) == 1:
        return candidates[0], []
    if not candidates:
        return None, [_error("E309", f"no model in '{main.path}'", where,
                             hint="a file describes a model in a 'model NAME ... end' block")]
    return None, [_error("E309", f"'{main.path}' has {len(candidates)} models; choose one with --model", where,
                         hint=f"available models: {', '.join(model.name for model in candidates)}")]


def _select_experiment(m: _Model, name: str | None) -> tuple[ast.Experiment | None, list[Diagnostic]]:
    if name is None:
        return None, []
    experiments = m.experiments
    if name == FIRST:
        return (experiments[0] if experiments else None), []
    for experiment in experiments:
        if experiment.name == name:
            return experiment, []
    listing = ", ".join(e.name for e in experiments) or "none"
    return None, [_error("E318", f"model '{m.model.name}' has no experiment '{name}'", _file_span(m.file.path),
                         hint=_join_hints(_did_you_mean(name, [e.name for e in experiments]),
                                          f"its experiments: {listing}"))]


def check_sets(m: _Model, sets: Sequence[ast.SetValue]) -> list[ast.SetValue]:
    """The command line's ``--set`` overrides that name a parameter with a fitting value and unit."""
    good = []
    for item in sets:
        name_span = Span(item.span.file, item.span.line, item.span.column, item.span.line,
                         item.span.column + len(item.name), item.span.start, item.span.start + len(item.name))
        if _check_override(m, item.name, name_span, item.value, item.unit, "an override (--set)"):
            good.append(item)
    return good


def _build(files: Sequence[ast.File], sources: Mapping[str, Source], model: str | None, experiment: str | None,
           sets: Sequence[ast.SetValue]) -> tuple[BondGraph | None, list[Diagnostic]]:
    chosen, problems = _select_model(files, model)
    if chosen is None:
        return None, problems
    component = bool(ports_of(chosen))     # (its causality is checked where it is used)
    flat = flatten(chosen, files, standalone=component)
    if flat.too_large:
        return None, list(flat.diagnostics)
    m = _Model(files[0], sources, _with_defaults(flat.model), tuple(files))
    m.diagnostics += flat.diagnostics
    m.bindings, m.instances = flat.bindings, flat.instances
    selected, problems = _select_experiment(m, experiment)
    m.diagnostics += problems
    _declare(m)
    _number_bonds(m)
    check_reserved_names(m)
    check_duplicate_names(m)
    check_kinds(m)
    check_bonds(m)
    check_ports(m)
    # what the structural checks found: with no error there, the causality of the graph's
    # structure is known whatever the laws' errors (_structural_conflicts)
    structure_known = not any(d.is_error for d in m.diagnostics)
    check_laws(m)
    check_model_states(m)
    check_shadowing(m)
    check_functions(m)
    check_expressions(m)
    check_signal_cycles(m)
    check_units(m)
    check_bindings(m)
    check_defaults(m)
    plans = check_experiments(m)
    good_sets = check_sets(m, sets)
    base, base_values = check_parameters(m, good_sets)
    check_constants(m, base_values)
    experiment_defs, chosen = check_experiment_values(m, plans, good_sets, base_values, selected)
    chosen_definitions, chosen_values = chosen or (base, base_values)
    check_divisors(m, chosen_values)
    check_passive_orientation(m)
    check_label_names(m)
    check_unused(m)

    diagnostics = _unique(m.diagnostics)
    if any(d.is_error for d in diagnostics):
        if structure_known and not component:
            diagnostics = _unique(diagnostics + _structural_conflicts(m, diagnostics))
        return None, diagnostics
    inputs = {i.name: _signal(i) for i in m.inputs}
    for i in m.inputs:
        if i.external:          # its default's value (SI), for the note that says it is used
            inputs[i.name] = dataclasses.replace(inputs[i.name], default=_try_evaluate(m, i.value, chosen_values))
    if selected is not None:
        inputs.update(experiment_defs[selected.name].inputs)
    graph = _graph(m, _parameters(m, chosen_definitions, chosen_values), inputs, experiment_defs)
    dimension_errors, si_units = check_dimensions(m, graph, chosen_values)
    if dimension_errors:
        if not component:    # (the laws' targets are right: only their dimensions are not)
            from bondc.causality import structural_conflicts

            dimension_errors += structural_conflicts(graph)
        return None, _unique(diagnostics + dimension_errors)
    from bondc.scope import build_scope

    return dataclasses.replace(graph, si_units=si_units, instances=tuple(m.instances),
                               scope=build_scope(m.model, m.all_decls)), diagnostics


def _structural_conflicts(m: _Model, diagnostics: Sequence[Diagnostic]) -> list[Diagnostic]:
    """E601: the causal conflicts of a model whose structure (elements, junctions, bonds, ports) is
    right and whose laws, parameters or experiments have errors, so that one run reports both.

    The graph is built from the structure only: no parameter, input or experiment is evaluated and
    no law is read but for which of ``e``/``f`` a resistor gives; an element with an error in its
    statement (its laws) is of unknown law, a resistor among them either way
    (:func:`bondc.causality.structural_conflicts`)."""
    from bondc.causality import structural_conflicts

    starts: dict[tuple[str, str], list[int]] = {}      # where the errors are, by file and instance
    for d in diagnostics:
        if d.is_error:
            starts.setdefault((d.span.file, d.span.instance), []).append(d.span.start)
    for offsets in starts.values():
        offsets.sort()

    def has_error(span: Span) -> bool:
        offsets = starts.get((span.file, span.instance), [])
        index = bisect.bisect_left(offsets, span.start)
        return index < len(offsets) and offsets[index] < max(span.end, span.start + 1)

    unknown = [element.name for element in m.elements if has_error(element.span)]
    elements, junctions, bonds = _structure(m, states=False)
    graph = BondGraph(m.model.name, m.model.description, m.file.path, {}, {}, {}, {}, elements, junctions, bonds,
                      (), {}, sources=dict(m.sources), span=m.model.span)
    return structural_conflicts(graph, unknown)


def check_dimensions(m: _Model, graph: BondGraph, values: Mapping[str, float]) -> tuple[list[Diagnostic], dict]:
    """E210: laws, outputs and inputs dimensionally consistent (LANGUAGE.md section 14); and the SI
    unit of every state and bond variable whose dimension is known."""
    from bondc import dimensions

    state_units: dict[str, ast.Unit | None] = {}
    for element in m.elements:
        for law in element.laws:
            if isinstance(law, ast.LawState):
                state_units[f"{element.name}.{law.name}"] = law.unit
    for statement in m.statements(ast.StateDecl):
        state_units[statement.name] = statement.unit
    for statement in m.statements(ast.Discrete):
        state_units[statement.name] = statement.unit
    context = dimensions.Context(
        graph=graph, unit_of=lambda unit: _resolve_unit(m, unit),
        params={p.name: p for p in m.params if m.decls.get(p.name) is not None and m.decls[p.name].node is p},
        inputs={i.name: i for i in m.inputs}, outputs={o.name: o for o in m.outputs},
        discretes={d.name: d for d in m.statements(ast.Discrete)}, state_units=state_units,
        functions=graph.functions, values=values)
    return dimensions.analyse(context)


def check_parameters(m: _Model, sets: Sequence[ast.SetValue]) -> tuple[dict[str, _Definition], dict[str, float]]:
    """E305 override cycles and E311: every parameter's SI value with the ``--set`` overrides."""
    definitions = _parameter_definitions(m)
    for item in sets:
        _override(item.name, item.value, item.unit, item.span, "--set", definitions)
    return definitions, _evaluate_parameters(m, definitions)


def check_experiment_values(m: _Model, plans: Sequence[_ExperimentPlan], sets: Sequence[ast.SetValue],
                            base_values: Mapping[str, float], selected: ast.Experiment | None):
    """Each experiment's parameters (its overrides, then ``--set``) and settings, evaluated.

    Returns the experiments by name and, for the selected one, its parameter definitions and values.
    """
    experiment_defs: dict[str, ExperimentDef] = {}
    chosen = None
    for plan in plans:
        experiment = plan.experiment
        if experiment.name in experiment_defs:
            continue  # a duplicate name, reported by check_duplicate_names
        definitions = _parameter_definitions(m)
        for item in plan.params:
            _override(item.name, item.value, item.unit, item.span, f"experiment '{experiment.name}'", definitions)
        for item in sets:
            _override(item.name, item.value, item.unit, item.span, "--set", definitions)
        values = _in_experiment(m, experiment, lambda: _evaluate_parameters(m, definitions))
        experiment_defs[experiment.name] = _experiment_def(m, plan, base_values, values)
        if experiment is selected:
            chosen = (definitions, values)
    return experiment_defs, chosen


def _in_experiment(m: _Model, experiment: ast.Experiment, run):
    """Run ``run`` and add, to each problem it reports outside the experiment, a note naming the experiment."""
    start = len(m.diagnostics)
    result = run()
    inside = experiment.span
    for index in range(start, len(m.diagnostics)):
        d = m.diagnostics[index]
        if d.span.file == inside.file and inside.start <= d.span.start <= inside.end:
            continue
        if any(d == earlier for earlier in m.diagnostics[:start]):
            m.diagnostics[index] = None
            continue
        note = Related(experiment.name_span, f"with the overrides of experiment '{experiment.name}'")
        m.diagnostics[index] = dataclasses.replace(d, related=d.related + (note,))
    m.diagnostics[:] = [d for d in m.diagnostics if d is not None]
    return result


def _unique(diagnostics: Iterable[Diagnostic]) -> list[Diagnostic]:
    return sorted(dict.fromkeys(diagnostics), key=sort_key)


def _graph(m: _Model, parameters: Mapping[str, Parameter], inputs: Mapping[str, Signal],
           experiments: Mapping[str, ExperimentDef]) -> BondGraph:
    elements, junctions, bonds = _structure(m)
    model_states = []
    for state in m.statements(ast.StateDecl):
        laws = m.model_states[state.name]
        model_states.append(StateVar(state.name, state.name, None, state.unit.text if state.unit else None,
                                     laws.initial.value if laws.initial else None, laws.rate.value,
                                     state.description, state.span))
    discrete = []
    for variable in m.statements(ast.Discrete):
        zero = ast.Num(0.0, "0", variable.span)
        model_states.append(StateVar(variable.name, variable.name, None,
                                     variable.unit.text if variable.unit else None, variable.value, zero,
                                     variable.description, variable.span))
        discrete.append(variable.name)
    whens = []
    for when in m.statements(ast.When):
        actions = tuple(("assign", ast.Name(a.name, a.name_span), a.value) if isinstance(a, ast.WhenAssign)
                        else ("reinit", a.args[0], a.args[1]) for a in when.actions)
        whens.append(WhenDef(when.condition, actions, _when_text(m, when), when.span))
    functions = {name: Function(name, f.params, f.body, f.description, f.span) for name, f in m.functions.items()}
    outputs = {}
    for output in m.outputs:
        resolved = m.units.get(id(output.unit)) if output.unit is not None else None
        outputs[output.name] = OutputDef(output.name, output.value, output.unit.text if output.unit else None,
                                         output.description, output.span,
                                         resolved.factor if resolved is not None else 1.0)
    return BondGraph(m.model.name, m.model.description, m.file.path, parameters, functions, inputs, outputs,
                     elements, junctions, bonds, tuple(model_states), experiments,
                     sources=dict(m.sources), span=m.model.span, discrete=tuple(discrete), whens=tuple(whens),
                     divisors=getattr(m, "divisors", ()))


def _structure(m: _Model, states: bool = True) -> tuple[dict[str, ElementNode], dict[str, JunctionNode],
                                                          tuple[Bond, ...]]:
    """The graph's elements, junctions and bonds; ``states``: with the storage elements' states
    (False: a model whose laws have errors, where they may be incomplete)."""
    labels = {bond.label for bond in m.bonds if bond.label}
    # A label "b9" on another bond takes the name bond 9 would have (W305 says so).
    bonds = [dataclasses.replace(bond, default_name=f"bond{bond.number}")
             if bond.label is None and f"b{bond.number}" in labels else bond for bond in m.bonds]
    elements = {}
    for element in m.elements:
        laws = m.element_laws[element.name]
        if KINDS[element.kind].ports == 2:
            (p1, p2), signs = m.ports[element.name]
            for number, port in ((p1, "p1"), (p2, "p2")):
                bond = bonds[number - 1]
                side = "tail_port" if bond.tail == element.name else "head_port"
                bonds[number - 1] = dataclasses.replace(bond, **{side: port})
            bond_numbers = (p1, p2)
        else:
            (end,) = m.ends[element.name]
            bond_numbers, signs = (end.bond,), (1 if end.side == "head" else -1,)
        elements[element.name] = ElementNode(
            element.kind, element.name, element.description,
            laws={target: law.value for target, law in laws.assigns.items()},
            law_spans={target: law.span for target, law in laws.assigns.items()},
            states=_element_states(element, laws) if states else (), bonds=bond_numbers, port_signs=signs,
            span=element.span, name_span=element.name_span)
    junctions = {}
    for junction in m.statements(ast.Junction):
        spans = junction.name_spans or (junction.span,) * len(junction.names)
        for name, span in zip(junction.names, spans):
            junctions[name] = JunctionNode(junction.kind, name, tuple(end.bond for end in m.ends[name]), span)
    return elements, junctions, tuple(bonds)


def _when_text(m: _Model, when: ast.When) -> str:
    """``when CONDITION`` as written (one line), for event lists; inside a component, with the
    names as the flat model has them (``when r2.air.e > r2.T_set + r2.hyst``), so that the firings
    of two instances are told apart."""
    if when.span is not None and when.span.instance:
        from bondc.fmt import format_expr

        head = "when " + " ".join(format_expr(when.condition).split())
    else:
        source = m.sources.get(when.span.file) if when.span is not None else None
        text = source.text[when.span.start:when.span.end] if source is not None else "when ..."
        head = " ".join(text.split(" then")[0].split())
    return head if len(head) <= 120 else head[:117] + "..."


def _element_states(element: ast.Element, laws: _ElementLaws) -> tuple[StateVar, ...]:
    kind = KINDS[element.kind]
    if not kind.storage:
        return ()
    if not laws.custom:
        initial = laws.initials.get(kind.state)
        return (StateVar(kind.state, f"{element.name}.{kind.state}", element.name, None,
                         initial.value if initial else None, None, None, element.name_span),)
    states = []
    for name, declared in laws.custom.items():
        initial = laws.initials.get(name)
        states.append(StateVar(name, f"{element.name}.{name}", element.name,
                               declared.unit.text if declared.unit else None,
                               initial.value if initial else None, laws.rates[name].value,
                               declared.description, declared.span))
    return tuple(states)


def build(file: ast.File, sources: Mapping[str, Source] | None = None, *, model: str | None = None,
          experiment: str | None = None, overrides: Sequence[ast.SetValue] = (),
          imported: Sequence[ast.File] = ()) -> tuple[BondGraph, list[Diagnostic]]:
    """Check one model of a parsed file and build its graph; raise ModelError with every error.

    ``imported`` are the files ``file`` imports (parsed); ``overrides`` are ``--set`` values, applied
    after the experiment's. Returns the graph and the warnings.
    """
    graph, diagnostics = _build([file, *imported], sources or {}, model, experiment, overrides)
    if graph is None:
        raise ModelError([d for d in diagnostics if d.is_error])
    return graph, diagnostics


# ====================================================================== load

def _read(path: Path, name: str) -> Source:
    return read_source(path, name)


def _std_library(name: str) -> Path | None:
    """The file of a shipped component library (``import "std:hydraulics"``)."""
    found = std_path_of(name)
    return None if found is None else Path(str(found))


def _shown_path(path: str, limit: int = 80) -> str:
    """A path as a message quotes it: a path longer than any file system allows, shortened."""
    return path if len(path) <= limit else f"{path[:limit // 2]}...{path[-limit // 4:]} ({len(path)} characters)"


def _not_a_model_file(target: Path, written: str) -> str | None:
    """Why an import's path cannot be a model file, or None: its name (or, through symbolic links,
    the name of the file it is) does not end in .bg, or the system cannot look it up."""
    if not written.endswith(".bg"):
        return f"cannot import '{_shown_path(written)}': it is not a .bg model file"
    try:
        real = target.resolve()
        target.is_file()
    except (OSError, RuntimeError, ValueError) as error:
        reason = getattr(error, "strerror", None) or "the system cannot look it up"
        return f"cannot find imported file '{_shown_path(written)}': {reason.lower()}"
    if real.suffix != ".bg" and target.exists():
        return f"cannot import '{_shown_path(written)}': it is a link to a file that is not a .bg model file"
    return None


def load_files(path: str | Path, text: str | None = None) -> tuple[list[ast.File], dict[str, Source], list[Diagnostic]]:
    """Parse ``path`` and, recursively, the files it imports (each once).

    ``text``: the main file's text as an editor holds it (unsaved); imports are still read from
    disk, relative to ``path``. Returns the files (the main one first), their sources by name, and
    E307/E308 diagnostics. I/O errors on the main file raise UsageError; syntax errors raise
    ParseError.
    """
    path = Path(path)
    main = _read(path, str(path)) if text is None else Source(str(path), text, path)
    sources = {main.name: main}
    files = [parse_source(main)]
    diagnostics: list[Diagnostic] = []
    loaded = {path.resolve()}

    def visit(file: ast.File, source: Source, stack: list[tuple[Path, str]]) -> None:
        for item in file.imports:
            if item.path.startswith("std:"):
                target, name = _std_library(item.path[4:]), item.path
                if target is None:
                    diagnostics.append(_error("E307", f"no component library '{item.path}'", item.span,
                                              hint=_join_hints(_did_you_mean(item.path[4:], STD_LIBRARIES),
                                                               "shipped libraries: " + ", ".join(
                                                                   f"std:{n}" for n in STD_LIBRARIES))))
                    continue
            else:
                target = source.path.parent / item.path
                name = os.path.normpath(os.path.join(os.path.dirname(source.name), item.path))
                problem = _not_a_model_file(target, item.path)
                if problem is not None:
                    # (a model may name any file: one that is not a model is not read, nor quoted)
                    diagnostics.append(_error("E307", problem, item.span,
                                              hint="import names a model file (.bg), relative to the importing "
                                                   "file, or a shipped library (std:NAME)"))
                    continue
            key = target.resolve()
            keys = [k for k, _ in stack]
            if key in keys:
                cycle = [n for _, n in stack[keys.index(key):]] + [name]
                diagnostics.append(_error("E308", f"cyclic import: {' -> '.join(cycle)}", item.span,
                                          hint="files cannot import each other; move what both need into a "
                                               "third file"))
                continue
            if key in loaded:
                continue
            if not target.is_file():
                diagnostics.append(_error("E307", f"cannot find imported file '{item.path}'", item.span,
                                          hint=f"import paths are relative to the importing file: looked for "
                                               f"'{name}'"))
                continue
            try:
                imported = Source(name, target.read_text(encoding="utf-8"), target)
            except (OSError, UnicodeDecodeError) as error:
                diagnostics.append(_error("E307", f"cannot read imported file '{item.path}': "
                                                  f"{getattr(error, 'strerror', None) or error}", item.span))
                continue
            loaded.add(key)
            sources[imported.name] = imported
            parsed = parse_source(imported)
            files.append(parsed)
            visit(parsed, imported, stack + [(key, name)])

    visit(files[0], main, [(path.resolve(), main.name)])
    return files, sources, diagnostics


def load(path: str | Path, *, model: str | None = None, experiment: str | None = None,
         sets: Sequence[ast.SetValue] = (), text: str | None = None,
         loaded: tuple | None = None) -> tuple[BondGraph, list[Diagnostic]]:
    """Read, parse and check a ``.bg`` file; return its graph and warnings, or raise ModelError.

    ``experiment`` names the experiment whose overrides apply (None: none; :data:`FIRST`: the first);
    ``sets`` are command-line ``--set`` values (from ``parse_set_value``), applied last; ``text``
    is the file's text when it is not read from disk (an editor's unsaved buffer); ``loaded`` is
    what :func:`load_files` returned for it, when the caller has parsed it already.
    """
    if loaded is not None:
        files, sources, diagnostics = list(loaded[0]), dict(loaded[1]), list(loaded[2])
    else:
        files, sources, diagnostics = load_files(path, text)
    for assignment in sets:
        if assignment.source is not None:
            sources[assignment.source.name] = assignment.source
    graph, more = _build(files, sources, model, experiment, sets)
    diagnostics = _unique(diagnostics + more)
    if graph is None or any(d.is_error for d in diagnostics):
        raise ModelError([d for d in diagnostics if d.is_error], sources)
    return graph, diagnostics

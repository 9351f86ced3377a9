"""What every check of the semantic stage shares.

Takes the parsed files and the chosen ``ast.Model``; holds them in :class:`CheckContext` with the
model's declarations (:func:`declare`: one namespace of parameters, inputs, outputs, states,
elements, junctions, functions and bond labels), its numbered bonds and ends, its elements'
laws and the diagnostics collected so far. The checks read and fill a ``CheckContext``; nothing here
reports a problem itself. Also the small helpers that word diagnostics (``error_at``, hints).
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence, TypeVar, Union

from bondc import ast, builtins, units
from bondc.errors import Diagnostic, Hint, Related
from bondc.evaluate import ExpansionBudget
from bondc.kinds import JUNCTION_KINDS, KINDS
from bondc.model import Bond
from bondc.source import Source, Span


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

BOND_NUMBER = re.compile(r"b([0-9]+)")


def a_or_an(noun: str) -> str:
    """The noun with its article: "an input", "a C", "an R", "an MSe" (letters as spoken)."""
    first = noun[:1]
    vowel = first in "aeiou" if first.islower() else first in "AEFHILMNORSX"
    return f"{'an' if vowel else 'a'} {noun}"


def quoted(names: Iterable[str]) -> str:
    return ", ".join(f"'{n}'" for n in names)


def did_you_mean(name: str, candidates: Iterable[str]) -> str | None:
    """``"did you mean 'x'?"`` for the closest candidate, or None."""
    candidates = sorted(set(candidates))
    same_case = [c for c in candidates if c.lower() == name.lower() and c != name]
    found = same_case or difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return Hint(f"did you mean '{found[0]}'?", (found[0],)) if found else None


def join_hints(*hints: str | None) -> str | None:
    parts = [h for h in hints if h]
    return Hint.join(parts) if parts else None


def error_at(code: str, message: str, span: Span, hint: str | None = None,
             related: Sequence[Related] = ()) -> Diagnostic:
    return Diagnostic("error", code, message, span, hint=hint, related=tuple(related),
                      suggestions=getattr(hint, "suggestions", ()))


def warning_at(code: str, message: str, span: Span, hint: str | None = None,
               related: Sequence[Related] = ()) -> Diagnostic:
    return Diagnostic("warning", code, message, span, hint=hint, related=tuple(related),
                      suggestions=getattr(hint, "suggestions", ()))


def file_span(name: str) -> Span:
    """A span naming only a file (rendered ``file: error...`` without source lines)."""
    return Span(name, 0, 0, 0, 0)


# ============================================================== declarations

#: A statement that declares a name.
Declaration = Union[ast.Param, ast.Input, ast.Output, ast.StateDecl, ast.Discrete, ast.FnDef, ast.Element,
                    ast.Junction, ast.BondChain]
_Statement = TypeVar("_Statement")


@dataclass(frozen=True)
class Decl:
    """One name the model defines, in its single namespace."""

    category: str       # parameter input output state element junction function "bond label"
    name: str
    span: Span          # the name as written
    node: Declaration


@dataclass
class Definition:
    """How a parameter gets its value: its declaration, or an override of it."""

    name: str
    expr: ast.Expr
    unit: ast.Unit | None
    span: Span                      # the statement that gives this value
    declared_unit: ast.Unit | None  # the declaration's unit (a bare-number override is read in it)
    origin: str                     # "declaration", "experiment 'x'", "--set"


@dataclass
class CheckContext:
    """Everything the checks share about the model being built."""

    file: ast.File
    sources: Mapping[str, Source]
    model: ast.Model
    files: tuple[ast.File, ...]
    diagnostics: list[Diagnostic] = field(default_factory=list)
    decls: dict[str, Decl] = field(default_factory=dict)
    all_decls: list[Decl] = field(default_factory=list)
    file_functions: dict[str, ast.FnDef] = field(default_factory=dict)
    functions: dict[str, ast.FnDef] = field(default_factory=dict)
    bad_functions: set[str] = field(default_factory=set)
    bonds: list[Bond] = field(default_factory=list)
    ends: dict[str, list["BondEnd"]] = field(default_factory=dict)
    ports: dict[str, tuple[tuple[int, int], tuple[int, int]]] = field(default_factory=dict)
    element_laws: dict[str, "ElementLaws"] = field(default_factory=dict)
    model_states: dict[str, "StateLaws"] = field(default_factory=dict)
    units: dict[int, units.SIUnit | None] = field(default_factory=dict)
    expr_ok: dict[int, bool] = field(default_factory=dict)
    used: set[str] = field(default_factory=set)
    csv_headers: dict[str, list[str] | str | None] = field(default_factory=dict)   # str: why unreadable
    misspelt: set[str] = field(default_factory=set)   # nodes a misspelt bond endpoint probably meant
    bindings: list = field(default_factory=list)       # flatten.Binding: instances' parameter values
    good_bindings: list = field(default_factory=list)  # those that fit their parameter
    instances: list = field(default_factory=list)      # flatten.Instance: the instance tree
    by_kind: dict = field(default_factory=dict, repr=False)     # statements(): kind -> statements
    # every division by parameters alone: (divisor, parameter names), for BondGraph.divisors
    divisors: tuple[tuple[ast.Expr, tuple[str, ...]], ...] = ()
    # what evaluating the constants may spend on expanding fn calls (E319)
    budget: ExpansionBudget = field(default_factory=ExpansionBudget, repr=False)

    def report(self, diagnostic: Diagnostic) -> None:
        self.diagnostics.append(diagnostic)

    # The model's statements by type, in order (each kind sorted out once: the checks ask ~60
    # times, and a 10000-section chain has 120000 statements).
    def statements(self, kind: type[_Statement]) -> list[_Statement]:
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
        return decl.node if decl is not None and isinstance(decl.node, ast.Element) else None

    def known_kind(self, name: str) -> str | None:
        """The kind of element ``name`` if it is an element of a known kind."""
        element = self.element(name)
        return element.kind if element is not None and element.kind in KINDS else None

    def junction_kind(self, name: str) -> str | None:
        decl = self.decls.get(name)
        if decl is None or not isinstance(decl.node, ast.Junction):
            return None
        return decl.node.kind if decl.node.kind in JUNCTION_KINDS else None


def input_value(item: ast.Input) -> ast.Expr:
    """An input's signal or default: flattening gives every input of the model one (0 for an
    external input written without a default), so None does not reach the checks."""
    return item.value if item.value is not None else ast.Num(0.0, "0", item.name_span)


#: The category of the one name each of these statements declares.
_CATEGORY: Mapping[type, str] = {
    ast.Param: "parameter", ast.Input: "input", ast.Output: "output", ast.StateDecl: "state",
    ast.Discrete: "discrete", ast.FnDef: "function", ast.Element: "element",
}


def declare(m: CheckContext) -> None:
    """Fill the model's one namespace: file-level functions, then the model's own names."""
    for file in m.files:
        for function in file.functions:
            _add_decl(m, Decl("function", function.name, function.name_span, function))
            m.file_functions.setdefault(function.name, function)
    for statement in m.model.body:
        if isinstance(statement, (ast.Param, ast.Input, ast.Output, ast.StateDecl, ast.Discrete, ast.FnDef,
                                  ast.Element)):
            _add_decl(m, Decl(_CATEGORY[type(statement)], statement.name, statement.name_span, statement))
        elif isinstance(statement, ast.Junction):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for name, span in zip(statement.names, spans):
                _add_decl(m, Decl("junction", name, span, statement))
        elif isinstance(statement, ast.BondChain) and statement.label is not None:
            _add_decl(m, Decl("bond label", statement.label, statement.label_span, statement))
    m.functions = {d.name: d.node for d in m.decls.values() if isinstance(d.node, ast.FnDef)}


def _add_decl(m: CheckContext, decl: Decl) -> None:
    m.all_decls.append(decl)
    m.decls.setdefault(decl.name, decl)


@dataclass(frozen=True)
class BondEnd:
    """One end of a bond at a node."""

    bond: int
    side: str           # "tail" (power leaves the node) or "head" (power enters it)
    port: str | None    # the port as written, if any
    span: Span          # the endpoint as written


@dataclass
class ElementLaws:
    """An element's laws sorted out: what the expression checks and the graph need."""

    assigns: dict[str, ast.LawAssign] = field(default_factory=dict)
    custom: dict[str, ast.LawState] = field(default_factory=dict)
    initials: dict[str, ast.LawCall] = field(default_factory=dict)
    rates: dict[str, ast.LawCall] = field(default_factory=dict)
    state_names: tuple[str, ...] = ()


@dataclass
class StateLaws:
    initial: ast.LawCall | None = None
    rate: ast.LawCall | None = None

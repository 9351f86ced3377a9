"""The plan of a generated module: a :class:`~bondc.statespace.StateSpace` -> a :class:`_Plan`
(:func:`_plan`): its laws frozen at their discontinuities (:mod:`bondc.codegen.freeze`), in causal
order as statements, with the derived parameters, switches, events and, unless asked not to, the
forward-mode Jacobian (:mod:`bondc.codegen.jacobian`); :func:`switch_kinds` lists its switches.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from sympy.printing.str import StrPrinter

from bondc.codegen.freeze import Freezer
from bondc.codegen.jacobian import _forward_jacobian
from bondc.codegen.printer import QuickPrinting, negatives_last
from bondc.codegen.statements import _assign, _Statement

if TYPE_CHECKING:
    from bondc.statespace import StateSpace


_LAW_LIMIT = 200


@dataclass
class _Plan:
    """Everything :func:`emit` prints, decided before printing."""

    ss: StateSpace
    states: list
    parameters: list                 # [(name, symbol, value)]
    statements: list                 # frozen assignments and blocks, causal order
    variables: list                  # [(name, symbol, law text)] every assigned symbol and block unknown
    derivatives: list                # frozen, in state order
    outputs: list                    # [(name, frozen expr)]
    switches: list
    time_breaks: list
    derived: list = field(default_factory=list)    # [(name, expr of other parameters)] in declaration order
    events: list = field(default_factory=list)     # [(label, frozen condition, [(state index, frozen value)])]
    jacobian_statements: list = field(default_factory=list)
    jacobian_entries: dict = field(default_factory=dict)   # (row, column) -> expr
    blocks: int = 0
    freezer: Freezer | None = None                 # the Freezer that froze the laws (its kinks)


def _derived_parameters(ss) -> list:
    """Parameters defined by other parameters (``Ar = pi/4*(D^2 - d^2)``), as sympy, in declaration order.

    The generated module recomputes them when ``p`` overrides what they depend on.
    """
    from bondc.errors import EquationError
    from bondc.symbolic import Translator

    graph = getattr(ss, "graph", None)
    declared = getattr(graph, "parameters", None)
    if not declared:
        return []
    symbols = {name: symbol for name, (symbol, _) in ss.parameters.items()}

    def resolve(name, node):
        if name in symbols:
            return symbols[name]
        raise EquationError(f"'{name}' is not a parameter")     # the translator falls back for pi

    translator = Translator(resolve, functions=getattr(graph, "functions", {}), time=ss.time)
    derived = []
    for name, parameter in declared.items():
        if name not in symbols:
            continue
        try:
            expr = translator(parameter.expr)
        except Exception:       # not expressible here (a csv value, ...): keep its number
            continue
        if expr.free_symbols and expr.free_symbols <= set(symbols.values()):
            derived.append((name, expr))
    return derived


def _switch_depends(plan: _Plan) -> list:
    """For each switch, the modes its frozen switching function reads (through the laws it uses)."""
    index = {s.mode: s.index for s in plan.switches}
    closure: dict = {}

    def modes_of(exprs):
        found = set()
        for expr in exprs:
            for symbol in expr.free_symbols:
                if symbol in index:
                    found.add(index[symbol])
                elif symbol in closure:
                    found |= closure[symbol]
        return found

    for statement in plan.statements:
        exprs = statement.exprs if statement.kind == "assign" else statement.data["residuals"]
        found = modes_of(exprs)
        for symbol in statement.defines:
            closure[symbol] = found
    return [sorted(modes_of([s.g]) - {s.index}) for s in plan.switches]


class _LawPrinter(QuickPrinting, StrPrinter):
    """sympy's str printer, with sums in sympy's argument order and negative terms last
    ("q - 1"): sorting the terms of every sum for display is most of a large model's printing."""

    _default_settings = {**StrPrinter._default_settings, "order": "none"}

    def _as_ordered_terms(self, expr, order=None):
        return negatives_last(expr)

    def _quick_name(self, symbol):
        return symbol.name


_LAW_PRINTER = _LawPrinter()


def _law_text(expr) -> str:
    text = _LAW_PRINTER.quick(expr) or _LAW_PRINTER.doprint(expr)
    return text if len(text) <= _LAW_LIMIT else text[: _LAW_LIMIT - 3] + "..."


def switch_kinds(ss) -> list[tuple[str, str, str]]:
    """Every switch of a model's laws as the engine treats it (LANGUAGE.md section 7), as
    ``(switch, kind, variable)``: a ``jump`` (located as an event, its law frozen on a branch
    between events; ``jump (known times)`` when its instants are found before integrating) or a
    ``kink`` (the law continuous across it: evaluated as written, never frozen), and the variable
    whose law has it; jumps first, each in the order the laws are frozen.

    >>> from bondc.pipeline import derive_file
    >>> from pathlib import Path
    >>> root = Path(__file__).resolve().parent.parent.parent
    >>> switch_kinds(derive_file(root / "tests" / "fixtures" / "engine" / "relief_valve.bg", cache=False).state_space)
    [('if b4.e > pr', 'kink', 'b4.f')]
    """
    freezer = _plan(ss, jacobian=False).freezer
    assert freezer is not None      # (_plan sets it)
    rows = [(switch.label.removesuffix(f" in {switch.owner}"), "jump" if switch.event else "jump (known times)",
             switch.owner) for switch in freezer.switches if switch.event or switch.breaks]
    return rows + [(kink.label, "kink", kink.owner) for kink in freezer.kinks]


def _plan(ss, jacobian: bool = True) -> _Plan:
    states = list(ss.states)
    state_symbols = [s.symbol for s in states]
    parameters = [(name, symbol, float(value)) for name, (symbol, value) in ss.parameters.items()]
    freezer = Freezer(ss.time, state_symbols, [symbol for _, symbol, _ in parameters])
    blocks_at: dict[int, list] = {}
    for number, block in enumerate(ss.algebraic_blocks):
        blocks_at.setdefault(block.index, []).append((number, block))
    statements, variables = [], []

    def add_blocks(position):
        for number, block in blocks_at.get(position, ()):
            owner = "algebraic loop " + ", ".join(block.nodes or (str(u) for u in block.unknowns))
            residuals = [freezer.freeze(r, owner) for r in block.residuals]
            unknowns = tuple(block.unknowns)
            uses = frozenset().union(*(r.free_symbols for r in residuals), *(g.free_symbols for g in block.guesses))
            statements.append(_Statement("block", unknowns, [], uses - set(unknowns),
                                         {"number": number, "residuals": residuals, "guesses": list(block.guesses)}))
            for unknown in unknowns:    # not defined to the freezer: never of time only
                variables.append((unknown.name, unknown, f"root of the {owner}"))

    for position, (symbol, expr) in enumerate(ss.assignments):
        add_blocks(position)
        frozen = freezer.freeze(expr, symbol.name)
        freezer.define(symbol, frozen)
        statements.append(_assign(symbol, frozen))
        variables.append((symbol.name, symbol, _law_text(expr)))
    add_blocks(len(ss.assignments))
    derivatives = [freezer.freeze(ss.derivatives[s.name], f"der({s.name})") for s in states]
    outputs = [(name, freezer.freeze(expr, f"output {name}")) for name, expr in ss.outputs.items()]
    state_index = {s.name: i for i, s in enumerate(states)}
    events = []
    for label, condition, actions in getattr(ss, "events", ()):
        frozen = freezer.freeze(condition, label)
        events.append((label, frozen, [(state_index[name], freezer.freeze(value, label)) for name, value in actions]))
    plan = _Plan(ss, states, parameters, statements, variables, derivatives, outputs, freezer.switches,
                 freezer.time_breaks, blocks=len(ss.algebraic_blocks), derived=_derived_parameters(ss),
                 events=events, freezer=freezer)
    if jacobian:
        _forward_jacobian(plan, state_symbols)
    return plan

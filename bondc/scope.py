"""The names of a checked model: every declaration and every use, with its span (issue 11).

The semantic stage builds one :class:`Scope` per model, on the flattened model
(names inside components are dotted, their spans point into the component's
file and carry the instance path), and keeps it on the graph
(``BondGraph.scope``). The equations stage resolves names through it, and
editor tools find definitions and references in it.

>>> from bondc.parse import parse_text
>>> from bondc.semantic import build
>>> text = "model M\\n  param k = 2\\n  Se s : e = k\\n  C c : e = k*q\\n  s -> c\\nend\\n"
>>> graph, _ = build(parse_text(text, "m.bg"))
>>> graph.scope.category("k"), [u.span.line for u in graph.scope.uses_of("k")]
('parameter', [3, 4])
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Protocol

from bondc import ast
from bondc.source import Span

#: An element's own variables inside its laws: never a use of a model's name.
_OWN = frozenset({"e", "f"})


@dataclass(frozen=True)
class Declaration:
    name: str
    category: str        # parameter input output state discrete function element junction "bond label"
    span: Span           # the name as written


class Declared(Protocol):
    """What :func:`build_scope` reads of a declaration (semantic's ``_Decl``)."""

    @property
    def name(self) -> str: ...

    @property
    def category(self) -> str: ...

    @property
    def span(self) -> Span: ...


@dataclass(frozen=True)
class Use:
    name: str            # the declaration it names (a dotted reference: its element, junction or bond)
    span: Span           # the name (or the whole dotted reference) as written


@dataclass(frozen=True)
class Scope:
    declarations: Mapping[str, Declaration] = field(default_factory=dict)
    uses: tuple[Use, ...] = ()

    def category(self, name: str) -> str | None:
        declaration = self.declarations.get(name)
        return declaration.category if declaration is not None else None

    def uses_of(self, name: str) -> list[Use]:
        return [use for use in self.uses if use.name == name]

    def at(self, file: str, line: int, column: int) -> Declaration | None:
        """The declaration named (or declared) at a 1-based position of ``file``."""
        def inside(span):
            return span.file == file and (span.line, span.column) <= (line, column) <= (span.end_line,
                                                                                         span.end_column)
        for use in self.uses:
            if inside(use.span):
                return self.declarations.get(use.name)
        for declaration in self.declarations.values():
            if inside(declaration.span):
                return declaration
        return None


def build_scope(model: ast.Model, declarations: Iterable[Declared]) -> Scope:
    """The scope of a (flattened) model from its declarations (semantic's ``_Decl`` list)."""
    known: dict[str, Declaration] = {}
    uses: list[Use] = []
    for decl in declarations:
        known.setdefault(decl.name, Declaration(decl.name, decl.category, decl.span))

    def walk(expr, local=frozenset()):
        for node in ast.walk(expr):
            if isinstance(node, ast.Name) and node.name not in local and node.name in known:
                uses.append(Use(node.name, node.span))
            elif isinstance(node, ast.Ref) and node.parts[0] in known and node.parts[0] not in local:
                uses.append(Use(node.parts[0], node.span))
            elif isinstance(node, ast.Call) and node.func in known:
                uses.append(Use(node.func, node.func_span))

    for statement in model.body:
        if isinstance(statement, (ast.Param, ast.Input, ast.Output, ast.Discrete)):
            if statement.value is not None:
                walk(statement.value)
        elif isinstance(statement, (ast.Element, ast.StateDecl)):
            own = _OWN | {law.name for law in statement.laws if isinstance(law, ast.LawState)}
            if isinstance(statement, ast.Element):
                own |= {"q", "p"}
            for law in statement.laws:
                if isinstance(law, ast.LawAssign):
                    walk(law.value, own)
                elif isinstance(law, ast.LawCall):
                    walk(law.value, own)
                    walk(law.arg, own)
        elif isinstance(statement, ast.FnDef):
            walk(statement.body, frozenset(statement.params))
        elif isinstance(statement, ast.BondChain):
            for end in statement.endpoints:
                if end.name in known:
                    uses.append(Use(end.name, end.span))
        elif isinstance(statement, ast.When):
            walk(statement.condition)
            for action in statement.actions:
                if isinstance(action, ast.WhenAssign):
                    if action.name in known:
                        uses.append(Use(action.name, action.name_span))
                    walk(action.value)
                else:
                    for argument in action.args:
                        walk(argument)
        elif isinstance(statement, ast.Experiment):
            for item in statement.body:
                if isinstance(item, (ast.Param, ast.Input)):
                    if item.name in known:
                        uses.append(Use(item.name, item.name_span))
                    walk(item.value)
                elif isinstance(item, ast.Setting):
                    walk(item.value)
    return Scope(known, tuple(uses))

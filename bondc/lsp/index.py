"""What a document declares and uses, for hover, definition, references, rename and completion.

The index is built from the parsed files of an analysis (the document first, then what it
imports); names are found through a table by (name, model), and the uses on a line through a
table by line, so that a request on a 5 000-line model looks at a handful of entries.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bondc import ast
from bondc.kinds import JUNCTIONS, KINDS
from bondc.lsp.positions import contains

@dataclass
class Symbol:
    name: str
    category: str             # parameter element junction input output state function model port ...
    span: object              # the name as written
    statement: object         # its AST statement (for hover)
    model: str | None         # the model it belongs to (None: file level)
    file: str


@dataclass
class Use:
    name: str                 # the name used (its first part for dotted references)
    span: object
    model: str | None
    parts: tuple[str, ...] = ()
    part_spans: tuple = ()
    call: bool = False        # a function called by this name: an fn (or a built-in), nothing else


@dataclass
class Index:
    symbols: list[Symbol] = field(default_factory=list)
    uses: list[Use] = field(default_factory=list)
    models: dict[str, tuple[ast.Model, str]] = field(default_factory=dict)   # every model: (model, file)
    by_name: dict[tuple[str, str | None], Symbol] = field(default_factory=dict)   # (name, model): the first
    by_line: dict[tuple[str, int], list] = field(default_factory=dict)     # (file, 0-based line): uses, symbols
    functions: dict[tuple[str, str | None], Symbol] = field(default_factory=dict)   # fn (name, model)
    imports: list[tuple[ast.Import, str]] = field(default_factory=list)             # (import, its file)

    def finish(self) -> "Index":
        """The lookup tables, once every symbol and use is in."""
        for symbol in self.symbols:
            self.by_name.setdefault((symbol.name, symbol.model), symbol)
            if symbol.category == "function":
                self.functions.setdefault((symbol.name, symbol.model), symbol)
        for item in self.uses + self.symbols:
            span = item.span
            for line in range(span.line - 1, max(span.end_line, span.line)):
                self.by_line.setdefault((span.file, line), []).append(item)
        return self

    def declared(self, name: str, model: str | None) -> Symbol | None:
        return self.by_name.get((name, model)) or self.by_name.get((name, None))


def _ref_parts(node: ast.Ref) -> tuple:
    """Spans of each part of a dotted reference (``valve.loss.f``)."""
    spans, column, offset = [], node.span.column, node.span.start
    for part in node.parts:
        spans.append(type(node.span)(node.span.file, node.span.line, column, node.span.line, column + len(part),
                                     offset, offset + len(part)))
        column += len(part) + 1
        offset += len(part) + 1
    return tuple(spans)


def build_index(files) -> Index:
    index = Index()
    for file in files:
        for item in file.items:
            if isinstance(item, ast.FnDef):
                index.symbols.append(Symbol(item.name, "function", item.name_span, item, None, file.path))
                _uses_in(index, item.body, None, item.params)
            elif isinstance(item, ast.Import):
                index.imports.append((item, file.path))
            elif isinstance(item, ast.Model):
                index.models[item.name] = (item, file.path)
                index.symbols.append(Symbol(item.name, "model", item.name_span, item, None, file.path))
                _index_model(index, item, file.path)
    return index.finish()


def _index_model(index: Index, model: ast.Model, path: str) -> None:
    name = model.name

    def add(symbol_name, category, span, statement):
        index.symbols.append(Symbol(symbol_name, category, span, statement, name, path))

    def uses_in(expr, local=()):
        _uses_in(index, expr, name, local)

    for statement in model.body:
        if isinstance(statement, (ast.Param, ast.Input, ast.Output, ast.Discrete)):
            category = {ast.Param: "parameter", ast.Input: "input", ast.Output: "output",
                        ast.Discrete: "discrete"}[type(statement)]
            add(statement.name, category, statement.name_span, statement)
            if statement.value is not None:
                uses_in(statement.value)
        elif isinstance(statement, ast.StateDecl):
            add(statement.name, "state", statement.name_span, statement)
            for law in statement.laws:
                if isinstance(law, ast.LawCall) and law.func != "der":      # x(0) = ...: the state itself
                    index.uses.append(Use(law.func, law.func_span, name))
                for expr in (getattr(law, "value", None), getattr(law, "arg", None)):
                    if expr is not None:
                        uses_in(expr)
        elif isinstance(statement, ast.FnDef):
            add(statement.name, "function", statement.name_span, statement)
            uses_in(statement.body, statement.params)
        elif isinstance(statement, ast.Element):
            category = "element" if statement.kind in KINDS else "instance"
            add(statement.name, category, statement.name_span, statement)
            if category == "instance":
                component = statement.kind.rpartition(".")[2]
                index.uses.append(Use(component, _tail(statement.kind_span, component), None))
                for law in statement.laws:      # a binding's target: the component's parameter or input
                    if isinstance(law, ast.LawAssign):
                        index.uses.append(Use(law.target, law.target_span, component))
            for law in statement.laws:
                for expr in (getattr(law, "value", None), getattr(law, "arg", None)):
                    if expr is not None:
                        uses_in(expr)
        elif isinstance(statement, ast.Junction):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for junction, span in zip(statement.names, spans):
                add(junction, "junction", span, statement)
        elif isinstance(statement, ast.PortDecl):
            spans = statement.name_spans or (statement.span,) * len(statement.names)
            for port, span in zip(statement.names, spans):
                add(port, "port", span, statement)
        elif isinstance(statement, ast.BondChain):
            if statement.label:
                add(statement.label, "bond label", statement.label_span, statement)
            for end in statement.endpoints:
                span = end.span
                width = len(end.name)
                name_span = type(span)(span.file, span.line, span.column, span.line, span.column + width,
                                       span.start, span.start + width)
                spans = (name_span,)
                if end.port and span.line == span.end_line and span.end_column - span.column > width + len(end.port):
                    column = span.column + width + 1
                    spans += (type(span)(span.file, span.line, column, span.line, column + len(end.port),
                                         span.start + width + 1, span.start + width + 1 + len(end.port)),)
                index.uses.append(Use(end.name, name_span, name, (end.name,) + ((end.port,) if end.port else ()),
                                      spans))
        elif isinstance(statement, ast.When):
            uses_in(statement.condition)
            for action in statement.actions:
                for expr in ([action.value] if isinstance(action, ast.WhenAssign) else list(action.args)):
                    uses_in(expr)
        elif isinstance(statement, ast.Experiment):
            add(statement.name, "experiment", statement.name_span, statement)
            for item in statement.body:
                if isinstance(item, (ast.Param, ast.Input)):
                    index.uses.append(Use(item.name, item.name_span, name))
                    uses_in(item.value)



def _uses_in(index: Index, expr, model: str | None, local=()) -> None:
    """The names, dotted names and calls in ``expr`` (``local``: a function's own parameters, no uses)."""
    for node in ast.walk(expr):
        if isinstance(node, ast.Name):
            if node.name not in local:
                index.uses.append(Use(node.name, node.span, model))
        elif isinstance(node, ast.Ref):
            index.uses.append(Use(node.parts[0], node.span, model, node.parts, _ref_parts(node)))
        elif isinstance(node, ast.Call):
            index.uses.append(Use(node.func, node.func_span, model, call=True))


def _tail(span, name: str):
    """The last ``len(name)`` characters of a one-line span (``Orifice`` of ``lib.Orifice``)."""
    if span.line != span.end_line or span.end_column - span.column <= len(name):
        return span
    return type(span)(span.file, span.line, span.end_column - len(name), span.end_line, span.end_column,
                      span.end - len(name), span.end)


def at(index: Index | None, file: str, line: int, column: int):
    """The use or declaration at 0-based (line, column, in characters) of ``file``: (Symbol or
    None, Use or None, part index)."""
    if index is None:
        return None, None, 0
    items = index.by_line.get((file, line), ())
    for use in items:
        if not isinstance(use, Use):
            continue
        if use.part_spans:
            for number, span in enumerate(use.part_spans):
                if contains(span, line, column):
                    return None, use, number
        elif contains(use.span, line, column):
            return None, use, 0
    for symbol in items:
        if isinstance(symbol, Symbol) and contains(symbol.span, line, column):
            return symbol, None, 0
    return None, None, 0


def resolve(index: Index, use: Use, part: int = 0) -> Symbol | None:
    """The declaration a use names; through instances for a dotted name."""
    model = use.model
    if use.call:        # step(...) is the built-in even where an experiment or a parameter is named step
        return index.functions.get((use.name, model)) or index.functions.get((use.name, None))
    if part == 0 or not use.parts:
        return index.declared(use.name, model)
    symbol = index.declared(use.parts[0], model)
    for number in range(1, part + 1):
        if symbol is None or symbol.category != "instance":
            return None
        kind = symbol.statement.kind.rpartition(".")[2]
        symbol = index.by_name.get((use.parts[number], kind))
    return symbol


def element_members(statement: ast.Element) -> list[str]:
    """The variables ``NAME.x`` an element has, as bondc.semantic resolves them: a two-port's
    ``p1.e`` ... ``p2.f``; a one-port's ``e``, ``f`` and its states (the ones its laws declare,
    else its kind's own: ``q`` of a C, ``p`` of an I)."""
    kind = KINDS[statement.kind]
    if kind.ports == 2:
        from bondc.model import PORT_NAMES

        return [f"{port}.{variable}" for port in PORT_NAMES for variable in "ef"]
    declared = [law.name for law in statement.laws if isinstance(law, ast.LawState)]
    return ["e", "f"] + (declared or ([kind.state] if kind.storage else []))


#: What ``INSTANCE.x`` may name in an expression (flatten.py's member lookup): its values, its
#: elements, junctions and bond labels, and its instances; its ports only in a bond.
VALUE_MEMBERS = ("parameter", "input", "output", "state", "discrete", "element", "junction", "bond label",
                 "instance")


def members(index: Index, parts: list[str], model: str | None, bond: bool) -> list[tuple[str, str]]:
    """(name, what) of each member of the dotted name ``parts`` in ``model``: what may follow
    ``parts.`` (``bond``: in a bond statement, where an instance's ports are named)."""
    symbol = index.declared(parts[0], model)
    for part in parts[1:]:
        if symbol is None or symbol.category != "instance":
            return []
        symbol = index.by_name.get((part, symbol.statement.kind.rpartition(".")[2]))
    if symbol is None:
        return []
    if symbol.category == "instance":
        inner = symbol.statement.kind.rpartition(".")[2]
        wanted = ("port",) if bond else VALUE_MEMBERS
        seen: dict[str, str] = {}
        for s in index.symbols:
            if s.model == inner and s.category in wanted:
                seen.setdefault(s.name, s.category)
        return sorted(seen.items())
    if symbol.category == "element" and symbol.statement.kind in KINDS:
        if bond and KINDS[symbol.statement.kind].ports == 2:
            from bondc.model import PORT_NAMES

            return [(port, "port") for port in PORT_NAMES]
        return [(name, "state" if name not in ("e", "f") and "." not in name else
                 "effort" if name.endswith("e") else "flow") for name in element_members(symbol.statement)]
    if symbol.category == "junction":
        junction = JUNCTIONS.get(symbol.statement.kind)
        return [(junction.common, f"common {junction.common_word}")] if junction else [("f", "common flow")]
    if symbol.category == "bond label":
        return [("e", "effort"), ("f", "flow")]
    return []

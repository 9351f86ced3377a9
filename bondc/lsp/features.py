"""What the server answers from an :class:`~bondc.lsp.analysis.Analysis`: hover, completion,
definition and references, rename, quick fixes, the outline. Pure functions of the analysis
(no server state), each a lookup in its index: they answer at once whatever is being analysed.
"""

from __future__ import annotations

import re

from lsprotocol import types as lsp

from bondc import ast
from bondc.builtins import BUILTINS
from bondc.lsp.analysis import Analysis
from bondc.lsp.index import Symbol, at, members, resolve
from bondc.kinds import KINDS

KEYWORDS = ("model", "end", "param", "input", "output", "state", "fn", "experiment", "import", "if", "then",
            "else", "and", "or", "not", "port", "defaults", "discrete", "when", "external")


def cursor(analysis: Analysis, position: lsp.Position) -> tuple[int, int]:
    """A client's position as 0-based (line, column in characters) of the analysed text."""
    return position.line, analysis.lines.character(position.line, position.character)


def at_cursor(analysis: Analysis, position: lsp.Position):
    """(Symbol or None, Use or None, part) under the cursor."""
    line, column = cursor(analysis, position)
    return at(analysis.index, str(analysis.path), line, column)


def symbol_at(analysis: Analysis, position: lsp.Position) -> Symbol | None:
    symbol, use, part = at_cursor(analysis, position)
    if symbol is not None:
        return symbol
    return resolve(analysis.index, use, part) if use is not None else None


def location(analysis: Analysis, symbol: Symbol) -> lsp.Location:
    return analysis.positions.location(symbol.span)


def scoped(analysis: Analysis, position: lsp.Position):
    """The declaration at the cursor from the checked model's own scope (bondc.scope), or None."""
    scope = getattr(analysis.graph, "scope", None)
    if scope is None:
        return None, None
    line, column = cursor(analysis, position)
    return scope, scope.at(str(analysis.path), line + 1, column + 1)


def definition(analysis: Analysis, position: lsp.Position):
    if analysis.index is not None:
        _, use, _ = at_cursor(analysis, position)
        if use is not None and use.call:        # a call: an fn, or a built-in (no definition to go to)
            symbol = resolve(analysis.index, use)
            return location(analysis, symbol) if symbol is not None else None
    _, declaration = scoped(analysis, position)
    if declaration is not None:
        return analysis.positions.location(declaration.span)
    symbol = symbol_at(analysis, position) if analysis.index is not None else None
    return location(analysis, symbol) if symbol is not None else None


def occurrences(analysis: Analysis, symbol: Symbol, file: str | None = None):
    """The spans of every use of ``symbol`` (in ``file`` only, if given)."""
    for use in analysis.index.uses:
        if file is not None and use.span.file != file:
            continue
        for part in range(len(use.part_spans) or 1):
            if resolve(analysis.index, use, part) is symbol:
                yield use.part_spans[part] if use.part_spans else use.span


def references(analysis: Analysis, position: lsp.Position, include_declaration: bool):
    positions = analysis.positions
    scope, declaration = scoped(analysis, position)
    if declaration is not None:
        found = [positions.location(declaration.span)] if include_declaration else []
        return found + [positions.location(use.span) for use in scope.uses_of(declaration.name)]
    symbol = symbol_at(analysis, position) if analysis.index is not None else None
    if symbol is None:
        return []
    found = [location(analysis, symbol)] if include_declaration else []
    return found + [positions.location(span) for span in occurrences(analysis, symbol)]


# ------------------------------------------------------------------ hover

def _expr(expr) -> str:
    from bondc.fmt import format_expr

    return format_expr(expr)


def _signature(fn: ast.FnDef) -> str:
    return f"fn {fn.name}({', '.join(fn.params)}) = {_expr(fn.body)}"


def _causality(analysis: Analysis, name: str) -> str | None:
    causal = analysis.causal
    if causal is None or name not in analysis.graph.elements:
        return None
    derivative = name in causal.summary().get("derivative_storage", [])
    parts = [f"bond {bond}: effort set by {causal.effort_setter.get(bond, '?')}"
             for bond in analysis.graph.elements[name].bonds]
    return "; ".join(parts) + (" (derivative causality)" if derivative else "")


def hover_text(analysis: Analysis, symbol: Symbol) -> str:
    from bondc.fmt import format_law, unit_text

    statement = symbol.statement
    graph = analysis.graph
    lines = []
    if symbol.category == "parameter":
        written = f"{_expr(statement.value)}" + (f" {unit_text(statement.unit)}" if statement.unit else "")
        lines.append(f"**param {symbol.name}** = {written}")
        if graph is not None and symbol.name in graph.parameters:
            lines.append(f"SI value: `{graph.parameters[symbol.name].value:.6g}`")
        if statement.description:
            lines.append(statement.description)
    elif symbol.category == "element":
        kind = KINDS[statement.kind]
        lines.append(f"**{statement.kind} {symbol.name}** — {kind.description}")
        if statement.description:
            lines.append(statement.description)
        lines += [f"`{format_law(law)}`" for law in statement.laws]
        if graph is not None and symbol.name in graph.elements:
            element = graph.elements[symbol.name]
            bonds = ", ".join(str(b) for b in element.bonds)
            lines.append(f"bonds: {bonds}" + (f"; states: {', '.join(s.qualified for s in element.states)}"
                                              if element.states else ""))
            causality = _causality(analysis, symbol.name)
            if causality:
                lines.append(causality)
    elif symbol.category in ("instance", "model"):
        model_name = statement.kind.rpartition(".")[2] if symbol.category == "instance" else symbol.name
        found = analysis.index.models.get(model_name)
        if found is not None:
            lines += _component(found[0])
            if symbol.category == "instance" and statement.laws:
                lines.append("bound: " + ", ".join(format_law(law) for law in statement.laws))
    elif symbol.category == "function":
        lines.append(f"```\n{_signature(statement)}\n```")
        if statement.description:
            lines.append(statement.description)
        where = "file level" if symbol.model is None else f"model {symbol.model}"
        lines.append(f"function ({where}, {symbol.file})")
    else:
        text = getattr(statement, "description", None)
        lines.append(f"**{symbol.category} {symbol.name}**" + (f" — {text}" if text else ""))
        value = getattr(statement, "value", None)
        if isinstance(value, (ast.Num, ast.Binary, ast.Call, ast.Name, ast.Ref, ast.If, ast.Unary)):
            lines.append(f"`{_expr(value)}`")
    return "\n\n".join(lines)


def _component(model: ast.Model) -> list[str]:
    from bondc.flatten import ports_of

    lines = [f"**{model.name}**" + (f" — {model.description}" if model.description else "")]
    ports = ports_of(model)
    if ports:
        lines.append(f"ports: {', '.join(ports)}")
    params = [s for s in model.body if isinstance(s, ast.Param)]
    if params:
        lines.append("parameters: " + ", ".join(f"{p.name}" + (f" [{p.unit.text}]" if p.unit else "")
                                                for p in params))
    return lines


def _import_text(analysis: Analysis, item: ast.Import) -> str:
    """What an import brings: the library's leading comment and each model, its ports and description."""
    import os

    # the name the loader gives the file (semantic.load_files): std:NAME, or the path from the importer's
    name = item.path if item.path.startswith("std:") else os.path.normpath(
        os.path.join(os.path.dirname(str(analysis.path)), item.path))
    file = next((f for f in analysis.files[1:] if f.path == name), None)
    if file is None:
        return f"**import \"{item.path}\"**: not read (see the diagnostics)"
    head = []
    for comment in file.comments:       # the file's leading comment: what its models share
        if comment.span.line != len(head) + 1:
            break
        head.append(comment.text.lstrip("#").strip())
    from bondc.flatten import ports_of

    models = file.models
    listing = [f"{len(models)} model{'s' if len(models) != 1 else ''}:"]
    for model in models:
        ports = ports_of(model)
        listing.append(f"- **{model.name}**" + (f" ({', '.join(ports)})" if ports else "")
                       + (f": {model.description}" if model.description else ""))
    parts = [f"**import \"{item.path}\"**", " ".join(text for text in head if text), "\n".join(listing)]
    return "\n\n".join(part for part in parts if part)


def hover(analysis: Analysis, position: lsp.Position) -> lsp.Hover | None:
    if analysis.index is None:
        return None
    line, column = cursor(analysis, position)
    for item, file in analysis.index.imports:
        span = item.span
        if file == str(analysis.path) and span.line - 1 == line and span.column - 1 <= column < span.end_column:
            return _markdown(_import_text(analysis, item))
    symbol, use, part = at(analysis.index, str(analysis.path), line, column)
    if symbol is None and use is not None:
        symbol = resolve(analysis.index, use, part)
        if symbol is None and use.call and use.name in BUILTINS:
            return _markdown(f"**{use.name}** (built-in): {BUILTINS[use.name].summary}")
    if symbol is None:
        return None
    return _markdown(hover_text(analysis, symbol))


def _markdown(text: str) -> lsp.Hover:
    return lsp.Hover(contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=text))


# ------------------------------------------------------------------ completion

_MEMBER = re.compile(r"([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)\.[A-Za-z0-9_]*$")
_BOND_LINE = re.compile(r"\s*[A-Za-z_][A-Za-z0-9_.]*$|.*->")


def _basics() -> list[lsp.CompletionItem]:
    return ([lsp.CompletionItem(label=kind, kind=lsp.CompletionItemKind.Class, detail=KINDS[kind].description)
             for kind in KINDS]
            + [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Function, detail=b.summary)
               for name, b in BUILTINS.items()]
            + [lsp.CompletionItem(label=word, kind=lsp.CompletionItemKind.Keyword) for word in KEYWORDS])


def completions(analysis: Analysis, text: str, line_text: str, model: str | None) -> list[lsp.CompletionItem]:
    """What may be written at the end of ``line_text`` (``text``: the buffer as it is now)."""
    from bondc.units import unit_names

    index = analysis.index
    if re.search(r"\[[^\]]*$", line_text):                        # inside a unit
        return [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Unit) for name in unit_names()]
    if index is None:       # a file that never parsed (a new one being written): what needs no index
        words = set(re.findall(r"\b(?:param|input|output|state|discrete)\s+([A-Za-z_]\w*)", text))
        return ([lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Variable) for name in sorted(words)]
                + _basics())
    member = _MEMBER.search(line_text)
    if member:
        bond = bool(_BOND_LINE.match(line_text[:member.start()] + "x"))
        return [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Field, detail=what)
                for name, what in members(index, member.group(1).split("."), model, bond)]
    items = [lsp.CompletionItem(label=s.name, kind=lsp.CompletionItemKind.Variable, detail=s.category)
             for s in index.symbols if s.model in (model, None) and s.category != "experiment"]
    items += [lsp.CompletionItem(label=name, kind=lsp.CompletionItemKind.Class, detail="model")
              for name in index.models]
    return items + _basics()


def model_at(analysis: Analysis, line: int) -> str | None:
    for model in (analysis.files[0].models if analysis.files else ()):
        if model.span.line - 1 <= line <= model.span.end_line - 1:
            return model.name
    return None


# ------------------------------------------------------------------ rename

#: What can be renamed: the names a model declares and the models and functions of a file.
RENAMED = ("parameter", "input", "output", "discrete", "state", "element", "instance", "junction", "model",
           "function", "bond label")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class RenameRefused(Exception):
    """Why the name at the cursor cannot be renamed, or not to the name asked."""


def renamed_symbol(analysis: Analysis, position: lsp.Position) -> tuple[Symbol, lsp.Range]:
    """The symbol at the cursor that rename would change, and the range of the name at the cursor."""
    if analysis.index is None:
        raise RenameRefused("the document does not parse: fix its syntax first")
    symbol, use, part = at_cursor(analysis, position)
    span = symbol.span if symbol is not None else None
    if symbol is None and use is not None:
        symbol = resolve(analysis.index, use, part)
        span = use.part_spans[part] if use.part_spans else use.span
    if symbol is None:
        raise RenameRefused("no name declared in this file here (built-ins, kinds and units keep their names)")
    if symbol.category not in RENAMED:
        raise RenameRefused(f"a {symbol.category} cannot be renamed")
    if symbol.file != str(analysis.path):
        raise RenameRefused(f"'{symbol.name}' is declared in {symbol.file}: rename it there")
    return symbol, analysis.positions.range(span)


def rename(analysis: Analysis, position: lsp.Position, new_name: str) -> lsp.WorkspaceEdit:
    symbol, _ = renamed_symbol(analysis, position)
    if not _NAME.fullmatch(new_name) or new_name in KEYWORDS or new_name in KINDS:
        raise RenameRefused(f"'{new_name}' is not a name (a letter or _, then letters, digits, _; not a keyword)")
    if new_name == symbol.name:
        return lsp.WorkspaceEdit(changes={})
    clash = analysis.index.by_name.get((new_name, symbol.model))
    if clash is None and symbol.category in ("model", "function") and symbol.model is None:
        clash = next((s for s in analysis.index.symbols if s.name == new_name and s.model is None), None)
    if clash is not None:
        where = f"line {clash.span.line}" if clash.file == str(analysis.path) else clash.file
        raise RenameRefused(f"'{new_name}' is already {clash.category} '{new_name}' ({where})")
    here = str(analysis.path)
    positions = analysis.positions
    spans = [symbol.span] + list(occurrences(analysis, symbol, here))
    unique = {(s.line, s.column, s.end_line, s.end_column): s for s in spans}
    edits = [lsp.TextEdit(range=positions.range(s), new_text=new_name) for _, s in sorted(unique.items())]
    return lsp.WorkspaceEdit(changes={analysis.uri: edits})


# ------------------------------------------------------------------ quick fixes

def quick_fixes(uri: str, diagnostics: list[lsp.Diagnostic]) -> list[lsp.CodeAction]:
    """A code action per suggestion of each "did you mean" diagnostic (its ``data``: the range to
    replace and the names offered, :func:`bondc.lsp.analysis._quick_fix`)."""
    actions = []
    for diagnostic in diagnostics:
        data = diagnostic.data
        if diagnostic.source != "bondc" or not isinstance(data, dict) or "replace" not in data:
            continue
        replace = data["replace"]
        try:
            where = lsp.Range(lsp.Position(int(replace["start"]["line"]), int(replace["start"]["character"])),
                              lsp.Position(int(replace["end"]["line"]), int(replace["end"]["character"])))
        except (KeyError, TypeError, ValueError):
            continue
        for number, name in enumerate(data.get("with") or ()):
            if not isinstance(name, str):
                continue
            actions.append(lsp.CodeAction(
                title=f"Replace with '{name}'", kind=lsp.CodeActionKind.QuickFix, diagnostics=[diagnostic],
                is_preferred=number == 0,
                edit=lsp.WorkspaceEdit(changes={uri: [lsp.TextEdit(range=where, new_text=name)]})))
    return actions


# ------------------------------------------------------------------ the outline

_SYMBOL_KINDS = {"parameter": lsp.SymbolKind.Constant, "element": lsp.SymbolKind.Object,
                 "instance": lsp.SymbolKind.Module, "junction": lsp.SymbolKind.Struct,
                 "input": lsp.SymbolKind.Variable, "output": lsp.SymbolKind.Variable,
                 "state": lsp.SymbolKind.Variable, "function": lsp.SymbolKind.Function,
                 "port": lsp.SymbolKind.Interface, "experiment": lsp.SymbolKind.Event,
                 "discrete": lsp.SymbolKind.Variable, "bond label": lsp.SymbolKind.Field}


def outline(analysis: Analysis) -> list[lsp.DocumentSymbol]:
    if analysis.index is None:
        return []
    here, positions = str(analysis.path), analysis.positions
    children: dict[str, list] = {}
    for s in analysis.index.symbols:
        if s.file == here and s.model is not None:
            span = positions.range(s.span)
            children.setdefault(s.model, []).append(lsp.DocumentSymbol(
                name=s.name, detail=s.category, kind=_SYMBOL_KINDS.get(s.category, lsp.SymbolKind.Field),
                range=span, selection_range=span))
    return [lsp.DocumentSymbol(name=model.name, detail=model.description or "model", kind=lsp.SymbolKind.Class,
                               range=positions.range(model.span), selection_range=positions.range(model.name_span),
                               children=children.get(model.name, []))
            for model in (analysis.files[0].models if analysis.files else ())]

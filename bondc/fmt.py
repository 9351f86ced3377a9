"""Format stage: ``ast.File`` (with its comments) -> the canonical ``.bg`` text.

The layout is decided by the AST alone, plus three facts taken from the spans:
where blank lines separated statements (kept, at most one), which comments
stood on a line of their own (kept before the statement that followed them) and
which ended a statement's line (kept at the end of that line). So
``parse(fmt(x)) == parse(x)`` (spans aside, comments included) and
``fmt(fmt(x)) == fmt(x)``.

Canonical layout: two-space indent inside ``model`` and ``experiment``; one
statement per line; expressions with the fewest parentheses the precedence
needs (``+ -``, comparisons, ``and``/``or`` spaced; ``* / ^`` tight); numbers
as written; units without spaces; runs of consecutive elements, parameters,
inputs/outputs and settings aligned in columns; trailing comments aligned;
element and state laws that would pass column 100 continue after a comma on
the next line, indented four more. A comment inside a multi-line statement
stays after its law when it followed one (the line breaks there); otherwise it
moves to its own line just before the statement.

>>> print(fmt("model M\\n  param k=800 [ N / m ]  # spring\\n  R   damper:e=b*(f)\\nend\\n"), end="")
model M
  param k = 800 [N/m]  # spring
  R damper : e = b*f
end
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from bondc import ast
from bondc.io import read_source
from bondc.kinds import KINDS
from bondc.parse import parse_source, parse_text
from bondc.source import Source, Span

MAX_WIDTH = 100  # a line of laws continues after a comma rather than pass this column
INDENT = "  "  # per block level
CONTINUATION = "    "  # extra indent of a statement's continuation lines
ALIGN_CELL_MAX = 40  # a column cell longer than this does not widen its column...
VALUE_ALIGN_MAX = 24  # ...nor an expression longer than this (units and descriptions after it)...
HEAD_ALIGN_MAX = 64  # ...nor an element's 'KIND NAME "description"' longer than this (its ':')
COMMENT_ALIGN_MAX = 80  # a line longer than this does not push the trailing-comment column


# ------------------------------------------------------------- expressions

# Binding levels, loosest first (LANGUAGE.md section 7); an atom is 9.
_IF, _OR, _AND, _NOT, _COMPARE, _SUM, _PRODUCT, _UNARY, _POWER, _ATOM = range(10)

_BINARY_LEVEL = {
    "or": _OR, "and": _AND,
    "<": _COMPARE, "<=": _COMPARE, ">": _COMPARE, ">=": _COMPARE, "==": _COMPARE, "!=": _COMPARE,
    "+": _SUM, "-": _SUM, "*": _PRODUCT, "/": _PRODUCT, "^": _POWER,
}
# The least binding level each operand may have without parentheses (from the
# grammar): or/and/+-/*/ are left-associative, comparisons do not chain, and ^
# takes an atom on the left and a unary expression on the right, so
# a^b^c is a^(b^c) and -x^2 is -(x^2).
_OPERAND_LEVELS = {
    _OR: (_OR, _AND),
    _AND: (_AND, _NOT),
    _COMPARE: (_SUM, _SUM),
    _SUM: (_SUM, _PRODUCT),
    _PRODUCT: (_PRODUCT, _UNARY),
    _POWER: (_ATOM, _UNARY),
}
_TIGHT = frozenset("*/^")


def quote(value: str) -> str:
    """A string literal that parses back to ``value``.

    >>> print(quote('say "hi" \\\\ bye'))
    "say \\"hi\\" \\\\ bye"
    """
    escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
    return f'"{escaped}"'


def unit_text(unit: ast.Unit) -> str:
    """A unit in brackets, written without spaces: ``[N*m/rad]``."""
    return "[" + "".join(re.sub(r"#[^\n]*", "", unit.text).split()) + "]"


class ExprPrinter:
    """Expressions -> text with minimal parentheses (one ``_print_<Class>`` per node)."""

    def print(self, expr: ast.Expr, level: int = _IF) -> str:
        """``expr`` as text, in parentheses if it binds looser than ``level``."""
        method = getattr(self, "_print_" + type(expr).__name__, None)
        if method is None:
            raise TypeError(f"fmt: unsupported expression node {type(expr).__name__}")
        text, own_level = method(expr)
        return f"({text})" if own_level < level else text

    def _print_Num(self, expr: ast.Num):
        return expr.text, _ATOM

    def _print_Str(self, expr: ast.Str):
        return quote(expr.value), _ATOM

    def _print_Name(self, expr: ast.Name):
        return expr.name, _ATOM

    def _print_Ref(self, expr: ast.Ref):
        return ".".join(expr.parts), _ATOM

    def _print_Call(self, expr: ast.Call):
        return f"{expr.func}({self.join(expr.args)})", _ATOM

    def _print_ListExpr(self, expr: ast.ListExpr):
        return f"[{self.join(expr.items)}]", _ATOM

    def _print_Transfer(self, expr: ast.Transfer):
        return f"{expr.source.name} -> {expr.target.name}", _ATOM

    def _print_Unary(self, expr: ast.Unary):
        if expr.op == "not":
            return "not " + self.print(expr.operand, _NOT), _NOT
        # -(-x) rather than --x: legal, but it reads like a typo
        nested_sign = isinstance(expr.operand, ast.Unary) and expr.operand.op in "+-"
        return expr.op + self.print(expr.operand, _ATOM if nested_sign else _UNARY), _UNARY

    def _print_Binary(self, expr: ast.Binary):
        level = _BINARY_LEVEL[expr.op]
        left_level, right_level = _OPERAND_LEVELS[level]
        left = self.print(expr.left, left_level)
        right = self.print(expr.right, right_level)
        if expr.op in _TIGHT:
            return f"{left}{expr.op}{right}", level
        return f"{left} {expr.op} {right}", level

    def _print_If(self, expr: ast.If):
        return f"if {self.print(expr.cond)} then {self.print(expr.then)} else {self.print(expr.orelse)}", _IF

    def join(self, exprs) -> str:
        return ", ".join(self.print(e) for e in exprs)


_EXPR = ExprPrinter()


def format_expr(expr: ast.Expr) -> str:
    """One expression in canonical form.

    >>> from bondc.parse import parse_set_value
    >>> format_expr(parse_set_value("x = -(a^b)^c + (d - (e - f)) * (if g then h else i)").value)
    '-(a^b)^c + (d - (e - f))*(if g then h else i)'
    """
    return _EXPR.print(expr)


def format_law(law: ast.Law) -> str:
    if isinstance(law, ast.LawAssign):
        return _words(f"{law.target} = {format_expr(law.value)}", _unit(law.unit))
    if isinstance(law, ast.LawCall):
        return f"{law.func}({format_expr(law.arg)}) = {format_expr(law.value)}"
    if isinstance(law, ast.LawState):
        return _words("state", law.name, _unit(law.unit), _desc(law.description))
    raise TypeError(f"fmt: unsupported law node {type(law).__name__}")


def _law_text(law: ast.Law, prefix_width: int) -> str:
    """A law as :func:`format_law` writes it, its if-chain broken if it would end past MAX_WIDTH."""
    if isinstance(law, ast.LawAssign):
        if law.unit is not None:
            return format_law(law)
        head = f"{law.target} = "
    elif isinstance(law, ast.LawCall):
        head = f"{law.func}({format_expr(law.arg)}) = "
    else:
        return format_law(law)
    return head + _value(law.value, prefix_width + len(head))


def _unit(unit: ast.Unit | None) -> str:
    return "" if unit is None else unit_text(unit)


def _when_action(action) -> str:
    if isinstance(action, ast.WhenAssign):
        return f"{action.name} = {format_expr(action.value)}"
    return f"{action.func}({', '.join(format_expr(arg) for arg in action.args)})"


def _desc(description: str | None) -> str:
    return "" if description is None else quote(description)


def _words(*parts: str) -> str:
    return " ".join(part for part in parts if part)


# ------------------------------------------------------------- comments

def _last_line(span: Span, source: Source | None) -> int:
    """The line a statement's text ends on (its span runs past the closing newline)."""
    if source is not None and span.end > span.start:
        return source.position(span.end - 1)[0]
    if span.end_line > span.line and span.end_column == 1:
        return span.end_line - 1
    return span.end_line


@dataclass
class _Gap:
    """Comments between law ``k`` and law ``k+1`` of one statement."""

    trailing: ast.Comment | None = None
    own_lines: list[ast.Comment] = field(default_factory=list)


@dataclass
class _Attached:
    """The comments that belong to one statement or block."""

    leading: list[ast.Comment] = field(default_factory=list)  # own lines before it
    moved: list[ast.Comment] = field(default_factory=list)  # from inside it, now before it
    trailing: ast.Comment | None = None  # at the end of its (last) line
    gaps: dict[int, _Gap] = field(default_factory=dict)  # law index -> comments after it
    end_leading: list[ast.Comment] = field(default_factory=list)  # blocks: own lines before 'end'
    end_trailing: ast.Comment | None = None  # blocks: after 'end'
    header_trailing: ast.Comment | None = None  # blocks: after the header


def _laws_of(stmt) -> tuple:
    return getattr(stmt, "laws", ()) if isinstance(stmt, (ast.Element, ast.StateDecl)) else ()


def _body_of(stmt) -> tuple | None:
    return stmt.body if isinstance(stmt, (ast.Model, ast.Experiment, ast.Defaults)) else None


class _Comments:
    """Assigns every comment of a file to the statement (or block end) it belongs to."""

    def __init__(self, file: ast.File, source: Source | None):
        self.source = source
        self.by_node: dict[int, _Attached] = {}
        self.file_trailing: list[ast.Comment] = []
        comments = sorted(file.comments, key=lambda c: (c.span.line, c.span.column))
        if comments and all(c.span.line > 0 for c in comments):
            self._block(comments, None, file.items, None, self.file_trailing)
        elif comments:  # no positions: keep them, at the end
            self.file_trailing.extend(comments)

    def of(self, node) -> _Attached:
        return self.by_node.setdefault(id(node), _Attached())

    def first(self, node) -> int:
        return node.span.line

    def last(self, node) -> int:
        return _last_line(node.span, self.source)

    def _block(self, comments, header_line, stmts, end_line, end_leading, block=None):
        inside: dict[int, list[ast.Comment]] = {}
        for comment in comments:
            line = comment.span.line
            if header_line is not None and line == header_line:
                self.of(block).header_trailing = comment
                continue
            if end_line is not None and line == end_line:
                self.of(block).end_trailing = comment
                continue
            for index, stmt in enumerate(stmts):
                if self.first(stmt) <= line <= self.last(stmt):
                    inside.setdefault(index, []).append(comment)
                    break
                if self.first(stmt) > line:
                    self.of(stmt).leading.append(comment)
                    break
            else:
                end_leading.append(comment)
        for index, stmt_comments in inside.items():
            stmt = stmts[index]
            body = _body_of(stmt)
            if body is not None:
                self._block(stmt_comments, self.first(stmt), body, self.last(stmt),
                            self.of(stmt).end_leading, stmt)
            else:
                self._statement(stmt_comments, stmt)

    def _statement(self, comments, stmt) -> None:
        attached = self.of(stmt)
        last = self.last(stmt)
        interior = []
        for comment in comments:
            if comment.span.line == last:
                attached.trailing = comment
            else:
                interior.append(comment)
        if not interior:
            return
        laws = _laws_of(stmt)
        gaps: dict[int, _Gap] = {}
        for comment in interior:
            line = comment.span.line
            for k in range(len(laws) - 1):
                end_k, start_next = laws[k].span.end_line, laws[k + 1].span.line
                if end_k == line < start_next:
                    gaps.setdefault(k, _Gap()).trailing = comment
                    break
                if end_k < line < start_next:
                    gaps.setdefault(k, _Gap()).own_lines.append(comment)
                    break
            else:
                # Inside an expression: the line breaks there are not kept, so the
                # comment (and, to keep their order, every other one) goes before it.
                attached.moved.extend(interior)
                return
        attached.gaps = gaps


# ------------------------------------------------------------- layout

@dataclass
class _Line:
    indent: str
    text: str  # "" for a blank line
    comment: str | None = None  # a trailing comment
    own_comment: bool = False  # the whole line is a comment (text)
    aligned: bool = True  # False for block headers and 'end': their comments stay apart


def _is_instance(stmt) -> bool:
    """A submodel instance (``Orifice valve : A = 2e-5``): an element statement whose kind is a model."""
    return isinstance(stmt, ast.Element) and stmt.kind not in KINDS


def _group(stmt) -> str | None:
    return "instance" if _is_instance(stmt) else _GROUP.get(type(stmt))


_GROUP = {
    ast.Param: "param",
    ast.Element: "element",
    ast.Junction: "element",
    ast.Input: "signal",
    ast.Output: "signal",
    ast.Setting: "setting",
}


def _outside_strings(text: str):
    """(offset, bracket depth) of every character of ``text`` outside string literals."""
    depth, index, in_string = 0, 0, False
    while index < len(text):
        char = text[index]
        if in_string:
            if char == "\\":
                index += 1
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        else:
            if char in ")]":
                depth -= 1
            yield index, depth
            if char in "([":
                depth += 1
        index += 1


def _commas(text: str, start: int = 0) -> list[tuple[int, int]]:
    """(offset, bracket depth) of each ', ' outside string literals, from ``start`` on."""
    return [(index, depth) for index, depth in _outside_strings(text)
            if index >= start and text.startswith(", ", index)]


def _leading(text: str) -> str:
    return text[: len(text) - len(text.lstrip(" "))]


def _wrap(indent: str, text: str, start: int = 0) -> list[str]:
    """A line too long for MAX_WIDTH, continued after commas, indented by CONTINUATION.

    Any comma may end a line (inside brackets, or a trailing one outside them).
    The outermost commas are used first, filling each line greedily; a piece
    still too long is then cut at its own outermost commas. Commas before
    ``start`` (a function's parameter list) are not used.
    """
    if len(indent) + len(text) <= MAX_WIDTH:
        return [text]
    commas = _commas(text, start)
    if not commas:
        return [text]
    outermost = min(depth for _, depth in commas)
    cuts = [offset for offset, depth in commas if depth == outermost]
    pieces = [text[a:b] for a, b in zip([0] + [c + 2 for c in cuts], [c + 1 for c in cuts] + [len(text)])]
    continuation = _leading(text) + CONTINUATION
    lines: list[str] = []
    current = pieces[0]
    for piece in pieces[1:]:
        if len(indent) + len(current) + 1 + len(piece) <= MAX_WIDTH:
            current += " " + piece
        else:
            lines.append(current)
            current = continuation + piece
    lines.append(current)
    wrapped = _wrap(indent, lines[0], start) if lines[0] != text else [lines[0]]
    for line in lines[1:]:
        wrapped += _wrap(indent, line)
    return wrapped


# Where a long if/then/else chain, put in parentheses, continues on a new line
# (only outside string literals, which may hold any character).
_ELSE_BREAK = "\x00"


def _is_broken(text: str) -> bool:
    return any(text[index] == _ELSE_BREAK for index, _ in _outside_strings(text))


def _broken_if(expr: ast.If) -> str:
    """``(if c then a <break>else if d then b <break>else z)``: one branch a line when too long."""
    parts = [f"(if {format_expr(expr.cond)} then {format_expr(expr.then)}"]
    rest = expr.orelse
    while isinstance(rest, ast.If):
        parts.append(f"else if {format_expr(rest.cond)} then {format_expr(rest.then)}")
        rest = rest.orelse
    parts.append(f"else {format_expr(rest)})")
    return _ELSE_BREAK.join(parts)


def _lay_out(indent: str, text: str, start: int = 0) -> list[str]:
    """The physical lines of one logical line: if/else breaks first, then commas."""
    breaks = [index for index, _ in _outside_strings(text) if text[index] == _ELSE_BREAK]
    segments = [text[a:b] for a, b in zip([0] + [i + 1 for i in breaks], breaks + [len(text)])]
    continuation = _leading(segments[0]) + CONTINUATION
    lines = _wrap(indent, segments[0], start)
    for segment in segments[1:]:
        lines += _wrap(indent, continuation + segment)
    return lines


def _value(expr: ast.Expr, prefix_width: int) -> str:
    """``expr`` on one line, or as a broken if-chain when it would end past MAX_WIDTH."""
    text = format_expr(expr)
    if isinstance(expr, ast.If) and prefix_width + len(text) > MAX_WIDTH:
        return _broken_if(expr)
    return text


def _joins(line: _Line) -> bool:
    """Whether a line's trailing comment is aligned with its neighbours'."""
    return bool(line.text) and not line.own_comment and line.aligned


def _column(cells: list[str], longest: int = ALIGN_CELL_MAX) -> int:
    """The width of a column: its longest cell, ignoring cells longer than ``longest``."""
    widths = [len(cell) for cell in cells if len(cell) <= longest]
    return max(widths, default=0)


def _pad(cell: str, width: int) -> str:
    return cell.ljust(width)


class _Formatter:
    def __init__(self, file: ast.File, source: Source | None):
        self.file = file
        self.comments = _Comments(file, source)
        self.lines: list[_Line] = []

    # output ------------------------------------------------------------------
    def blank(self) -> None:
        if self.lines and self.lines[-1].text:
            self.lines.append(_Line("", ""))

    def own_comment(self, indent: str, comment: ast.Comment, blank_before: bool = False) -> None:
        if blank_before:
            self.blank()
        self.lines.append(_Line(indent, comment.text, own_comment=True))

    def code(self, indent: str, text: str, comment: ast.Comment | None = None, aligned: bool = True,
             start: int = 0) -> None:
        """One logical line, continued on more lines if it would pass MAX_WIDTH."""
        pieces = _lay_out(indent, text, start)
        for piece in pieces[:-1]:
            self.lines.append(_Line(indent, piece, aligned=aligned))
        self.lines.append(_Line(indent, pieces[-1], None if comment is None else comment.text, aligned=aligned))

    def text(self) -> str:
        while self.lines and not self.lines[-1].text:
            self.lines.pop()
        self._align_comments()
        out = []
        for line in self.lines:
            if not line.text:
                out.append("")
            elif line.comment is None:
                out.append((line.indent + line.text).rstrip())
            else:
                out.append(line.indent + line.text + line.comment)
        return "\n".join(out) + "\n" if out else ""

    def _align_comments(self) -> None:
        """Trailing comments of consecutive code lines start in one column."""
        section: list[_Line] = []
        for line in self.lines + [_Line("", "")]:
            if _joins(line) and (not section or section[-1].indent == line.indent):
                section.append(line)
                continue
            commented = [s for s in section if s.comment is not None]
            widths = [len(s.indent + s.text.rstrip()) for s in commented]
            column = max((w for w in widths if w <= COMMENT_ALIGN_MAX), default=0) + 2
            for s, width in zip(commented, widths):
                s.text = s.text.rstrip() + " " * (max(column, width + 2) - width)
            section = [line] if _joins(line) else []
            if line.comment is not None and not line.aligned:
                line.text = line.text.rstrip() + "  "

    # blocks ------------------------------------------------------------------
    def format(self) -> str:
        self._sequence(self.file.items, "", None, self.comments.file_trailing, top=True)
        return self.text()

    def _sequence(self, stmts, indent: str, header_line: int | None, end_leading, top: bool = False) -> None:
        """A run of statements (a block body or the file) and the comments before its end."""
        comments = self.comments
        previous_last = header_line
        entries = []  # (stmt, blank lines before each of its leading comments, blank before it)
        for stmt in stmts:
            attached = comments.of(stmt)
            comment_blanks = []
            for comment in attached.leading:
                comment_blanks.append(previous_last is not None and comment.span.line - previous_last > 1)
                previous_last = comment.span.line
            stmt_blank = previous_last is not None and comments.first(stmt) - previous_last > 1
            previous_last = comments.last(stmt)
            entries.append((stmt, comment_blanks, stmt_blank))

        runs = self._runs(entries)
        for index, (stmt, comment_blanks, stmt_blank) in enumerate(entries):
            attached = comments.of(stmt)
            if index == 0 and not top:  # no blank line right after a block header
                comment_blanks = [False] * len(comment_blanks)
                stmt_blank = False
            if top and index > 0 and (isinstance(stmt, ast.Model) or isinstance(entries[index - 1][0], ast.Model)):
                if comment_blanks:
                    comment_blanks = [True] + comment_blanks[1:]
                else:
                    stmt_blank = True
            for comment, blank in zip(attached.leading, comment_blanks):
                self.own_comment(indent, comment, blank)
            for position, comment in enumerate(attached.moved):
                self.own_comment(indent, comment, stmt_blank and position == 0)
            if stmt_blank and not attached.moved:
                self.blank()
            self._statement(stmt, indent, runs[index])

        for comment in end_leading:
            blank = previous_last is not None and comment.span.line - previous_last > 1
            if not top and previous_last == header_line:
                blank = False
            self.own_comment(indent, comment, blank)
            previous_last = comment.span.line

    def _runs(self, entries) -> list[dict]:
        """Column widths for each statement, shared by a run of aligned statements."""
        widths: list[dict] = [{} for _ in entries]
        start = 0
        while start < len(entries):
            group = _group(entries[start][0])
            end = start + 1
            while (group is not None and end < len(entries)
                   and _group(entries[end][0]) == group
                   and not any(entries[end][1]) and not entries[end][2]):
                end += 1
            if group is not None:
                shared = getattr(self, "_widths_" + group)([entry[0] for entry in entries[start:end]],
                                                           [entry[0] for entry in entries])
                for index in range(start, end):
                    widths[index] = shared
            start = end
        return widths

    def _statement(self, stmt, indent: str, widths: dict) -> None:
        method = getattr(self, "_stmt_" + type(stmt).__name__, None)
        if method is None:
            raise TypeError(f"fmt: unsupported statement node {type(stmt).__name__}")
        method(stmt, indent, widths, self.comments.of(stmt))

    def _block(self, stmt, header: str, indent: str, attached: _Attached) -> None:
        self.code(indent, header, attached.header_trailing, aligned=False)
        self._sequence(stmt.body, indent + INDENT, self.comments.first(stmt), attached.end_leading)
        self.code(indent, "end", attached.end_trailing, aligned=False)

    def _laws(self, head: str, items: list, indent: str, attached: _Attached, fill: bool = False) -> None:
        """``head`` then ``items`` (laws, or names) separated by commas, continued past MAX_WIDTH.

        The first line takes as many items as fit; after it each law gets a line of
        its own (``fill``: lines are filled, as for junction names). A comment that
        followed an item keeps the line break after it.
        """
        if not items:
            self.code(indent, head, attached.trailing)
            return

        def render(item, prefix: str) -> str:
            return item if isinstance(item, str) else _law_text(item, len(indent) + len(prefix))

        first = render(items[0], head)
        if head.endswith(" : ") and len(indent + head) + len(first.split(_ELSE_BREAK)[0]) > MAX_WIDTH \
                and not isinstance(items[0], str):
            # a long first law starts on the next line (a newline may follow the colon)
            self.code(indent, head.rstrip(), None)
            head = CONTINUATION
            first = render(items[0], head)
        current, first_line = head + first, True
        for k in range(1, len(items)):
            gap = attached.gaps.get(k - 1)
            plain = items[k] if isinstance(items[k], str) else format_law(items[k])  # one line
            comma = 1 if k < len(items) - 1 else 0
            if (gap is None and (first_line or fill) and not _is_broken(current)
                    and len(indent + current) + 2 + len(plain) + comma <= MAX_WIDTH):
                current += ", " + plain
                continue
            self.code(indent, current + ",", gap.trailing if gap else None)
            for comment in gap.own_lines if gap else ():
                self.own_comment(indent + CONTINUATION, comment)
            # the line keeps the block's indent (for comment alignment); CONTINUATION is in its text
            current, first_line = CONTINUATION + render(items[k], CONTINUATION), False
        self.code(indent, current, attached.trailing)

    # statements --------------------------------------------------------------
    def _stmt_Import(self, stmt: ast.Import, indent, widths, attached) -> None:
        self.code(indent, f"import {quote(stmt.path)}", attached.trailing)

    def _stmt_FnDef(self, stmt: ast.FnDef, indent, widths, attached) -> None:
        head = f"fn {stmt.name}({', '.join(stmt.params)}) = "
        text = _words(head + _value(stmt.body, len(indent + head)), _desc(stmt.description))
        self.code(indent, text, attached.trailing, start=len(head))  # not inside the parameter list

    def _stmt_Model(self, stmt: ast.Model, indent, widths, attached) -> None:
        self._block(stmt, _words("model", stmt.name, _desc(stmt.description)), indent, attached)

    def _stmt_Experiment(self, stmt: ast.Experiment, indent, widths, attached) -> None:
        self._block(stmt, _words("experiment", stmt.name, _desc(stmt.description)), indent, attached)

    def _stmt_Defaults(self, stmt: ast.Defaults, indent, widths, attached) -> None:
        self._block(stmt, "defaults", indent, attached)

    def _stmt_PortDecl(self, stmt: ast.PortDecl, indent, widths, attached) -> None:
        self._laws("port ", list(stmt.names), indent, attached, fill=True)

    def _stmt_BondChain(self, stmt: ast.BondChain, indent, widths, attached) -> None:
        chain = " -> ".join(e.name if e.port is None else f"{e.name}.{e.port}" for e in stmt.endpoints)
        text = chain if stmt.label is None else f"{stmt.label}: {chain}"
        self.code(indent, text, attached.trailing)

    def _stmt_StateDecl(self, stmt: ast.StateDecl, indent, widths, attached) -> None:
        head = _words("state", stmt.name, _unit(stmt.unit), _desc(stmt.description))
        self._laws(head + " : " if stmt.laws else head, list(stmt.laws), indent, attached)

    def _stmt_Discrete(self, stmt: ast.Discrete, indent, widths, attached) -> None:
        head = _words("discrete", stmt.name, _unit(stmt.unit)) + " = "
        self.code(indent, _words(head + _value(stmt.value, len(indent + head)), _desc(stmt.description)),
                  attached.trailing)

    def _stmt_When(self, stmt: ast.When, indent, widths, attached) -> None:
        """``when COND then A, B end`` on one line; past the width, one action a line."""
        actions = [_when_action(action) for action in stmt.actions]
        self._laws(f"when {format_expr(stmt.condition)} then ", actions[:-1] + [actions[-1] + " end"], indent,
                   attached)

    # params: param NAME = VALUE [UNIT] "DESC"
    def _widths_param(self, run, block) -> dict:
        with_unit_or_desc = [p for p in run if p.unit is not None or p.description is not None]
        return {
            "name": _column([p.name for p in run]),
            "value": _column([format_expr(p.value) for p in with_unit_or_desc], VALUE_ALIGN_MAX),
            "unit": _column([_unit(p.unit) for p in run if p.description is not None]),
        }

    def _stmt_Param(self, stmt: ast.Param, indent, widths, attached) -> None:
        prefix = f"param {_pad(stmt.name, widths.get('name', 0))} = "
        value = _value(stmt.value, len(indent + prefix))
        unit, desc = _unit(stmt.unit), _desc(stmt.description)
        aligned = not _is_broken(value) and len(value) <= widths.get("value", 0)
        if aligned and (unit or desc):
            value = _pad(value, widths.get("value", 0))
        if aligned and desc and (unit or widths.get("unit")):  # a value too long to align ends the columns
            unit = _pad(unit, widths.get("unit", 0))
        self.code(indent, " ".join(part for part in (prefix + value, unit, desc) if part), attached.trailing)

    # elements and junctions: KIND NAME "DESC" : LAWS   /   KIND NAME, NAME
    def _widths_element(self, run, block) -> dict:
        elements = [s for s in run if isinstance(s, ast.Element)]
        # one kind column for the whole block, so every element's name starts in one column
        kind = max(len(s.kind) for s in block if isinstance(s, (ast.Element, ast.Junction)) and not _is_instance(s))
        name = max((len(s.name) for s in elements if s.description is not None or s.laws), default=0)
        heads = [self._element_head(s, kind, name) for s in elements if s.laws]
        return {"kind": kind, "name": name, "colon": _column(heads, HEAD_ALIGN_MAX)}

    @staticmethod
    def _element_head(stmt: ast.Element, kind: int, name: int) -> str:
        return _words(_pad(stmt.kind, kind), _pad(stmt.name, name), _desc(stmt.description)).rstrip()

    # instances: MODEL NAME "DESC" : BINDING, ... aligned among themselves, bindings filling lines
    def _widths_instance(self, run, block) -> dict:
        kind = max(len(s.kind) for s in run)
        name = max((len(s.name) for s in run if s.description is not None or s.laws), default=0)
        heads = [self._element_head(s, kind, name) for s in run if s.laws]
        return {"kind": kind, "name": name, "colon": _column(heads, HEAD_ALIGN_MAX)}

    def _stmt_Element(self, stmt: ast.Element, indent, widths, attached) -> None:
        head = self._element_head(stmt, widths.get("kind", 0), widths.get("name", 0))
        if stmt.laws:
            head = _pad(head, widths.get("colon", 0)) + " : "
        if _is_instance(stmt):
            self._laws(head, [format_law(law) for law in stmt.laws], indent, attached, fill=True)
            return
        self._laws(head, list(stmt.laws), indent, attached)

    def _stmt_Junction(self, stmt: ast.Junction, indent, widths, attached) -> None:
        head = _pad(stmt.kind, widths.get("kind", 0)) + " "
        self._laws(head, list(stmt.names), indent, attached, fill=True)

    # inputs and outputs: input NAME [UNIT] = VALUE "DESC"
    def _widths_signal(self, run, block) -> dict:
        return {
            "keyword": max(len(_keyword(s)) for s in run),
            "name": _column([s.name for s in run]),
            "unit": _column([_signal_unit(s) for s in run]),
            "value": _column([format_expr(s.value) for s in run if s.description is not None and s.value is not None],
                             VALUE_ALIGN_MAX),
        }

    def _signal(self, stmt, indent, widths, attached) -> None:
        keyword = _pad(_keyword(stmt), widths.get("keyword", 0))
        name = _pad(stmt.name, widths.get("name", 0))
        bare = _signal_unit(stmt)       # input NAME [UNIT] external = DEFAULT: the keyword stays with the unit
        unit = _pad(bare, widths.get("unit", 0))
        if stmt.value is None:    # a component's input without a default (or an external one: 0)
            self.code(indent, _words(keyword, name if stmt.description else stmt.name, unit if stmt.description else
                                     bare, _desc(stmt.description)), attached.trailing)
            return
        prefix = " ".join(part for part in (keyword, name, unit) if part) + " = "
        value = _value(stmt.value, len(indent + prefix))
        desc = _desc(stmt.description)
        if desc and not _is_broken(value):
            value = _pad(value, widths.get("value", 0))
        self.code(indent, _words(prefix + value, desc), attached.trailing)

    _stmt_Input = _signal
    _stmt_Output = _signal

    # experiment settings: NAME = VALUE [UNIT]
    def _widths_setting(self, run, block) -> dict:
        return {"name": max(len(s.name) for s in run)}

    def _stmt_Setting(self, stmt: ast.Setting, indent, widths, attached) -> None:
        prefix = f"{_pad(stmt.name, widths.get('name', 0))} = "
        text = _words(prefix + _value(stmt.value, len(indent + prefix)), _unit(stmt.unit))
        self.code(indent, text, attached.trailing)


def _signal_unit(stmt) -> str:
    """An input's or output's unit as printed, with ``external`` after it for an external input."""
    return " ".join(part for part in (_unit(stmt.unit), "external" if getattr(stmt, "external", False) else "")
                    if part)


def _keyword(stmt) -> str:
    return "input" if isinstance(stmt, ast.Input) else "output"


# ------------------------------------------------------------- entry points

def format_file(file: ast.File, source_text: str | None = None) -> str:
    """The canonical text of a parsed file.

    ``source_text`` is the text ``file`` was parsed from; with it, line ends are
    read exactly from the text, without it they are read from the spans.
    """
    source = None if source_text is None else Source(file.path or "<text>", source_text)
    return _Formatter(file, source).format()


def fmt(text: str, name: str = "<text>") -> str:
    """Parse ``text`` and return its canonical form; raises ``ParseError`` on a syntax error."""
    return format_file(parse_text(text, name), text)


def format_path(path: str | Path) -> tuple[str, str]:
    """``(original, formatted)`` text of a ``.bg`` file, for ``bondc fmt``."""
    source = read_source(path)
    return source.text, format_file(parse_source(source), source.text)

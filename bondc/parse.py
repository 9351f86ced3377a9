"""Parse stage: ``.bg`` text -> :class:`bondc.ast.File`, or every syntax error.

The grammar lives in ``grammar/bondgraph.lark`` (shipped as ``bondc.grammar``);
the LALR parser is built once and cached. A post-lexer implements the line
rules of the language: a statement ends at the end of its line, continues after
a trailing ``,`` and anywhere inside ``( )`` or ``[ ]``; comments are collected
for ``bondc fmt``.

On a syntax error the parser records a diagnostic, blanks the offending
statement (keeping every other character where it was, so later positions stay
exact) and parses again, so one run reports every syntax error.

>>> f = parse_text("model M\\n  I mass : f = p/m\\nend\\n", "m.bg")
>>> f.models[0].body[0].kind, f.models[0].body[0].laws[0].target
('I', 'f')
"""

from __future__ import annotations

import functools
import re
import sys
from dataclasses import replace
from fractions import Fraction
from importlib import resources
from pathlib import Path

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import GrammarError, UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, VisitError

from bondc import ast
from bondc.errors import Diagnostic, ParseError, Related
from bondc.source import Source, Span
from bondc import codes

#: Python's default of 1000 nested calls is reached by a sum of a few hundred terms: the parser,
#: the syntax tree and the translation to sympy follow an operator chain one call per term.
#: Python 3.11 keeps these calls off the C stack; a deeper chain is E005 (bondc.cli).
RECURSION_LIMIT = 20_000
if sys.getrecursionlimit() < RECURSION_LIMIT:
    sys.setrecursionlimit(RECURSION_LIMIT)

MAX_SYNTAX_ERRORS = 20

KEYWORDS = frozenset(
    "model end param input output state fn experiment import if then else and or not".split()
)

# Keywords only at the start of a statement (LANGUAGE.md section 11): names everywhere else.
STATEMENT_KEYWORDS = frozenset({"discrete", "when", "port", "defaults"})

# What an expected terminal means to a user.
TERMINAL_NAMES = {
    "NAME": "a name",
    "NUMBER": "a number",
    "STRING": "a string",
    "_NL": "end of line",
    "$END": "end of file",
    "COMP_OP": "a comparison",
    "ADD_OP": "'+' or '-'",
    "MUL_OP": "'*' or '/'",
    "LPAR": "'('",
    "RPAR": "')'",
    "LSQB": "'['",
    "RSQB": "']'",
    "COMMA": "','",
    "COLON": "':'",
    "EQUAL": "'='",
    "DOT": "'.'",
    "CIRCUMFLEX": "'^'",
    "__ANON_0": "'->'",
}


def _grammar_text() -> str:
    return resources.files("bondc.grammar").joinpath("bondgraph.lark").read_text(encoding="utf-8")


class _LinePostLexer:
    """Drops newlines inside brackets, after a trailing comma or colon, and repeated ones.

    Comments are taken out of the token stream and kept in ``comments`` for fmt.
    """

    always_accept = ("_NL", "COMMENT")

    def __init__(self) -> None:
        self.comments: list[Token] = []
        self.text = ""

    def process(self, stream):
        return self._lines(self._statement_keywords(stream))

    def _statement_keywords(self, stream):
        """``discrete`` and ``when`` are keywords only at the start of a statement (after a line
        break) and where they begin a declaration: ``discrete NAME``, and ``when`` not followed by
        ``->``, ``.`` or ``:`` (a bond from an element called ``when``). The text after the word is
        looked at directly: the contextual lexer cannot read ahead of the parser's state."""
        start = True
        for token in stream:
            if token.type == "NAME" and start and token.value in STATEMENT_KEYWORDS:
                rest = self.text[token.end_pos:token.end_pos + 200].lstrip(" \t")
                if token.value in ("discrete", "port"):
                    keyword = rest[:1].isalpha() or rest[:1] == "_"
                elif token.value == "defaults":
                    keyword = rest == "" or rest.startswith(("\n", "\r", "#"))
                else:
                    keyword = not rest.startswith(("->", ".", ":", "\n", "#")) and rest != ""
                if keyword:
                    token = Token.new_borrow_pos(token.value.upper(), token.value, token)
            if token.type != "COMMENT":
                start = token.type == "_NL"
            yield token

    def _lines(self, stream):
        self.comments = []
        depth = 0
        previous = None
        for token in stream:
            kind = token.type
            if kind == "COMMENT":
                self.comments.append(token)
                continue
            if kind == "NAME" and token.value in KEYWORDS:
                # The contextual lexer reads a keyword as a NAME where no keyword fits
                # (``param end = 5``); keywords are reserved, so hand it on as one.
                kind = token.value.upper()
                token = Token.new_borrow_pos(kind, token.value, token)
            if kind == "_NL":
                if depth > 0 or previous is None or previous.type in ("_NL", "COMMA", "COLON"):
                    continue
            elif kind in ("LPAR", "LSQB"):
                depth += 1
            elif kind in ("RPAR", "RSQB"):
                depth = max(0, depth - 1)
            previous = token
            yield token
        if previous is not None and previous.type != "_NL":
            yield Token.new_borrow_pos("_NL", "\n", previous)


_PARSER_OPTIONS = {"parser": "lalr", "lexer": "contextual", "propagate_positions": True,
                   "maybe_placeholders": True, "start": ["start", "set_value"]}


@functools.lru_cache(maxsize=1)
def _parser() -> tuple[Lark, _LinePostLexer]:
    """The LALR parser. Its tables are built from the grammar once, kept in bondc's cache folder
    (lark's ``cache``, which checks them against the grammar and the options) and loaded from
    there afterwards: building them is a third of a ``bondc check``.

    lark writes the file itself, under its final name: the check it writes into the file hashes
    every option, the file's name included, so a file written under another name (to be renamed
    into place) is never loaded. A file another run is still writing, or a damaged one, fails
    lark's check or its unpickling: lark then builds the tables and writes the file again."""
    postlex = _LinePostLexer()
    text = _grammar_text()
    path = _parser_cache_path(text)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            return Lark(text, postlex=postlex, cache=str(path), **_PARSER_OPTIONS), postlex
        except OSError:     # a read-only or full cache folder: the parser is built each time
            pass
    return Lark(text, postlex=postlex, **_PARSER_OPTIONS), postlex


def _parser_cache_path(grammar: str) -> Path | None:
    """Where the parser of this grammar, these options and this lark is kept (None: nowhere)."""
    import hashlib

    import lark

    try:
        from bondc.io import cache_dir

        key = hashlib.sha256("\n".join((lark.__version__, sys.version, repr(sorted(_PARSER_OPTIONS.items())),
                                        grammar)).encode("utf-8")).hexdigest()[:32]
        return Path(cache_dir()) / "parser" / f"lalr-{key}.lark"
    except Exception:
        return None


def _unquote(token: Token) -> str:
    body = str(token)[1:-1]
    out = []
    index = 0
    while index < len(body):
        char = body[index]
        if char == "\\" and index + 1 < len(body):
            nxt = body[index + 1]
            out.append({"n": "\n", "t": "\t"}.get(nxt, nxt))
            index += 2
        else:
            out.append(char)
            index += 1
    return "".join(out)


def _opt_str(token: Token | None) -> str | None:
    return None if token is None else _unquote(token)


class _ToAst(Transformer):
    """Lark tree -> frozen AST nodes with spans (one method per rule alias)."""

    def __init__(self, source: Source):
        super().__init__()
        self.source = source
        self.methods: dict = {}

    def _call_userfunc(self, tree, new_children=None):
        """lark's ``Transformer._call_userfunc`` with each rule's method looked up once: lark binds
        a ``v_args`` method anew on every node (a wrapper object and ``functools.update_wrapper``),
        a tenth of the parse of a large model."""
        children = new_children if new_children is not None else tree.children
        method = self.methods.get(tree.data)
        if method is None:
            try:
                method = self.methods[tree.data] = getattr(self, tree.data)
            except AttributeError:
                return self.__default__(tree.data, children, tree.meta)
        try:
            wrapper = getattr(method, "visit_wrapper", None)
            if wrapper is not None:
                return wrapper(method, tree.data, children, tree.meta)
            return method(children)
        except GrammarError:
            raise
        except Exception as error:
            raise VisitError(tree.data, tree, error) from error

    # spans -----------------------------------------------------------------
    def _tok(self, token: Token) -> Span:
        # (lark types positions as optional; a token the parser produced has both)
        return self.source.span(token.start_pos or 0, token.end_pos or 0)

    def _meta(self, meta) -> Span:
        if getattr(meta, "empty", True):
            return self.source.span(0, 0)
        # A statement's tokens include its closing newline; the span ends at its last character.
        text = self.source.text
        end = meta.end_pos
        while end > meta.start_pos and text[end - 1] in " \t\r\n":
            end -= 1
        return self.source.span(meta.start_pos, end)

    # expressions -----------------------------------------------------------
    @v_args(meta=True)
    def number(self, meta, children):
        (token,) = children
        return ast.Num(float(token), str(token), self._tok(token))

    @v_args(meta=True)
    def string(self, meta, children):
        (token,) = children
        return ast.Str(_unquote(token), self._tok(token))

    @v_args(meta=True)
    def name(self, meta, children):
        (token,) = children
        return ast.Name(str(token), self._tok(token))

    @v_args(meta=True)
    def ref(self, meta, children):
        return ast.Ref(tuple(str(t) for t in children), self._meta(meta))

    @v_args(meta=True)
    def call(self, meta, children):
        func, args = children
        return ast.Call(str(func), tuple(args or ()), self._meta(meta), self._tok(func))

    @v_args(meta=True)
    def list(self, meta, children):
        (args,) = children
        return ast.ListExpr(tuple(args or ()), self._meta(meta))

    def args(self, children):
        return list(children)

    @v_args(meta=True)
    def if_expr(self, meta, children):
        cond, then, orelse = children
        return ast.If(cond, then, orelse, self._meta(meta))

    @v_args(meta=True)
    def or_op(self, meta, children):
        return ast.Binary("or", children[0], children[1], self._meta(meta))

    @v_args(meta=True)
    def and_op(self, meta, children):
        return ast.Binary("and", children[0], children[1], self._meta(meta))

    @v_args(meta=True)
    def not_op(self, meta, children):
        return ast.Unary("not", children[0], self._meta(meta))

    @v_args(meta=True)
    def compare(self, meta, children):
        left, op, right = children
        return ast.Binary(str(op), left, right, self._meta(meta))

    @v_args(meta=True)
    def binop(self, meta, children):
        left, op, right = children
        return ast.Binary(str(op), left, right, self._meta(meta))

    @v_args(meta=True)
    def unary_op(self, meta, children):
        op, operand = children
        return ast.Unary(str(op), operand, self._meta(meta))

    @v_args(meta=True)
    def pow(self, meta, children):
        base, exponent = children
        return ast.Binary("^", base, exponent, self._meta(meta))

    # units -----------------------------------------------------------------
    @v_args(meta=True)
    def unit(self, meta, children):
        (factors,) = children
        span = self._meta(meta)
        text = self.source.text[span.start + 1:span.end - 1]
        # Layout-free text (no spaces, newlines or comments), so that it compares
        # equal however the unit was laid out and fmt can print it as it stands.
        text = "".join(re.sub(r"#[^\n]*", "", text).split())
        return ast.Unit(tuple(factors), text, span)

    def unit_product(self, children):
        factors = list(children[0])
        for op, operand in zip(children[1::2], children[2::2]):
            sign = 1 if str(op) == "*" else -1
            factors += [ast.UnitFactor(f.name, sign * f.exponent, f.span) for f in operand]
        return factors

    def unit_power(self, children):
        base, exponent = children
        if exponent is None:
            return base
        return [ast.UnitFactor(f.name, f.exponent * exponent, f.span) for f in base]

    def unit_name(self, children):
        (token,) = children
        return [ast.UnitFactor(str(token), Fraction(1), self._tok(token))]

    def unit_number(self, children):
        (token,) = children
        # Only "1" is meaningful ([1], [1/s]); anything else is reported by the units stage.
        return [ast.UnitFactor(str(token), Fraction(1), self._tok(token))]

    def unit_exponent(self, children):
        sign, numerator = children[0], children[1]
        value = Fraction(str(numerator))
        if len(children) > 2 and children[3] is not None:
            value = value / Fraction(str(children[3]))
        return -value if sign is not None and str(sign) == "-" else value

    # laws ------------------------------------------------------------------
    def laws(self, children):
        return tuple(children)

    @v_args(meta=True)
    def law_assign(self, meta, children):
        target, value, unit = children
        return ast.LawAssign(str(target), value, self._meta(meta), self._tok(target), unit)

    @v_args(meta=True)
    def law_call(self, meta, children):
        func, arg, value = children
        return ast.LawCall(str(func), arg, value, self._meta(meta), self._tok(func))

    @v_args(meta=True)
    def law_state(self, meta, children):
        name, unit, description = children
        return ast.LawState(str(name), unit, _opt_str(description), self._meta(meta), self._tok(name))

    # statements ------------------------------------------------------------
    @v_args(meta=True)
    def import_stmt(self, meta, children):
        (path,) = children
        return ast.Import(_unquote(path), self._meta(meta))

    def fn_params(self, children):
        return tuple(str(t) for t in children)

    @v_args(meta=True)
    def fn_def(self, meta, children):
        name, params, body, description = children
        return ast.FnDef(str(name), params or (), body, _opt_str(description), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def param(self, meta, children):
        name, value, unit, description = children
        return ast.Param(str(name), value, unit, _opt_str(description), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def input(self, meta, children):
        name, unit, external, value, description = children
        return ast.Input(str(name), unit, value, _opt_str(description), self._meta(meta), self._tok(name),
                         external=external is not None)

    @v_args(meta=True)
    def output(self, meta, children):
        name, unit, value, description = children
        return ast.Output(str(name), unit, value, _opt_str(description), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def state_decl(self, meta, children):
        name, unit, description, laws = children
        return ast.StateDecl(str(name), unit, _opt_str(description), laws or (), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def discrete_decl(self, meta, children):
        _, name, unit, value, description = children
        return ast.Discrete(str(name), unit, value, _opt_str(description), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def when_assign(self, meta, children):
        name, value = children
        return ast.WhenAssign(str(name), value, self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def when_call(self, meta, children):
        func, args = children
        return ast.WhenCall(str(func), tuple(args or ()), self._meta(meta), self._tok(func))

    @v_args(meta=True)
    def when_clause(self, meta, children):
        actions = tuple(child for child in children[2:] if isinstance(child, (ast.WhenAssign, ast.WhenCall)))
        return ast.When(children[1], actions, self._meta(meta))

    @v_args(meta=True)
    def element(self, meta, children):
        kind, member, name, description, laws = children
        kind_span = self._tok(kind) if member is None else self._tok(kind).to(self._tok(member))
        kind_text = str(kind) if member is None else f"{kind}.{member}"
        return ast.Element(kind_text, str(name), _opt_str(description), laws or (), self._meta(meta),
                           kind_span, self._tok(name))

    @v_args(meta=True)
    def port_decl(self, meta, children):
        names = children[1:]
        return ast.PortDecl(tuple(str(n) for n in names), self._meta(meta), tuple(self._tok(n) for n in names))

    @v_args(meta=True)
    def defaults(self, meta, children):
        return ast.Defaults(tuple(c for c in children if isinstance(c, ast.Setting)), self._meta(meta))

    def dotted_name(self, children):
        return ".".join(str(c) for c in children)

    @v_args(meta=True)
    def junction(self, meta, children):
        kind, *names = children
        return ast.Junction(str(kind), tuple(str(n) for n in names), self._meta(meta), self._tok(kind),
                            tuple(self._tok(n) for n in names))

    @v_args(meta=True)
    def endpoint(self, meta, children):
        name, port = children
        return ast.Endpoint(str(name), None if port is None else str(port), self._meta(meta))

    @v_args(meta=True)
    def bond(self, meta, children):
        label, *endpoints = children
        label_span = self._tok(label) if label is not None else self._meta(meta)
        return ast.BondChain(None if label is None else str(label), tuple(endpoints), self._meta(meta), label_span)

    @v_args(meta=True)
    def setting(self, meta, children):
        name, value, unit = children
        return ast.Setting(str(name), value, unit, self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def setting_transfers(self, meta, children):
        name, *transfers = children
        span = self._meta(meta)
        items = ast.ListExpr(tuple(transfers), transfers[0].span.to(transfers[-1].span))
        return ast.Setting(str(name), items, None, span, self._tok(name))

    @v_args(meta=True)
    def transfer(self, meta, children):
        source, target = children
        return ast.Transfer(ast.Name(str(source), self._tok(source)), ast.Name(str(target), self._tok(target)),
                            self._meta(meta))

    @v_args(meta=True)
    def experiment(self, meta, children):
        name, description, *body = children
        return ast.Experiment(str(name), _opt_str(description), tuple(body), self._meta(meta), self._tok(name))

    @v_args(meta=True)
    def model(self, meta, children):
        name, description, *body = children
        return ast.Model(str(name), _opt_str(description), tuple(body), self._meta(meta), self._tok(name))

    def start(self, children):
        return tuple(children)

    @v_args(meta=True)
    def set_value(self, meta, children):
        name, value, unit = children
        return ast.SetValue(str(name), value, unit, self._meta(meta))


# ------------------------------------------------------------ error recovery

def _describe_expected(expected) -> str:
    names = []
    for terminal in sorted(set(expected) - {"COMMENT"}):
        if terminal in TERMINAL_NAMES:
            names.append(TERMINAL_NAMES[terminal])
        elif terminal.isupper() and terminal.lower() in KEYWORDS:
            names.append(f"'{terminal.lower()}'")
        else:
            names.append(terminal)
    names = sorted(set(names))
    if len(names) > 6:
        return "one of " + ", ".join(names[:6]) + ", ..."
    return names[0] if len(names) == 1 else "one of " + ", ".join(names)


def _token_text(token: Token) -> str:
    if token.type == "_NL":
        return "end of line"
    if token.type == "$END":
        return "end of file"
    return f"'{token}'"


def _code_chars(text: str, end: int):
    """``(index, character, quoted)`` of ``text[:end]`` outside comments, ``quoted`` for a string's
    characters and quotes (a string ends at its closing quote or, unclosed, at the end of its line;
    an escaped character is skipped with its backslash)."""
    in_string = False
    index = 0
    while index < end:
        char = text[index]
        if in_string:
            if char == "\\":
                index += 2
                continue
            in_string = char not in '"\n'
            yield index, char, char != "\n"
        elif char == "#":
            newline = text.find("\n", index)
            index = len(text) if newline < 0 else newline
            continue
        else:
            in_string = char == '"'
            yield index, char, in_string
        index += 1


def _statement_extent(text: str, offset: int) -> tuple[int, int]:
    """The [start, end) of the logical statement (line rules applied) holding offset."""
    starts = [0]
    depth = 0
    last_significant = ""
    for index, char, quoted in _code_chars(text, len(text)):
        if not quoted and char in "([":
            depth += 1
        elif not quoted and char in ")]":
            depth = max(0, depth - 1)
        if char == "\n" and not quoted:
            if depth == 0 and last_significant != ",":
                starts.append(index + 1)
        elif not char.isspace():
            last_significant = char
    starts.append(len(text) + 1)
    for start, end in zip(starts, starts[1:]):
        if start <= offset < end:
            return start, min(end - 1, len(text))
    return offset, len(text)


def _inside_when_block(text: str, start: int) -> bool:
    """Whether the statement starting at ``start`` is in the body of a ``when ... then`` block (its
    header on an earlier line, no ``end`` line since)."""
    for line in reversed(text[:start].split("\n")):
        code = line.split("#", 1)[0].strip()
        if code == "end" or code.startswith(("model ", "experiment ")):
            return False
        if code.startswith("when ") and code.endswith(" then"):
            return True
    return False


# A line that starts a statement of the model, never one of a when block's body: a keyword that
# begins a declaration, an element (KIND NAME followed by ':', '(' or its description) or a bond.
_OPENERS = sorted((KEYWORDS | STATEMENT_KEYWORDS) - {"end", "if", "then", "else", "and", "or", "not"})
_DECLARATION = re.compile(rf"({'|'.join(_OPENERS)})\b|[A-Za-z_]\w*\s+[A-Za-z_]\w*\s*(\(|:|\")|.*->")


def _unclosed_when(text: str, offset: int) -> tuple[int, int] | None:
    """The offsets of the ``when`` header whose block is still open at ``offset`` (no ``end`` since)
    and of the line's statement, when that line is not a statement of its body but the model's (a
    declaration, a bond, another ``when``): the block's ``end`` was forgotten. None otherwise."""
    line_start = text.rfind("\n", 0, offset) + 1
    line = text[line_start:].split("\n", 1)[0].split("#", 1)[0].strip()
    if not _DECLARATION.match(line):
        return None
    statement = line_start + len(text[line_start:]) - len(text[line_start:].lstrip(" \t"))
    position = line_start
    for previous in reversed(text[:line_start].split("\n")[:-1]):
        position -= len(previous) + 1
        code = previous.split("#", 1)[0].strip()
        if code == "end" or code.startswith(("model ", "experiment ")):
            return None
        if code.startswith("when "):
            return None if code.endswith(" end") else (position + len(previous) - len(previous.lstrip()), statement)
    return None


def _open_bracket(text: str, offset: int) -> int | None:
    """The offset of the innermost ``(`` or ``[`` still open at ``offset`` (strings and comments
    skipped), or None."""
    opened: list[int] = []
    for index, char, quoted in _code_chars(text, offset):
        if quoted:
            continue
        if char in "([":
            opened.append(index)
        elif char in ")]" and opened:
            opened.pop()
    return opened[-1] if opened else None


def _unclosed(diagnostic: Diagnostic, source: Source, offset: int) -> Diagnostic:
    """``diagnostic`` about a token on a later line than a bracket still open there: the bracket
    joined the lines (inside ( ) or [ ] a line break continues the statement), so say so and
    point at it."""
    opened = _open_bracket(source.text, offset)
    if opened is None:
        return diagnostic
    closing = ")" if source.text[opened] == "(" else "]"
    if "\n" not in source.text[opened:offset] and (not diagnostic.message.endswith(f"expected '{closing}'")
                                                    or source.text[offset:offset + 1] in ")]"):
        return diagnostic       # on its own line, only a wrong closing bracket: that one is the error
    bracket = source.text[opened]
    where = source.span(opened, opened + 1)
    if "\n" not in source.text[opened:offset]:     # only a closing bracket can come here
        return replace(diagnostic, hint=f"the '{bracket}' at column {where.column} is not closed; close it with "
                                        f"'{closing}' where its expression ends",
                       related=(Related(where, f"'{bracket}' opened here"),))
    return replace(diagnostic, hint=f"the '{bracket}' on line {where.line} is not closed: inside ( ) or [ ] the "
                                    f"statement goes on over the line break; close it with '{closing}'",
                   related=(Related(where, f"'{bracket}' opened here"),))


def _blank(text: str, start: int, end: int, replacement: str = "") -> str:
    """Replace text[start:end] by ``replacement`` padded with spaces, keeping newlines."""
    chunk = "".join(c if c == "\n" else " " for c in text[start:end])
    if replacement and "\n" not in chunk[: len(replacement)] and len(replacement) <= len(chunk):
        chunk = replacement + chunk[len(replacement):]
    return text[:start] + chunk + text[end:]


def _syntax_diagnostic(error: UnexpectedInput, source: Source) -> tuple[Diagnostic, int]:
    """A diagnostic for one lark error, and the offset it is at."""
    if isinstance(error, UnexpectedCharacters):
        offset = error.pos_in_stream or 0      # (set for every unexpected character)
        char = source.text[offset] if offset < len(source.text) else ""
        span = source.span(offset, offset + 1)
        if char == '"':
            end = source.text.find("\n", offset)
            end = len(source.text) if end < 0 else end
            return Diagnostic("error", codes.E102, "unterminated string", source.span(offset, end),
                              hint='close the string with " on the same line'), offset
        return Diagnostic("error", codes.E101, f"unexpected character {char!r}", span,
                          hint="names are letters, digits and '_'; comments start with '#'"), offset
    token = getattr(error, "token", None)
    expected = getattr(error, "expected", None) or getattr(error, "accepts", None) or set()
    if token is None or token.type == "$END" or isinstance(error, UnexpectedEOF):
        offset = len(source.text)
        span = source.span(max(offset - 1, 0), offset)
        hint = "every 'model' and 'experiment' block is closed by 'end'" if "END" in expected else None
        return Diagnostic("error", codes.E103, f"unexpected end of file; expected {_describe_expected(expected)}",
                          span, hint=hint), offset
    offset = token.start_pos if token.start_pos is not None else 0
    end = token.end_pos if token.end_pos is not None and token.type != "_NL" else offset + 1
    span = source.span(offset, end)
    if str(token) in ("if", "not") and "LPAR" in expected:  # an operand, not a name, was meant
        return Diagnostic("error", codes.E100, f"unexpected '{token}' here; an operand of an operator cannot start with it",
                          span, hint=f"put the '{token}' expression in parentheses, e.g. 2*({token} ...)"), offset
    if str(token) in KEYWORDS and "NAME" in expected:
        return Diagnostic("error", codes.E104, f"'{token}' is a keyword and cannot be used as a name", span,
                          hint=f"choose another name, e.g. '{token}_'"), offset
    hint = None
    line_start = source.text.rfind("\n", 0, offset) + 1
    statement = source.text[line_start:offset].lstrip()
    if token.type == "_NL":
        hint = "a statement ends at the end of its line; continue it after a trailing ',' or inside ( )"
    elif token.type == "EQUAL" and "COLON" in expected:
        hint = "element laws follow a ':' (e.g. R damper : e = b*f)"
    elif token.type == "EQUAL" and statement.startswith(("when ", "if ")) or " if " in statement and \
            token.type == "EQUAL":
        hint = "a comparison is written '==' ('=' assigns)"
    return Diagnostic("error", codes.E100, f"unexpected {_token_text(token)}; expected {_describe_expected(expected)}",
                      span, hint=hint), offset


def _parse_tree(text: str, start: str):
    parser, postlex = _parser()
    postlex.text = text
    tree = parser.parse(text, start=start)
    return tree, list(postlex.comments)


def parse_source(source: Source) -> ast.File:
    """Parse one source; raise :class:`ParseError` with every syntax error found."""
    text = source.text
    diagnostics: list[Diagnostic] = []
    tree = comments = None
    for _ in range(MAX_SYNTAX_ERRORS + 1):
        try:
            tree, comments = _parse_tree(text, "start")
            break
        except UnexpectedInput as error:
            diagnostic, offset = _syntax_diagnostic(error, source)
            if diagnostics and (diagnostics[-1].span == diagnostic.span or (
                    diagnostics[-1].span.line == diagnostic.span.line and diagnostics[-1].message == diagnostic.message)):
                break  # no progress: stop rather than report the same place (or line) twice
            unclosed = _unclosed_when(text, offset)
            if unclosed is not None and diagnostic.code in (codes.E100, codes.E104):
                # a forgotten 'end': one error, at the statement the block ran into; the block goes
                opened, statement = unclosed
                where = source.span(opened, opened + 4)
                word = re.match(r"\w+|->|\S", text[statement:])
                width = len(word.group()) if word else 1
                diagnostics.append(replace(
                    diagnostic, code=codes.E100, span=source.span(statement, statement + width),
                    message=f"the 'when' block of line {where.line} is not closed before this statement",
                    hint="close it with 'end': on a line of its own after its statements, or at the end of a "
                         "one-line block (when c then d = 1 end)",
                    related=(Related(where, "the block opened here"),)))
                line_start = text.rfind("\n", 0, offset) + 1
                text = _blank(text, opened, line_start)
                continue
            explained = _unclosed(diagnostic, source, offset)
            diagnostics.append(explained)
            if diagnostic.code == codes.E103 or len(diagnostics) >= MAX_SYNTAX_ERRORS or explained is not diagnostic:
                break   # (past an unclosed bracket the rest of the file is one statement: no more to say)
            start, end = _statement_extent(text, offset)
            header = text[start:end].lstrip()
            # Keep a block header's shape, so its body is not reported again statement by statement.
            replacement = ""
            for keyword in ("model", "experiment"):
                if header.startswith(keyword + " ") or header == keyword:
                    replacement = keyword + " _"
            written = header.split("#", 1)[0].rstrip()
            if header.startswith("when ") and not written.endswith(" end"):
                replacement = "when _ then"     # a when block's header: its statements and 'end' follow
            elif _inside_when_block(text, start):
                replacement = "_ = 0"           # a when block's statements: the block keeps one
            text = _blank(text, start, end, replacement)
    if diagnostics or tree is None or comments is None:
        raise ParseError(diagnostics, {source.name: source})
    try:
        items = _ToAst(source).transform(tree)
    except VisitError as error:  # a bug in a transformer method, not in the model
        raise ParseError(Diagnostic("error", codes.E199, f"internal error while reading the model: {error.orig_exc}",
                                    source.span(0, 0))) from error
    # Trailing blanks (and the \r of a CRLF file) are layout, not part of a comment.
    file_comments = tuple(ast.Comment(str(tok).rstrip(), source.span(tok.start_pos, tok.end_pos)) for tok in comments)
    return ast.File(tuple(items), source.name, file_comments)


def parse_text(text: str, name: str = "<text>") -> ast.File:
    return parse_source(Source(name, text))


def parse_file(path: str | Path) -> tuple[ast.File, Source]:
    source = Source.from_path(path)
    return parse_source(source), source


def parse_set_value(text: str, name: str = "--set") -> ast.SetValue:
    """Parse a command-line ``NAME=VALUE [unit]`` assignment; ``name`` labels it in diagnostics."""
    source = Source(name, text)
    try:
        tree, _ = _parse_tree(text, "set_value")
    except UnexpectedInput as error:
        diagnostic, _ = _syntax_diagnostic(error, source)
        raise ParseError(diagnostic, {name: source}) from None
    value = _ToAst(source).transform(tree)
    return ast.SetValue(value.name, value.value, value.unit, value.span, source)
